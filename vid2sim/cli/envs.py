"""`vid2sim envs ...`: navigation environments (record episodes of the scripted expert)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

app = typer.Typer(help="Navigation environments on registry scenes.", no_args_is_help=True)


@app.command("record")
def record(
    scene: str = typer.Argument(..., help="Scene id, or split:train / split:test / split:train_N."),
    episodes: int = typer.Option(1, "--episodes", min=1, help="Episodes to record (seeds seed, seed+1, ...)."),
    registry: Optional[str] = typer.Option(None, "--registry",
                                           help="Registry root (default $VID2SIM_REGISTRY or ./vid2sim-registry)."),
    out: Path = typer.Option(Path("vid2sim-recordings"), "--out", help="Folder for the MP4 files."),
    task: str = typer.Option("PointNav", "--task", help="PointNav | SocialNav"),
    variant: str = typer.Option("rgb", "--variant", help="rgb | depth | mesh-rgb"),
    seed: int = typer.Option(0, "--seed", min=0),
) -> None:
    """MP4s of the scripted expert: the robot's view beside a top-down map."""
    import gymnasium

    from vid2sim.cli.inputs import creatable_folder, registry_root

    registry = registry_root(registry)
    creatable_folder(str(out), "--out")

    import vid2sim.envs  # noqa: F401  (registers the env ids)
    from vid2sim.envs.expert import PurePursuitExpert
    from vid2sim.envs.recording import record_episodes

    env = gymnasium.make(f"vid2sim/{task}-v0", registry=registry, scenes=scene,
                         variant=variant, training=False)
    paths = record_episodes(env, out, episodes, PurePursuitExpert(), seed=seed)
    env.close()
    for p in paths:
        typer.echo(str(p))
