"""Sim-to-real without a robot: pixel students trained on factory reconstructions, tested in ground truth.

    python benchmarks/sim2real.py --root /tmp/vid2sim-distill --streets 40 --train 8 --steps 64000 --seed 0

The procedural street's ground truth plays the real world; the factory only ever sees the video
rendered from it. For the first `--train` streets of the registry's training split (varied
streets, `benchmarks/street_registry.py --vary`): render the walk as a 10-s 854x480 video
(`synthetic.varied(seed, "demo")`), ingest every video through the factory (`fast` pipeline,
`quick` reconstruction preset) into a second registry, then distill three students with the
same recipe (the default distillation recipe; `--teacher-replan`, `--mirror`), seed and budget:
  splat    on the reconstructed scenes, rendered from their Gaussian splats (Vid2Sim);
  mesh-rgb on the same reconstructions, rendered from their coloured visual mesh (the paper's
           mesh baseline, `--variant mesh-rgb`);
  gt       on the ground-truth bundles of the same streets (the upper bound).
All three are evaluated in the ground-truth worlds (splat rendering of the GT bundle, exact
fidelity) of the split's held-out streets, and of their own training streets, with
`vid2sim eval policy`'s protocol (0-5 static obstacles, seeds 1000 + k, a `--eval-max-steps`
limit). The test world's rendering matters, so two more can be asked for: the held-out streets'
flat-coloured GT mesh (`--mesh-world-trials`) and the same streets built with more GT splats
(`--dense-world-trials`, `--dense-world-splats`), closer to the video. The held-out streets can
also be reconstructed through the factory the same way (`--recon-world-trials`): every student is
then evaluated in those reconstructions too, rendered from their splats, with the factory's own
walkable maps and collision meshes (the pixel policy's bar on scenes the factory made: trained on
reconstructions, tested on reconstructions of streets it never saw); there, success is also
split by the episode's direction along the filmed walk (with it / against it, and starts past
either end of the walk, on ground the camera saw only from afar), from the records' start poses
and goals and the scenes' camera paths.
Every stage is resumable:
finished renders, reconstructions, trainings and evaluations of the same protocol are reused.
A longer training can go on from a finished shorter one of the same recipe (`--start-from-steps`):
its new folder starts with the shorter run's data and checkpoint, and its budget counts both parts.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import time
from dataclasses import dataclass, replace
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Optional

import numpy as np
from common import Run, add_run_args
from distill import evaluate_saved, record_eval, train_or_reuse
from street_registry import build

from vid2sim.registry import Registry, RegistryNotFound
from vid2sim.training.config import DistillConfig, TrainConfig
from vid2sim.training.evaluate import EvalConfig
from vid2sim.training.student import StudentConfig

VARIANTS = ("splat", "mesh-rgb", "gt")


def street_seed(scene_id: str) -> int:
    """street-v12 -> 12 (the varied street's generator seed)."""
    return int(scene_id.removeprefix("street-v"))


def choose_streets(gt_registry: str, n_train: int) -> tuple[list[str], list[str]]:
    """The first n_train streets of the split's training side (by seed) and all its held-out ones."""
    split = Registry(gt_registry).split(seed=0)
    if not 1 <= n_train <= len(split.train):
        raise SystemExit(f"--train {n_train}: the split of {gt_registry} has {len(split.train)} training streets")
    train = sorted(split.train, key=street_seed)[:n_train]
    return train, sorted(split.test, key=street_seed)


def render_clip(seed: int, clips: Path) -> Path:
    """The 10-s walk through varied street `seed` as <clips>/street-v<seed>.mp4 (a finished render is reused)."""
    from vid2sim.factory.synthetic import generate_street, render_video, varied

    conf = replace(varied(seed, "demo"), write_depth=False)
    clip = render_video(generate_street(conf), conf, clips / f"street-v{seed}")
    video = clips / f"street-v{seed}.mp4"  # the file name becomes the registry id's stem
    if not video.exists():
        shutil.copyfile(clip.video, video)
    return video


def reconstruct(run: Run, root: Path, streets: list[str], workers: int, side: str = "training") -> tuple[str, dict]:
    """Render and ingest every street of the split's `side` ("training" / "held-out") that the
    reconstruction registry lacks -> its root, and each street's reconstruction record."""
    from vid2sim.factory.recon.config import preset as recon_preset
    from vid2sim.factory.runtime.pipeline import ingest, preset
    from vid2sim.factory.synthetic import StreetConfig  # the walk's camera height (every varied street's)

    recon_root = root / "sim2real" / "registry"
    timings = root / "sim2real" / RECON_TIMINGS[side]  # the seconds of the call that made them
    have = recon_scenes(str(recon_root))
    todo = [s for s in streets if s not in have]
    if todo:
        t0 = time.perf_counter()
        with ProcessPoolExecutor(workers) as pool:
            videos = list(pool.map(render_clip, [street_seed(s) for s in todo],
                                   [root / "sim2real" / "clips"] * len(todo)))
        t1 = time.perf_counter()
        report = ingest([str(v) for v in videos], str(recon_root), workdir=root / "sim2real" / "work",
                        conf=replace(preset("fast"), recon=recon_preset("quick")), num_cpus=workers,
                        licence="CC0-synthetic", capture_height=StreetConfig().capture_height)
        timings.write_text(json.dumps({"streets": todo, "render_wall_s": t1 - t0,
                                       "ingest_wall_s": time.perf_counter() - t1}))
        for r in report.results:
            print(json.dumps({"clip": r.clip_id, "ok": r.ok, "stage": r.failed_stage, "reason": r.reason}), flush=True)
    have = recon_scenes(str(recon_root))
    missing = [s for s in streets if s not in have]
    if missing:
        raise SystemExit(f"reconstruction failed for {missing}: see the ingest report above")
    if timings.is_file():
        t = json.loads(timings.read_text())
        run.record_all(f"render and ingest {len(t['streets'])} videos, 10 s 854x480 (fast pipeline, quick recon)"
                       + ("" if side == "training" else f", {side} streets"),
                       {"render_wall_s": t["render_wall_s"], "ingest_wall_s": t["ingest_wall_s"]}, "s")
    for street in streets:
        rec = have[street]
        run.record_all(f"reconstruction of {street}", {"psnr_db": rec.metrics.get("recon.psnr"),
                                                       "splats": rec.num_splats,
                                                       "walkable_m2": rec.walkable_area_m2}, "")
    return str(recon_root), have


RECON_TIMINGS = {"training": "reconstruction.json", "held-out": "reconstruction_heldout.json"}


def recon_scenes(recon_registry: str) -> dict:
    """GT street id -> the latest record of its reconstruction (ids street-vN-<sha8>-<window>)."""
    try:
        records = Registry(recon_registry).list()
    except RegistryNotFound:  # nothing ingested yet
        return {}
    return {m.group(1): r for r in records if (m := re.match(r"(street-v\d+)-", r.scene_id))}


def train_student(args, name: str, registry: str, scene_ids: list[str]) -> tuple[Path, dict]:
    """Distil one student on `scene_ids` (rendered as the variant names) -> run folder, budget."""
    run_dir = args.root / "sim2real" / f"{name}_{args.steps}_s{args.seed}{args.tag}"
    variant = "mesh-rgb" if name == "mesh-rgb" else "rgb"
    config = TrainConfig(run_dir=str(run_dir), total_steps=args.steps, registry=registry, n_envs=args.envs,
                         n_actors=0, seed=args.seed, method="distill", stuck_steps=10, scene_ids=scene_ids,
                         env_kwargs={"training": True, "variant": variant, "fidelity": "exact",
                                     "checkout_root": str(args.root / "checkouts")},
                         distill=replace(DistillConfig(), teacher_replan=args.teacher_replan, mirror=args.mirror,
                                         hard_fraction=args.hard_fraction, hard_steps=args.hard_steps,
                                         student=replace(StudentConfig(), channels=tuple(args.channels),
                                                         frames=args.frames, frame_stride=args.frame_stride)))
    shorter = args.root / "sim2real" / f"{name}_{args.start_from_steps}_s{args.seed}{args.tag}"
    return run_dir, train_or_reuse(config, start_from=shorter if args.start_from_steps else None, scenes=scene_ids)


@dataclass(frozen=True)
class World:
    """Where a student is tested: `trials` episodes on each of a registry's `scene_ids`, rendered as
    `variant`; the report is saved in the run folder as `report` and recorded under `label`."""

    label: str
    registry: str
    scene_ids: list[str]
    trials: int
    report: str
    variant: str = "rgb"
    checkouts: Optional[Path] = None


def worlds_to_test(args, gt_registry: str, dense: Path, train: list[str], heldout: list[str],
                   recon_world: Optional[tuple[str, list[str]]]) -> list[World]:
    """Every test the arguments ask for: held-out GT streets, the student's own streets in GT, the
    held-out streets as a flat-coloured mesh and with dense GT splats (the root `dense`), and the
    factory's reconstructions of the held-out streets (registry, scene ids)."""
    worlds = [World("in GT held-out streets", gt_registry, heldout, args.trials, "eval_gt_splat_held-out.json")]
    if args.train_trials:
        worlds.append(World("in GT training streets", gt_registry, train, args.train_trials,
                            "eval_gt_splat_training.json"))
    if args.mesh_world_trials:
        worlds.append(World("in GT held-out streets, GT mesh rendering", gt_registry, heldout,
                            args.mesh_world_trials, "eval_gt_mesh_held-out.json", variant="mesh-rgb"))
    if args.dense_world_trials:
        worlds.append(World("in GT held-out streets, dense GT splats", str(dense / "registry"), heldout,
                            args.dense_world_trials, "eval_gt_dense_held-out.json", checkouts=dense / "checkouts"))
    if recon_world is not None:  # on the factory's own walkable maps and collision meshes
        worlds.append(World("in factory reconstructions of the held-out streets", *recon_world,
                            args.recon_world_trials, "eval_recon_held-out.json"))
    return worlds


def run_sim2real(args, run: Run) -> None:
    gt_registry = str(build(args.root, list(range(1, args.streets + 1)), vary=True).root)
    train, heldout = choose_streets(gt_registry, args.train)
    run.config.update({"train_streets": train, "heldout_streets": heldout})
    print(json.dumps({"train": train, "heldout": heldout}), flush=True)
    sources = {"gt": (gt_registry, train)}
    if args.recon_only or set(args.variants) - {"gt"}:
        recon_registry, recons = reconstruct(run, args.root, train, args.workers)
        recon_ids = [recons[s].scene_id for s in train]
        sources |= {"splat": (recon_registry, recon_ids), "mesh-rgb": (recon_registry, recon_ids)}
    recon_world = None
    if args.recon_world_trials:  # the held-out streets through the factory as well
        recon_registry, recons = reconstruct(run, args.root, heldout, args.workers, side="held-out")
        recon_world = (recon_registry, [recons[s].scene_id for s in heldout])
    if args.recon_only:
        return
    dense = args.root / "sim2real" / f"gt_{args.dense_world_splats}"
    if args.dense_world_trials:  # the held-out streets again, with more GT splats
        build(dense, [street_seed(s) for s in heldout], args.dense_world_splats, vary=True)
    worlds = worlds_to_test(args, gt_registry, dense, train, heldout, recon_world)
    for name in args.variants:
        run_dir, budget = train_student(args, name, *sources[name])
        run.record_all(f"{name} student, seed {args.seed}", {"train_wall_s": budget["train_wall_s"],
                                                             "train_cpu_s": budget["train_cpu_s"]}, "s",
                       {"seed": args.seed})
        for world in worlds:
            evaluate_in(args, run, name, run_dir, budget, world)


def evaluate_in(args, run: Run, name: str, run_dir: Path, budget: dict, world: World) -> None:
    """The evaluation protocol (0-5 static obstacles, exact render) in `world`; a saved report of the
    same protocol is reused. In reconstructions, also success by the episode's direction along the
    walk the video was filmed on."""
    checkouts = world.checkouts or args.root / "checkouts"
    config = EvalConfig(registry=world.registry, policy=str(run_dir), scene_ids=world.scene_ids,
                        trials=world.trials, obstacles="static", max_steps=args.eval_max_steps or None,
                        variant=world.variant, checkout_root=str(checkouts))
    rep = evaluate_saved(config, run_dir / world.report)
    case = f"{name} student, seed {budget['seed']}, {world.label}"
    record_eval(run, case, rep, {k: v for k, v in budget.items() if k != "scenes"}
                | {"trials": world.trials, "scenes": len(world.scene_ids)})
    if world.report == "eval_recon_held-out.json":
        for group, success in by_walk_direction(rep.records, world.registry, checkouts).items():
            run.record(f"{case}, {group}", "sr", float(np.mean(success)), "", {"episodes": len(success)})
            print(json.dumps({"case": case, "episodes": group, "n": len(success),
                              "sr": round(float(np.mean(success)), 3)}), flush=True)


def walk_xy(registry: str, scene_id: str, checkouts: Path) -> np.ndarray:
    """[K, 2] x, y of the scene's source-video camera centres in time order (every 10th and the last)."""
    from vid2sim.formats.cameras import load_cameras

    reg = Registry(registry)
    table = load_cameras(reg.checkout(scene_id, dest=checkouts / reg.show(scene_id).ref) / "cameras.parquet")
    c2w = np.array(table.column("cam_to_world").to_pylist()).reshape(-1, 4, 4)  # [N, 4, 4]
    xy = c2w[np.argsort(table.column("timestamp").to_numpy()), :2, 3]  # [N, 2]
    return np.vstack([xy[::10], xy[-1:]])


def along_walk(walk: np.ndarray, xy) -> float:
    """Arc length (m) along the polyline `walk` [K, 2] of its nearest point to `xy`, continued in a
    straight line before its first and past its last point (negative / above the walk's length)."""
    seg = np.diff(walk, axis=0)  # [K-1, 2]
    length = np.linalg.norm(seg, axis=1)
    start = np.r_[0.0, np.cumsum(length)]
    best, s_best = np.inf, 0.0
    for k in np.flatnonzero(length > 1e-9):
        u = float(np.dot(np.asarray(xy) - walk[k], seg[k])) / length[k] ** 2
        u = min(max(u, -np.inf if k == 0 else 0.0), np.inf if k == len(seg) - 1 else 1.0)
        dist = float(np.linalg.norm(np.asarray(xy) - walk[k] - u * seg[k]))
        if dist < best:
            best, s_best = dist, start[k] + u * length[k]
    return s_best


def by_walk_direction(records: list[dict], registry: str, checkouts: Path) -> dict[str, list[bool]]:
    """Episode successes grouped by where the episode runs against the filmed walk: the goal further
    along the walk than the start ("with the walk") or back toward its beginning ("against the
    walk"), and starts past either end of the walk (on ground the camera saw from afar)."""
    walks: dict[str, tuple[np.ndarray, float]] = {}  # scene -> (walk [K, 2], its length in m)
    groups: dict[str, list[bool]] = {}
    for r in records:
        if not r.get("start_pose"):  # a report written before records kept the poses
            continue
        if r["scene_id"] not in walks:
            xy = walk_xy(registry, r["scene_id"], checkouts)
            walks[r["scene_id"]] = xy, float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum())
        walk, total = walks[r["scene_id"]]
        s0, s1 = along_walk(walk, r["start_pose"][:2]), along_walk(walk, r["goal"])
        groups.setdefault("with the walk" if s1 > s0 else "against the walk", []).append(r["success"])
        past = s0 < -0.5 or s0 > total + 0.5
        groups.setdefault("starting past an end of the walk" if past else "starting along the walk",
                          []).append(r["success"])
    return groups


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("/tmp/vid2sim-distill"),
                    help="the GT street registry (built when absent) and sim2real/ (videos, reconstructions, runs)")
    ap.add_argument("--streets", type=int, default=40, help="varied streets in the GT registry (20 %% held out)")
    ap.add_argument("--train", type=int, default=8, help="training streets reconstructed through the factory")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=64_000, help="env steps per training")
    ap.add_argument("--start-from-steps", type=int, default=0,
                    help="go on from the finished run of this many env steps (same variant, seed and tag) "
                         "instead of training from scratch; its seconds count in the budget")
    ap.add_argument("--envs", type=int, default=8)
    ap.add_argument("--teacher-replan", type=float, default=DistillConfig.teacher_replan,
                    help="m off its path at which the teacher re-plans (0: at every state)")
    ap.add_argument("--mirror", type=float, default=DistillConfig.mirror,
                    help="probability that a learner sample is seen in a mirror (flipped frames, negated steering)")
    ap.add_argument("--channels", type=int, nargs=4, default=list(StudentConfig.channels), metavar="C",
                    help="student: the four conv widths of its frame encoder")
    ap.add_argument("--frames", type=int, default=StudentConfig.frames, help="student: stacked frames it looks at")
    ap.add_argument("--frame-stride", type=int, default=StudentConfig.frame_stride,
                    help="student: every k-th stacked frame back from the latest (5 with 2 frames: t-5, t)")
    ap.add_argument("--hard-fraction", type=float, default=DistillConfig.hard_fraction,
                    help="share of each learner batch drawn from the states before a contact (0: uniform)")
    ap.add_argument("--hard-steps", type=int, default=DistillConfig.hard_steps,
                    help="states before a contact's onset flagged hard")
    ap.add_argument("--trials", type=int, default=10, help="episodes per held-out GT street")
    ap.add_argument("--train-trials", type=int, default=5, help="episodes per training street's GT world (0: none)")
    ap.add_argument("--mesh-world-trials", type=int, default=0,
                    help="also evaluate in the held-out GT worlds rendered from their flat-coloured GT mesh")
    ap.add_argument("--dense-world-trials", type=int, default=0,
                    help="also evaluate in the held-out GT worlds built with --dense-world-splats splats")
    ap.add_argument("--dense-world-splats", type=int, default=200_000)
    ap.add_argument("--recon-world-trials", type=int, default=0,
                    help="also reconstruct the held-out streets through the factory and evaluate in them")
    ap.add_argument("--eval-max-steps", type=int, default=600, help="evaluation episode limit (0: the env's 3000)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 2, help="renders / Ray CPUs for the ingest")
    ap.add_argument("--recon-only", action="store_true", help="stop after the reconstructions")
    ap.add_argument("--tag", default="")
    add_run_args(ap)
    args = ap.parse_args()
    with Run("sim2real", args) as run:
        run_sim2real(args, run)


if __name__ == "__main__":
    main()
