"""`vid2sim train` and `vid2sim study`: SAC or distillation runs and scene-count studies (argument parsing only)."""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

from vid2sim.cli.errors import InputError
from vid2sim.cli.inputs import creatable_folder, registry_root
from vid2sim.cli.settings import apply_or_exit
from vid2sim.ranges import check_ranges
from vid2sim.training.actions import check_map
from vid2sim.training.config import METHODS, DistillConfig, SACConfig, TrainConfig
from vid2sim.training.distill import summary, train_distill
from vid2sim.training.privileged import PRIVILEGED_ID
from vid2sim.training.rollouts import init_ray
from vid2sim.training.sac import train
from vid2sim.training.student import StudentConfig
from vid2sim.training.study import StudyConfig, StudyError, aggregate, report_study, run_study

DEFAULT_STEPS = {"sac": 1_500_000, "distill": 80_000}  # the paper's SAC budget; a 2-core CPU distillation


def _sac(learning_starts: Optional[int], batch_size: Optional[int], buffer_size: Optional[int]) -> SACConfig:
    sac = SACConfig()
    updates = {k: v for k, v in (("learning_starts", learning_starts), ("batch_size", batch_size),
                                 ("buffer_size", buffer_size)) if v is not None}
    return replace(sac, **updates)


def _ray(address: Optional[str], num_cpus: Optional[int]) -> None:
    init_ray(address, num_cpus)


def _study_env(env: str) -> dict[str, str]:
    if env == "pixel":
        return {"env_id": "vid2sim/PointNav-v0", "env_module": "vid2sim.envs"}
    if env == "privileged":
        return {"env_id": PRIVILEGED_ID, "env_module": "vid2sim.training.privileged"}
    raise typer.BadParameter(f"--env must be pixel or privileged, got {env!r}")


def _distill(steps_per_round: int, updates_per_round: int, beta_decay: float, frames: int, pool: int,
             shift_pad: int) -> DistillConfig:
    return DistillConfig(steps_per_round=steps_per_round, updates_per_round=updates_per_round, beta_decay=beta_decay,
                         shift_pad=shift_pad, student=StudentConfig(frames=frames, pool=pool))


def _counts(text: str) -> list[int]:
    try:
        return [int(c) for c in text.split(",") if c.strip()]
    except ValueError:
        raise typer.BadParameter(f"--counts must be comma-separated integers, got {text!r}") from None


def _method(method: str) -> str:
    if method not in METHODS:
        raise typer.BadParameter(f"--method must be one of {', '.join(METHODS)}, got {method!r}")
    return method


def _resumed_config(run_dir: str, steps: Optional[int]) -> TrainConfig:
    """A resumed run keeps its recorded config; only the step budget may grow. It goes on in the folder
    named by --run, also when that folder was copied or moved since it was recorded."""
    path = Path(run_dir) / "config.json"
    if not path.is_file():
        raise typer.BadParameter(f"cannot resume {run_dir}: {path} does not exist (not a run folder)")
    config = TrainConfig.load(path)
    config.run_dir = str(run_dir)
    if steps is not None:
        config.total_steps = steps
    return config


RESUME_FREE = {"registry", "run_dir", "steps", "resume", "ray_address", "num_cpus"}  # may be given with --resume


def _refuse_changes_on_resume(ctx: typer.Context, run_dir: str) -> None:
    """A resumed run keeps its recorded config: any other option given on the command line is refused."""
    given = sorted(name for name in ctx.params if name not in RESUME_FREE
                   and getattr(ctx.get_parameter_source(name), "name", "") == "COMMANDLINE")
    if given:
        opts = {p.name: p.opts[0] for p in ctx.command.params if getattr(p, "opts", None)}
        flags = ", ".join(opts.get(name, name) for name in given)
        raise InputError(flags, f"refused with --resume: {run_dir} keeps its recorded config (config.json); "
                                "only --steps may change")


def train_command(
    ctx: typer.Context,
    registry: str = typer.Option(..., "--registry", help="Registry root."),
    run_dir: str = typer.Option(..., "--run", help="Run folder (config, scenes, checkpoints, TensorBoard)."),
    method: str = typer.Option("sac", "--method", help="sac (paper preset) | distill (pixel student from the A* "
                                                       "teacher, DAgger)."),
    steps: Optional[int] = typer.Option(None, "--steps", min=1, help="Env-step budget (default: sac 1.5M as the paper, "
                                                              "distill 80k)."),
    split_seed: int = typer.Option(0, "--split-seed", min=0, help="Registry split seed."),
    train_scenes: Optional[int] = typer.Option(None, "--train-scenes", min=1,
                                               help="Nested train subset size (default: all)."),
    task: str = typer.Option("PointNav", "--task", help="PointNav | SocialNav"),
    variant: str = typer.Option("rgb", "--variant", help="rgb | depth | mesh-rgb"),
    n_envs: int = typer.Option(4, "--envs", min=1, help="Parallel environments."),
    n_actors: int = typer.Option(2, "--actors", min=0, help="Ray actors hosting the envs (0: in-process)."),
    seed: int = typer.Option(0, "--seed", min=0),
    learning_starts: Optional[int] = typer.Option(None, "--learning-starts", min=0,
                                                  help="sac: override the paper's 10000."),
    batch_size: Optional[int] = typer.Option(None, "--batch-size", min=1, help="sac: override the paper's 256."),
    buffer_size: Optional[int] = typer.Option(None, "--buffer-size", min=1,
                                              help="sac: replay cap (also capped by memory)."),
    checkpoint_every: int = typer.Option(10_000, "--checkpoint-every", min=1,
                                         help="sac: env steps between checkpoints."),
    action_map: str = typer.Option("clamp", "--action-map",
                                   help="sac: clamp (the envs' speed contract) | full (speed = (a + 1) / 2)."),
    steps_per_round: int = typer.Option(4000, "--steps-per-round", min=1,
                                        help="distill: env steps collected per round."),
    updates_per_round: int = typer.Option(DistillConfig.updates_per_round, "--updates-per-round", min=1,
                                          help="distill: learner steps per round."),
    beta_decay: float = typer.Option(0.5, "--beta-decay", min=0.0, max=1.0,
                                     help="distill: teacher's episode share x this per round."),
    frames: int = typer.Option(2, "--frames", min=1, max=6, help="distill: most recent frames the student sees (1-6)."),
    pool: int = typer.Option(2, "--pool", min=1, help="distill: frame down-sampling factor (2: 36 x 64)."),
    shift_pad: int = typer.Option(4, "--shift-pad", min=0,
                                  help="distill: random-shift augmentation in pixels (0: off)."),
    stuck_steps: int = typer.Option(10, "--stuck-steps", min=0, help="distill: end a training episode after this many "
                                                              "control steps without motion (0: never)."),
    checkout_root: Optional[str] = typer.Option(None, "--checkout-root", help="Scene checkouts (and their sim-ready "
                                                "sets) shared between runs (default: RUN/scenes)."),
    resume: bool = typer.Option(False, "--resume", help="Continue the run from its checkpoint, with its recorded "
                                                        "config (only --steps may change)."),
    sets: Optional[list[str]] = typer.Option(None, "--set", help="Override a TrainConfig field: section.field=value "
                                             "(e.g. distill.beta_decay=0.7, sac.tau=0.01); see `vid2sim config show "
                                             "train`. Repeatable."),
    ray_address: Optional[str] = typer.Option(None, "--ray-address", help="Ray cluster (default: local runtime)."),
    num_cpus: Optional[int] = typer.Option(None, "--num-cpus", min=1, help="Local Ray runtime CPUs."),
) -> None:
    """Train SAC (paper preset) or distil a pixel student from the A* teacher on a registry split's training scenes."""
    if resume:
        _refuse_changes_on_resume(ctx, run_dir)
        config = _resumed_config(run_dir, steps)
    else:
        env_kwargs: dict = {"variant": variant}
        if checkout_root:
            env_kwargs["checkout_root"] = checkout_root
        config = TrainConfig(run_dir=run_dir, total_steps=steps or DEFAULT_STEPS[_method(method)],
                             env_id=f"vid2sim/{task}-v0", env_kwargs=env_kwargs, registry=registry,
                             split_seed=split_seed, train_scenes=train_scenes, n_envs=n_envs, n_actors=n_actors,
                             seed=seed, checkpoint_every=checkpoint_every, action_map=check_map(action_map),
                             sac=_sac(learning_starts, batch_size, buffer_size), method=method,
                             stuck_steps=(stuck_steps or None) if method == "distill" else None,
                             distill=_distill(steps_per_round, updates_per_round, beta_decay, frames, pool, shift_pad))
        config = apply_or_exit(config, sets)
    registry_root(registry)
    creatable_folder(run_dir, "--run")
    creatable_folder(checkout_root, "--checkout-root")
    if config.n_actors > 0:
        _ray(ray_address, num_cpus)
    if config.method == "distill":
        result = train_distill(config, resume=resume, log=lambda row: typer.echo(json.dumps(summary([row]))))
        typer.echo(json.dumps({"run": str(result.run_dir), "steps": result.num_timesteps,
                               "wall_s": round(result.wall_s, 1), **summary(result.history)}))
        return
    result = train(config, resume=resume)
    last = result.history[-1] if result.history else {}
    typer.echo(json.dumps({"run": str(result.run_dir), "steps": result.num_timesteps,
                           "wall_s": round(result.wall_s, 1), **last}))


def study_command(
    registry: str = typer.Option(..., "--registry", help="Registry root."),
    out_dir: str = typer.Option(..., "--out", help="Study folder (runs, study.json, study.png)."),
    counts: str = typer.Option("1,5,15,25,30", "--counts", help="Training-scene counts (each <= the train pool)."),
    seeds: int = typer.Option(3, "--seeds", min=1, help="Trainings per count."),
    first_seed: int = typer.Option(0, "--first-seed", min=0,
                                   help="Seeds first_seed .. first_seed + seeds - 1 (finished runs are reused)."),
    method: str = typer.Option("sac", "--method", help="sac | distill (pixel student from the A* teacher)."),
    steps: Optional[int] = typer.Option(None, "--steps", min=1, help="Env steps per training (default: sac 20k, "
                                                              "distill 80k)."),
    steps_per_round: int = typer.Option(4000, "--steps-per-round", min=1,
                                        help="distill: env steps collected per round."),
    updates_per_round: int = typer.Option(DistillConfig.updates_per_round, "--updates-per-round", min=1,
                                          help="distill: learner steps per round."),
    trials: int = typer.Option(25, "--trials", min=1, help="Episodes per held-out test scene."),
    split_seed: int = typer.Option(0, "--split-seed", min=0),
    n_envs: int = typer.Option(2, "--envs", min=1, help="Envs per training (in the training's Ray task)."),
    obstacles: str = typer.Option("static", "--obstacles", help="Evaluation obstacles: none | static | dynamic"),
    learning_starts: Optional[int] = typer.Option(None, "--learning-starts", min=0),
    batch_size: Optional[int] = typer.Option(None, "--batch-size", min=1),
    buffer_size: Optional[int] = typer.Option(None, "--buffer-size", min=1),
    ray_address: Optional[str] = typer.Option(None, "--ray-address"),
    num_cpus: Optional[int] = typer.Option(None, "--num-cpus", min=1),
    env: str = typer.Option("pixel", "--env", help="pixel (PointNav RGB) | privileged (goal vector + ranges)"),
    eval_max_steps: Optional[int] = typer.Option(None, "--eval-max-steps", min=1, help="Evaluation episode limit."),
    report_only: bool = typer.Option(False, "--report-only",
                                     help="Train nothing: the table and plot of the folder's finished runs."),
    as_json: bool = typer.Option(False, "--json"),
) -> None:
    """Train per (count, seed) as Ray tasks, evaluate on held-out scenes, table + PNG plot (over every
    finished run of the folder with the same settings)."""
    registry_root(registry)
    creatable_folder(out_dir, "--out")
    method = _method(method)
    steps = steps or {"sac": 20_000, "distill": DEFAULT_STEPS["distill"]}[method]
    env_ids = _study_env("pixel" if method == "distill" else env)
    config = StudyConfig(registry=registry, out_dir=out_dir, counts=_counts(counts),
                         seeds=seeds, first_seed=first_seed, split_seed=split_seed, total_steps=steps,
                         n_envs=n_envs, trials=trials,
                         obstacles=obstacles, sac=_sac(learning_starts, batch_size, buffer_size),
                         eval_max_steps=eval_max_steps, method=method,
                         env_kwargs={"training": True} if method == "distill" else {},
                         stuck_steps=10 if method == "distill" else None,
                         distill=replace(DistillConfig(), steps_per_round=steps_per_round,
                                         updates_per_round=updates_per_round), **env_ids)
    check_ranges(config)
    if report_only:
        try:
            rows = report_study(config)
        except StudyError as e:
            raise InputError(f"--out {out_dir}", str(e)) from e
    else:
        _ray(ray_address, num_cpus)
        rows = run_study(config)
    if as_json:
        typer.echo(json.dumps([asdict(r) for r in rows], indent=2))
        return
    table = Table(title=f"scene-count study: {steps} env steps per run, {trials} trials per test scene")
    for col in ("scenes", "seed", "SR", "SPL", "Cost", "train s"):
        table.add_column(col)
    for r in rows:
        table.add_row(str(r.count), str(r.seed), f"{r.sr:.2f}", f"{r.spl:.2f}", f"{r.cost:.2f}",
                      f"{r.train_wall_s:.0f}")
    Console().print(table)
    summary_table = Table(title="per count: SR mean over seeds, 95 % interval over the pooled held-out episodes")
    for col in ("scenes", "seeds", "SR", "SR 95% CI", "SPL"):
        summary_table.add_column(col)
    for n, agg in aggregate(rows).items():
        ci = f"[{agg['sr_ci_low']:.2f}, {agg['sr_ci_high']:.2f}]" if "sr_ci_low" in agg else "-"
        summary_table.add_row(n, str(agg["seeds"]), f"{agg['sr_mean']:.2f}", ci, f"{agg['spl_mean']:.2f}")
    Console().print(summary_table)
    typer.echo(f"plot: {out_dir}/study.png")
