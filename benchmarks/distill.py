"""Pixel agents distilled from the A* teacher: held-out success over seeds, SocialNav, the scene-count study.

    python benchmarks/distill.py heldout --streets 40 --seeds 0 1 2 [--socialnav] [--train-eval 8]   # the bar
    python benchmarks/distill.py heldout --streets 40 --seeds 0 1 2 3 4 5 6 7 8 --ensemble 3   # 3 ensembles of 3
    python benchmarks/distill.py study --streets 40 --counts 1,5,15,25,30 --seeds 0 1 2 --steps 40000
    python benchmarks/distill.py heldout --root ROOT2 --streets 40 --extra-streets 32 --seeds 0 1 2 --steps 64000
    python benchmarks/distill.py heldout --quick        # 6 streets, one seed, 2 small rounds (smoke run)

Scenes: synthetic-street ground-truth bundles whose layout, furniture and light differ by seed
(`benchmarks/street_registry.py --vary`, `vid2sim.factory.synthetic.varied`); the registry's split
(seed 0, 20 % of the streets) holds out whole streets. Training: `vid2sim train --method distill`
(`training/distill.py`), in-process envs (so the process's CPU seconds are the whole cost), exact
render fidelity (`--fidelity`; fast first fits a sim-ready set per street), camera jitter on, the
envs' image augmentation off unless `--augment` (`distill.augment`). Evaluation: `vid2sim eval
policy`'s protocol: 25 trials per held-out street (seeds 1000 + k), 0-5 static obstacles, exact
render fidelity, no jitter or augmentation, a 600-step limit (`--eval-max-steps`, 0: the env's 3000;
a robot pressed against geometry it cannot leave would otherwise cost 3000 steps per failure); SR,
SPL and Cost with 95 % bootstrap intervals; `--socialnav` also evaluates the same students with 1-4
pedestrians (SR, SNS). `--ensemble K` also evaluates the students of every K consecutive seeds
driving together (`training/ensemble.py`, the mean of their actions), whose training budget is the K
runs' sum.
Every figure states its budget (env steps, wall and CPU seconds).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Optional

sys.path.insert(0, str(Path(__file__).resolve().parent))
import numpy as np  # noqa: E402
from common import Run, add_run_args, cpu_seconds  # noqa: E402
from street_registry import build, scene_id as street_id  # noqa: E402

from vid2sim.envs.obstacles import EXTRA_KINDS, OBSTACLE_KINDS  # noqa: E402
from vid2sim.registry import Registry  # noqa: E402
from vid2sim.registry.split import SplitConfig, make_split  # noqa: E402
from vid2sim.training.config import DistillConfig, EVICTIONS, TrainConfig  # noqa: E402
from vid2sim.training.distill import STUDENT_NAME, train_distill  # noqa: E402
from vid2sim.training.ensemble import build_ensemble, load_student  # noqa: E402
from vid2sim.training.evaluate import EvalConfig, EvalReport, bootstrap_ci, evaluate  # noqa: E402
from vid2sim.training.rollouts import init_ray  # noqa: E402
from vid2sim.training.student import StudentConfig  # noqa: E402
from vid2sim.training.study import StudyConfig, aggregate, report_study, run_study  # noqa: E402


def registry(args) -> str:
    return str(build(args.root, list(range(1, args.streets + args.extra_streets + 1)), vary=True).root)


def extra_street_sides(args, reg: str) -> tuple[Optional[list[str]], Optional[list[str]]]:
    """(training, held-out) scene ids with --extra-streets: the held-out streets are the split's of
    the first --streets streets alone, the extra streets join the training side; (None, None)
    without, so the runs use the registry's own split."""
    if not args.extra_streets:
        return None, None
    store = Registry(reg)
    base_ids = {street_id(seed, True) for seed in range(1, args.streets + 1)}
    base = make_split([r for r in store.list() if r.scene_id in base_ids], SplitConfig(seed=0),
                      registry_version=0)  # only its held-out groups are used
    split = store.split(seed=0, test_groups=base.test_groups)
    return list(split.train), list(split.test)


def distill_config(args) -> DistillConfig:
    student = StudentConfig(frames=args.frames, frame_stride=args.frame_stride, pool=args.pool,
                            channels=tuple(args.channels),
                            clearance_rays=args.clearance_rays, steer_bins=args.steer_bins,
                            depth_target=args.depth_target, vector_history=args.vector_history,
                            steer_gain=args.steer_gain, keypoints=args.keypoints,
                            waypoints=args.waypoints, drive_waypoints=args.drive_waypoints)
    return replace(DistillConfig(), steps_per_round=args.steps_per_round, updates_per_round=args.updates_per_round,
                   max_samples=args.max_samples, eviction=args.eviction, shift_pad=args.shift_pad,
                   mirror=args.mirror, min_beta=args.min_beta,
                   teacher_comfort=args.teacher_comfort, teacher_replan=args.teacher_replan,
                   teacher_lookahead=args.teacher_lookahead, weight_decay=args.weight_decay,
                   clearance_weight=args.clearance_weight, steer_weight=args.steer_weight,
                   hard_fraction=args.hard_fraction, hard_steps=args.hard_steps,
                   scene_priority=args.scene_priority, depth_weight=args.depth_weight,
                   waypoint_weight=args.waypoint_weight, ema_decay=args.ema_decay,
                   augment=args.augment,
                   student=student)


def record_eval(run: Run, case: str, rep: EvalReport, budget: dict, metrics=("sr", "spl", "cost")) -> dict:
    row, ends = {}, rep.outcomes()  # ends: episodes per outcome (time-outs split into pinned and free)
    for k in metrics:
        m = rep.metrics[k]
        row[k] = [round(m.mean, 3), round(m.low, 3), round(m.high, 3)]
        success = {"outcomes": ends} if k == "sr" else {}  # kept once, with the success rate
        run.record(case, k, m.mean, "", {"ci95": [m.low, m.high], "episodes": rep.episodes, **success, **budget})
    print(json.dumps({"case": case, "episodes": rep.episodes, **row, "outcomes": ends, **budget}), flush=True)
    return row


def finished_budget(run_dir: Path, steps: int) -> Optional[dict]:
    """The budget a finished run of >= `steps` env steps recorded (run_dir/budget.json), else None."""
    path = run_dir / "budget.json"
    budget = json.loads(path.read_text()) if path.is_file() else None
    return budget if budget and budget["env_steps"] >= steps and (run_dir / STUDENT_NAME).is_file() else None


def check_same_scenes(run_dir: Path, scene_ids: Optional[list[str]]) -> None:
    """SystemExit when the run folder's config.json says it trained on other scenes than
    `scene_ids` (None or empty: the split's training side, not checked)."""
    path = run_dir / "config.json"
    saved = json.loads(path.read_text()).get("scene_ids") if path.is_file() else None
    if scene_ids and saved and sorted(saved) != sorted(scene_ids):
        raise SystemExit(f"{run_dir}: this run trained on {len(saved)} scenes ({', '.join(saved[:3])}, ...), "
                         f"the call asks for a different set of {len(scene_ids)}; give the new run its own --tag")


def training_settings(config: TrainConfig) -> dict:
    """The run's settings as JSON values, without its folder and env-step budget."""
    return json.loads(json.dumps({k: v for k, v in config.to_dict().items() if k not in ("run_dir", "total_steps")}))


def start_from_shorter_run(config: TrainConfig, source: Path) -> dict:
    """Start the run folder of `config` as a copy of the finished shorter run `source` (its config,
    checkpoint, TensorBoard log and data shards, the shards hard-linked: they are written once; not
    its evaluation reports, budget or final student), so that a resumed `train_distill` goes on at
    its next round -> the source's budget. SystemExit when `source` is not a finished run with a
    checkpoint, already has the steps asked for, or was trained with other settings (anything but
    the run folder and the env-step budget)."""
    budget = finished_budget(source, 1)
    if budget is None or not (source / "checkpoints" / "last.pt").is_file():
        raise SystemExit(f"{source}: not a finished run with a checkpoint (budget.json, student.pt, "
                         f"checkpoints/last.pt) to go on from")
    if budget["env_steps"] >= config.total_steps:
        raise SystemExit(f"{source}: already has {budget['env_steps']} env steps, the call asks for "
                         f"{config.total_steps}")
    saved, asked = training_settings(TrainConfig.load(source / "config.json")), training_settings(config)
    if differ := sorted(k for k in asked if saved.get(k) != asked[k]):
        raise SystemExit(f"{source}: trained with other settings ({', '.join(differ)}); cannot go on from it")
    run_dir = Path(config.run_dir)
    partial = run_dir.with_name(run_dir.name + ".partial")  # renamed into place once complete
    shutil.rmtree(partial, ignore_errors=True)
    shutil.copytree(source, partial, ignore=shutil.ignore_patterns("data", "eval_*.json", "budget.json",
                                                                   STUDENT_NAME))
    (partial / "data").mkdir()
    for shard in sorted((source / "data").glob("round_*.npz")):
        os.link(shard, partial / "data" / shard.name)
    partial.rename(run_dir)
    return budget


def train_or_reuse(config: TrainConfig, start_from: Optional[Path] = None, **extra) -> dict:
    """Train the distillation run `config` describes and write its budget (env steps, wall and CPU
    seconds, seed, `extra`) to budget.json; a finished run of the same folder is reused (a folder
    that trained on other scenes is refused: `check_same_scenes`). `start_from`: a finished shorter
    run of the same settings that a new folder goes on from (`start_from_shorter_run`; its wall and
    CPU seconds are counted in the budget)."""
    run_dir = Path(config.run_dir)
    check_same_scenes(run_dir, config.scene_ids)
    if (budget := finished_budget(run_dir, config.total_steps)) is not None:
        print(f"reusing {run_dir} (finished, {budget['env_steps']} env steps)", flush=True)
        return budget
    before = {"train_wall_s": 0, "train_cpu_s": 0}
    if start_from is not None:
        if run_dir.exists():
            raise SystemExit(f"{run_dir}: an unfinished run is already there; remove it to start from {start_from}")
        before = start_from_shorter_run(config, start_from)
        extra["started_from"] = {"run": str(start_from), "env_steps": before["env_steps"]}
        print(f"going on from {start_from} ({before['env_steps']} env steps)", flush=True)
    t0, cpu0 = time.perf_counter(), cpu_seconds()
    result = train_distill(config, resume=start_from is not None,
                           log=lambda row: print(json.dumps({k: round(v, 3) if isinstance(v, float) else v
                                                             for k, v in row.items()}), flush=True))
    budget = {"env_steps": result.num_timesteps,
              "train_wall_s": before["train_wall_s"] + round(time.perf_counter() - t0),
              "train_cpu_s": before["train_cpu_s"] + round(cpu_seconds() - cpu0), "seed": config.seed, **extra}
    (run_dir / "budget.json").write_text(json.dumps(budget))
    return budget


def camera_kwargs(args) -> dict:
    """The robot camera's override (--camera-vfov), {} for the robot's own camera."""
    return {"camera": {"vfov_deg": args.camera_vfov}} if args.camera_vfov else {}


def obstacle_kwargs(args) -> dict:
    """The training envs' obstacle overrides (--train-obstacles MIN MAX, --train-obstacle-kinds
    KIND...; the evaluation keeps the protocol's 0-5 of its five kinds), {} for the envs' own."""
    out: dict = {}
    if args.train_obstacles:
        lo, hi = args.train_obstacles
        if not 0 <= lo <= hi:
            raise SystemExit(f"--train-obstacles {lo} {hi}: need 0 <= MIN <= MAX")
        out.update(min_count=lo, max_count=hi)
    if args.train_obstacle_kinds:
        known = OBSTACLE_KINDS + EXTRA_KINDS
        unknown = [k for k in args.train_obstacle_kinds if k not in known]
        if unknown:
            raise SystemExit(f"--train-obstacle-kinds: unknown kind(s) {unknown}; choose from {', '.join(known)}")
        out["kinds"] = list(args.train_obstacle_kinds)
    return {"obstacles": out} if out else {}


def variant_kwargs(args) -> dict:
    """The students' observation (--variant): {} for the camera's RGB."""
    return {"variant": args.variant} if args.variant != "rgb" else {}


def train_one(args, reg: str, seed: int, scene_ids: Optional[list[str]] = None) -> tuple[Path, dict]:
    """Distil the student of `seed` (a finished run of the same folder is reused) -> run folder, budget.
    scene_ids: the training streets (None: the registry split's training side)."""
    run_dir = args.root / f"distill_{args.steps}_s{seed}{args.tag}"
    config = TrainConfig(run_dir=str(run_dir), total_steps=args.steps, registry=reg, n_envs=args.envs, n_actors=0,
                         seed=seed, method="distill", stuck_steps=10, scene_ids=scene_ids,
                         env_kwargs={"training": True, "checkout_root": str(args.root / "checkouts"),
                                     "fidelity": args.fidelity, **camera_kwargs(args), **obstacle_kwargs(args),
                                     **variant_kwargs(args)},
                         distill=distill_config(args))
    return run_dir, train_or_reuse(config)


def evaluate_saved(config: EvalConfig, saved: Path) -> EvalReport:
    """`evaluate(config)`, reusing the report at `saved` when it was made with the same config."""
    rep = EvalReport.from_json(saved.read_text()) if saved.is_file() else None
    if rep is None or rep.config != json.loads(json.dumps(asdict(config))):
        rep = evaluate(config)
        saved.write_text(rep.to_json())
    return rep


def eval_config(args, reg: str, run_dir: Path, obstacles: str, scenes: Optional[list[str]] = None) -> EvalConfig:
    """The benchmark's evaluation protocol for one student (default scenes: the split's held-out ones,
    with --extra-streets those of the base streets' split, set by `run_heldout` as args.heldout_ids)."""
    scenes = scenes or getattr(args, "heldout_ids", None) or []
    return EvalConfig(registry=reg, policy=str(run_dir), scene_ids=scenes, trials=args.trials,
                      obstacles=obstacles, max_steps=args.eval_max_steps or None, variant=args.variant,
                      checkout_root=str(args.root / "checkouts"))


def run_heldout(args, run: Run) -> None:
    reg = registry(args)
    args.train_ids, args.heldout_ids = extra_street_sides(args, reg)
    if args.train_streets:  # a diagnostic: train on named streets instead of the split's training side
        args.train_ids = list(args.train_streets)
    if args.eval_streets:
        args.heldout_ids = list(args.eval_streets)
    successes: dict[str, list[float]] = {"pointnav": [], "socialnav": []}
    trained: list[tuple[Path, dict]] = []
    for seed in args.seeds:
        run_dir, budget = train_one(args, reg, seed, args.train_ids)
        trained.append((run_dir, budget))
        run.record(f"pointnav seed {seed}", "train_wall_s", budget["train_wall_s"], "s", budget)
        run.record(f"pointnav seed {seed}", "train_cpu_s", budget["train_cpu_s"], "s", budget)
        if not args.no_member_eval:
            evaluate_policy(args, run, reg, run_dir, f"seed {seed}", budget, successes)
        if args.train_eval:
            eval_training_streets(args, run, reg, run_dir, budget)
    report_pooled(run, successes, "all seeds", {"seeds": list(args.seeds), "env_steps": args.steps})
    if args.ensemble:
        run_ensembles(args, run, reg, trained)
    for gain in args.eval_steer_gains:
        run_driving(args, run, reg, trained, f"steer gain {gain:g}", steer_gain=gain)
    if args.eval_mirror_average:
        run_driving(args, run, reg, trained, "mirror average", mirror_average=True)
    if args.eval_other_steering:  # students with a route head: the steering they were not trained to drive by
        label = "action head" if args.drive_waypoints else "route pursuit"
        run_driving(args, run, reg, trained, label, drive_waypoints=not args.drive_waypoints)


def evaluate_policy(args, run: Run, reg: str, policy_dir: Path, name: str, budget: dict,
                    successes: dict[str, list[float]]) -> None:
    """The held-out protocol (PointNav, and SocialNav with --socialnav) for one student or ensemble."""
    for task, obstacles in (("pointnav", "static"), ("socialnav", "dynamic")):
        if task == "socialnav" and not args.socialnav:
            continue
        rep = evaluate_saved(eval_config(args, reg, policy_dir, obstacles), policy_dir / f"eval_{task}.json")
        metrics = ("sr", "spl", "cost") + (("sns",) if task == "socialnav" else ())
        record_eval(run, f"{task} {name}", rep, budget, metrics)
        successes[task] += [float(r["success"]) for r in rep.records]


def report_pooled(run: Run, successes: dict[str, list[float]], name: str, extra: dict) -> None:
    for task, values in successes.items():
        if values:
            ci = bootstrap_ci(np.array(values))
            run.record(f"{task} {name}", "sr", ci.mean, "", {"ci95": [ci.low, ci.high], "episodes": len(values),
                                                             **extra})
            print(json.dumps({"case": f"{task} {name}", "sr": [round(ci.mean, 3), round(ci.low, 3),
                                                               round(ci.high, 3)], "episodes": len(values)}))


def run_ensembles(args, run: Run, reg: str, trained: list[tuple[Path, dict]]) -> None:
    """Every `--ensemble` consecutive students driving together; budget: the sum of their trainings."""
    successes: dict[str, list[float]] = {"pointnav": [], "socialnav": []}
    k = args.ensemble
    for i in range(0, len(trained) - k + 1, k):
        group = trained[i:i + k]
        seeds = [b["seed"] for _, b in group]
        folder = build_ensemble([d for d, _ in group], args.root / f"ensemble_{args.steps}_s{'-'.join(map(str, seeds))}"
                                                                    f"{args.tag}")
        budget = {"env_steps": sum(b["env_steps"] for _, b in group), "seeds": seeds,
                  "train_wall_s": sum(b["train_wall_s"] for _, b in group),
                  "train_cpu_s": sum(b["train_cpu_s"] for _, b in group)}
        evaluate_policy(args, run, reg, folder, f"ensemble of seeds {seeds}", budget, successes)
    report_pooled(run, successes, f"all ensembles of {k}", {"seeds": list(args.seeds), "env_steps": args.steps})


def run_driving(args, run: Run, reg: str, trained: list[tuple[Path, dict]], label: str, **settings) -> None:
    """The trained students driving with other driving settings (`StudentPolicy.driving_with`: a steering
    gain, the mirror average; their weights unchanged; written to RUN_LABEL/student.pt): held-out SR, and SR
    on training streets with --train-eval, which is where a setting is chosen without looking at the
    held-out streets."""
    successes: dict[str, list[float]] = {"pointnav": [], "socialnav": []}
    for run_dir, budget in trained:
        folder = run_dir.with_name(f"{run_dir.name}_{label.replace(' ', '')}")
        folder.mkdir(exist_ok=True)
        load_student(run_dir / STUDENT_NAME).driving_with(**settings).save(folder / STUDENT_NAME)
        (folder / "config.json").write_text((run_dir / "config.json").read_text())  # its training streets
        name = f"seed {budget['seed']}, {label}"
        evaluate_policy(args, run, reg, folder, name, {**budget, **settings}, successes)
        if args.train_eval:
            eval_training_streets(args, run, reg, folder, {**budget, **settings}, name)
    report_pooled(run, successes, f"all seeds, {label}", {"seeds": list(args.seeds), "env_steps": args.steps,
                                                          **settings})


def eval_training_streets(args, run: Run, reg: str, run_dir: Path, budget: dict, name: str = "") -> None:
    """The held-out protocol on the first `--train-eval` of the run's own training streets: SR there
    against held-out SR separates what the student failed to learn from what it failed to transfer."""
    scenes = TrainConfig.load(run_dir / "config.json").scene_ids[:args.train_eval]
    rep = evaluate_saved(eval_config(args, reg, run_dir, "static", scenes),
                         run_dir / "eval_pointnav_training_streets.json")
    name = name or f"seed {budget['seed']}"
    record_eval(run, f"pointnav {name}, {len(scenes)} training streets", rep, budget)


def run_study_bench(args, run: Run) -> None:
    reg = registry(args)
    seeds = sorted(args.seeds)
    if seeds != list(range(seeds[0], seeds[0] + len(seeds))):
        raise SystemExit(f"study: --seeds {' '.join(map(str, args.seeds))} must be consecutive (a study trains "
                         "seeds first .. first + n - 1 per count)")
    config = StudyConfig(registry=reg, out_dir=str(args.root / f"study_{args.steps}{args.tag}"),
                         counts=[int(c) for c in args.counts.split(",")], seeds=len(seeds), first_seed=seeds[0],
                         total_steps=args.steps, n_envs=args.envs, trials=args.trials, method="distill",
                         env_kwargs={"training": True, "fidelity": args.fidelity}, stuck_steps=10,
                         distill=distill_config(args), eval_max_steps=args.eval_max_steps or None)
    if args.report_only:  # the folder's finished runs, nothing trained
        rows = report_study(config)
    else:
        init_ray(None, args.num_cpus)
        rows = run_study(config)
    for n, agg in aggregate(rows).items():
        run.record_all(f"{n} training scenes", {k: agg[k] for k in agg if k != "seeds"}, "",
                       {"seeds": agg["seeds"], "env_steps": args.steps, "trials": args.trials})
        print(json.dumps({"scenes": int(n), **{k: round(v, 3) for k, v in agg.items()}}), flush=True)
    print(f"plot: {config.out_dir}/study.png")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=["heldout", "study"])
    ap.add_argument("--root", type=Path, default=Path("/tmp/vid2sim-distill"))
    ap.add_argument("--streets", type=int, default=12, help="varied streets in the registry (20 %% held out)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--steps", type=int, default=128_000, help="env steps per training")
    ap.add_argument("--steps-per-round", type=int, default=4000)
    ap.add_argument("--updates-per-round", type=int, default=DistillConfig.updates_per_round)
    ap.add_argument("--envs", type=int, default=8)
    ap.add_argument("--frames", type=int, default=2, help="student: stacked frames it sees")
    ap.add_argument("--pool", type=int, default=StudentConfig.pool, help="student: pooling of the 72 x 128 frames")
    ap.add_argument("--channels", type=int, nargs=4, default=list(StudentConfig.channels), metavar="C",
                    help="student: the four conv widths of its frame encoder")
    ap.add_argument("--frame-stride", type=int, default=1, help="student: every k-th stacked frame")
    ap.add_argument("--vector-history", type=int, default=StudentConfig.vector_history,
                    help="student: latest goal-vector entries it reads (1: only the current one)")
    ap.add_argument("--max-samples", type=int, default=DistillConfig.max_samples, help="dataset cap (labelled states)")
    ap.add_argument("--shift-pad", type=int, default=DistillConfig.shift_pad,
                    help="random-shift augmentation in student pixels (0: off)")
    ap.add_argument("--min-beta", type=float, default=DistillConfig.min_beta,
                    help="floor of the teacher's share of the collected episodes in every round")
    ap.add_argument("--mirror", type=float, default=DistillConfig.mirror,
                    help="probability that a learner sample is seen in a mirror (flipped frames, negated steering)")
    ap.add_argument("--eviction", default="oldest", choices=EVICTIONS, help="over the cap: what goes")
    ap.add_argument("--teacher-comfort", type=float, default=DistillConfig.teacher_comfort,
                    help="m the teacher's route keeps from blocked cells where there is room (0: the shortest route)")
    ap.add_argument("--teacher-replan", type=float, default=DistillConfig.teacher_replan,
                    help="m off its path at which the teacher re-plans (0: at every state)")
    ap.add_argument("--teacher-lookahead", type=float, default=DistillConfig.teacher_lookahead,
                    help="m ahead on its route the teacher's pure pursuit aims")
    ap.add_argument("--steer-gain", type=float, default=StudentConfig.steer_gain,
                    help="student: steering gain when it drives (collection and evaluation), not in its loss")
    ap.add_argument("--eval-steer-gains", type=float, nargs="*", default=[],
                    help="heldout: also evaluate the trained students driving with each of these steering gains")
    ap.add_argument("--eval-mirror-average", action="store_true",
                    help="heldout: also evaluate the trained students driving with their mirror average")
    ap.add_argument("--weight-decay", type=float, default=DistillConfig.weight_decay,
                    help="decoupled weight decay of the student (AdamW)")
    ap.add_argument("--clearance-rays", type=int, default=StudentConfig.clearance_rays,
                    help="auxiliary target: the teacher's clearance over the view, this many rays (0: off)")
    ap.add_argument("--steer-bins", type=int, default=StudentConfig.steer_bins,
                    help="student: steering as a distribution over K values (0: regressed)")
    ap.add_argument("--steer-weight", type=float, default=DistillConfig.steer_weight,
                    help="a label counts 1 + this x |its steering| in the action loss")
    ap.add_argument("--hard-fraction", type=float, default=DistillConfig.hard_fraction,
                    help="share of each learner batch drawn from the states before a contact (0: uniform)")
    ap.add_argument("--scene-priority", type=float, default=DistillConfig.scene_priority,
                    help="share of each env's episodes drawn by the student's failure rate per scene (0: uniform)")
    ap.add_argument("--hard-steps", type=int, default=DistillConfig.hard_steps,
                    help="states before a contact's onset flagged hard")
    ap.add_argument("--clearance-weight", type=float, default=DistillConfig.clearance_weight,
                    help="weight of the auxiliary clearance loss")
    ap.add_argument("--augment", action=argparse.BooleanOptionalAction, default=DistillConfig.augment,
                    help="the training envs' per-episode image augmentation (exposure, tint, fog, rain, snow)")
    ap.add_argument("--variant", choices=("rgb", "depth", "mesh-rgb"), default="rgb",
                    help="what the students see, in training and evaluation: the splat RGB, the depth oracle "
                         "or the mesh render")
    ap.add_argument("--camera-vfov", type=float, default=0.0,
                    help="the camera's vertical field of view in deg, trained and evaluated (0: the robot's 60)")
    ap.add_argument("--train-obstacles", type=int, nargs=2, default=None, metavar=("MIN", "MAX"),
                    help="static obstacles per training episode (default: the envs' 0-5; evaluation keeps 0-5)")
    ap.add_argument("--train-obstacle-kinds", nargs="+", default=None, metavar="KIND",
                    help="obstacle kinds of the training episodes, drawn uniformly (default: the protocol's five; "
                         "'planter' adds the sidewalk planter; evaluation keeps the protocol's)")
    ap.add_argument("--keypoints", type=int, default=StudentConfig.keypoints,
                    help="student: K spatial-softmax keypoints per frame instead of the flattened conv map (0: off)")
    ap.add_argument("--waypoints", type=int, default=StudentConfig.waypoints,
                    help="student: a second head predicting the teacher's route ahead as K points 0.5 m apart (0: off)")
    ap.add_argument("--drive-waypoints", action="store_true",
                    help="student: steer by pure pursuit on its predicted route (needs --waypoints)")
    ap.add_argument("--eval-other-steering", action="store_true",
                    help="with --waypoints: also evaluate the students steering the other way (the action head "
                         "when they drive by their route, the route's pure pursuit when not)")
    ap.add_argument("--waypoint-weight", type=float, default=DistillConfig.waypoint_weight,
                    help="weight of the route loss (with --waypoints)")
    ap.add_argument("--depth-target", action="store_true",
                    help="student: auxiliary head predicting the frame's nearest depth per cell of its last conv map")
    ap.add_argument("--depth-weight", type=float, default=DistillConfig.depth_weight,
                    help="weight of the auxiliary depth loss (with --depth-target)")
    ap.add_argument("--ema-decay", type=float, default=DistillConfig.ema_decay,
                    help="exponential moving average of the student's weights per learner step (0: off)")
    ap.add_argument("--fidelity", default="exact", choices=["exact", "fast"], help="training render fidelity")
    ap.add_argument("--eval-max-steps", type=int, default=600, help="evaluation episode limit (0: the env's 3000)")
    ap.add_argument("--trials", type=int, default=25)
    ap.add_argument("--socialnav", action="store_true", help="heldout: also evaluate with pedestrians")
    ap.add_argument("--train-eval", type=int, default=0,
                    help="heldout: also evaluate on this many of the run's training streets (same protocol)")
    ap.add_argument("--ensemble", type=int, default=0,
                    help="heldout: also evaluate the students of every K consecutive seeds as one ensemble")
    ap.add_argument("--no-member-eval", action="store_true",
                    help="heldout: evaluate only the ensembles, not each student")
    ap.add_argument("--counts", default="1,5,15,25,30", help="study: training-scene counts")
    ap.add_argument("--num-cpus", type=int, default=2, help="study: local Ray runtime CPUs (one training each)")
    ap.add_argument("--report-only", action="store_true",
                    help="study: train nothing, the table of the study folder's finished runs with these settings")
    ap.add_argument("--quick", action="store_true",
                    help="6 streets, one seed (two with --ensemble), 2 rounds of 200 steps, 2 trials")
    ap.add_argument("--extra-streets", type=int, default=0,
                    help="heldout: this many more streets (seeds after --streets') on the training side; the held-out "
                         "streets stay those of the first --streets (give the run its own --root)")
    ap.add_argument("--train-streets", nargs="+", default=None, metavar="ID",
                    help="heldout: train on these scene ids instead of the split's training side (a diagnostic, "
                         "e.g. one street's own student; give it its own --tag)")
    ap.add_argument("--eval-streets", nargs="+", default=None, metavar="ID",
                    help="heldout: evaluate on these scene ids instead of the split's held-out streets")
    ap.add_argument("--tag", default="")
    add_run_args(ap)
    args = ap.parse_args()
    if args.quick:
        args.streets, args.seeds, args.steps, args.steps_per_round = 6, args.seeds[:2 if args.ensemble else 1], 400, 200
        args.updates_per_round, args.trials, args.envs, args.eval_max_steps = 20, 2, 2, 100
    if args.ensemble and not 2 <= args.ensemble <= len(args.seeds):
        ap.error(f"--ensemble {args.ensemble}: an ensemble needs 2 to {len(args.seeds)} students (the --seeds)")
    if (args.drive_waypoints or args.eval_other_steering) and not args.waypoints:
        ap.error("--drive-waypoints and --eval-other-steering need a route head (--waypoints K)")
    with Run("distill", args) as run:
        {"heldout": run_heldout, "study": run_study_bench}[args.what](args, run)


if __name__ == "__main__":
    main()
