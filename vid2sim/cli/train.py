"""`vid2sim train` and `vid2sim study`: SAC training runs and scene-count studies (argument parsing only)."""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

from vid2sim.training.actions import check_map
from vid2sim.training.config import SACConfig, TrainConfig
from vid2sim.training.privileged import PRIVILEGED_ID
from vid2sim.training.rollouts import init_ray
from vid2sim.training.sac import train
from vid2sim.training.study import StudyConfig, run_study


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


def train_command(
    registry: str = typer.Option(..., "--registry", help="Registry root."),
    run_dir: str = typer.Option(..., "--run", help="Run folder (config, scenes, checkpoints, TensorBoard)."),
    steps: int = typer.Option(1_500_000, "--steps", help="Env-step budget (the paper: 1.5M)."),
    split_seed: int = typer.Option(0, "--split-seed", help="Registry split seed."),
    train_scenes: Optional[int] = typer.Option(None, "--train-scenes", help="Nested train subset size (default: all)."),
    task: str = typer.Option("PointNav", "--task", help="PointNav | SocialNav"),
    variant: str = typer.Option("rgb", "--variant", help="rgb | depth | mesh-rgb"),
    n_envs: int = typer.Option(4, "--envs", help="Parallel environments."),
    n_actors: int = typer.Option(2, "--actors", help="Ray actors hosting the envs (0: in-process)."),
    seed: int = typer.Option(0, "--seed"),
    learning_starts: Optional[int] = typer.Option(None, "--learning-starts", help="Override the paper's 10000."),
    batch_size: Optional[int] = typer.Option(None, "--batch-size", help="Override the paper's 256."),
    buffer_size: Optional[int] = typer.Option(None, "--buffer-size", help="Replay cap (also capped by free memory)."),
    checkpoint_every: int = typer.Option(10_000, "--checkpoint-every"),
    action_map: str = typer.Option("clamp", "--action-map",
                                   help="clamp (the envs' speed contract) | full (speed = (a + 1) / 2)."),
    resume: bool = typer.Option(False, "--resume", help="Continue from RUN/checkpoints/last.zip."),
    ray_address: Optional[str] = typer.Option(None, "--ray-address", help="Ray cluster (default: local runtime)."),
    num_cpus: Optional[int] = typer.Option(None, "--num-cpus", help="Local Ray runtime CPUs."),
) -> None:
    """Train SAC (paper preset) on a registry split's training scenes."""
    config = TrainConfig(run_dir=run_dir, total_steps=steps, env_id=f"vid2sim/{task}-v0",
                         env_kwargs={"variant": variant}, registry=registry, split_seed=split_seed,
                         train_scenes=train_scenes, n_envs=n_envs, n_actors=n_actors, seed=seed,
                         checkpoint_every=checkpoint_every, action_map=check_map(action_map),
                         sac=_sac(learning_starts, batch_size, buffer_size))
    if n_actors > 0:
        _ray(ray_address, num_cpus)
    result = train(config, resume=resume)
    last = result.history[-1] if result.history else {}
    typer.echo(json.dumps({"run": str(result.run_dir), "steps": result.num_timesteps,
                           "wall_s": round(result.wall_s, 1), **last}))


def study_command(
    registry: str = typer.Option(..., "--registry", help="Registry root."),
    out_dir: str = typer.Option(..., "--out", help="Study folder (runs, study.json, study.png)."),
    counts: str = typer.Option("1,5,15,25,30", "--counts", help="Training-scene counts (clipped to the registry)."),
    seeds: int = typer.Option(2, "--seeds", help="Trainings per count."),
    steps: int = typer.Option(20_000, "--steps", help="Env steps per training."),
    trials: int = typer.Option(25, "--trials", help="Episodes per held-out test scene."),
    split_seed: int = typer.Option(0, "--split-seed"),
    n_envs: int = typer.Option(2, "--envs", help="Envs per training (in the training's Ray task)."),
    obstacles: str = typer.Option("static", "--obstacles", help="Evaluation obstacles: none | static | dynamic"),
    learning_starts: Optional[int] = typer.Option(None, "--learning-starts"),
    batch_size: Optional[int] = typer.Option(None, "--batch-size"),
    buffer_size: Optional[int] = typer.Option(None, "--buffer-size"),
    ray_address: Optional[str] = typer.Option(None, "--ray-address"),
    num_cpus: Optional[int] = typer.Option(None, "--num-cpus"),
    env: str = typer.Option("pixel", "--env", help="pixel (PointNav RGB) | privileged (goal vector + ranges)"),
    eval_max_steps: Optional[int] = typer.Option(None, "--eval-max-steps", help="Evaluation episode limit."),
    as_json: bool = typer.Option(False, "--json"),
) -> None:
    """Train per (count, seed) as Ray tasks, evaluate on held-out scenes, table + PNG plot."""
    config = StudyConfig(registry=registry, out_dir=out_dir, counts=[int(c) for c in counts.split(",")],
                         seeds=seeds, split_seed=split_seed, total_steps=steps, n_envs=n_envs, trials=trials,
                         obstacles=obstacles, sac=_sac(learning_starts, batch_size, buffer_size),
                         eval_max_steps=eval_max_steps, **_study_env(env))
    _ray(ray_address, num_cpus)
    rows = run_study(config)
    if as_json:
        typer.echo(json.dumps([asdict(r) for r in rows], indent=2))
        return
    table = Table(title=f"scene-count study: {steps} env steps per run, {trials} trials per test scene")
    for col in ("scenes", "seed", "SR", "SPL", "Cost", "train s"):
        table.add_column(col)
    for r in rows:
        table.add_row(str(r.count), str(r.seed), f"{r.sr:.2f}", f"{r.spl:.2f}", f"{r.cost:.2f}", f"{r.train_wall_s:.0f}")
    Console().print(table)
    typer.echo(f"plot: {out_dir}/study.png")
