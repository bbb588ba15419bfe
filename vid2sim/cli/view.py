"""`vid2sim view`: the browser viewer for a scene, an episode or a registry."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer


def view_command(
    scene: Optional[str] = typer.Argument(None, help="Scene id (SCENE or SCENE@VERSION) or bundle folder; "
                                                     "none: the registry page."),
    registry: Optional[str] = typer.Option(None, "--registry",
                                           help="Registry root (default $VID2SIM_REGISTRY or ./vid2sim-registry)."),
    episode: Optional[Path] = typer.Option(None, "--episode",
                                           help="Replay an episode: its .trace.json, its MP4, or an `eval policy "
                                                "--record N --out REPORT.json` report."),
    index: int = typer.Option(0, "--index", min=0,
                              help="Which recorded episode of an evaluation report (0-based)."),
    port: int = typer.Option(8080, "--port", min=1, max=65535, help="Port to serve on."),
    host: str = typer.Option("127.0.0.1", "--host", help="Interface to listen on (0.0.0.0: every interface)."),
    max_splats: int = typer.Option(400_000, "--max-splats", min=1,
                                   help="Splat budget: at most this many Gaussians go to the browser (the ones "
                                        "with the largest opacity x area)."),
) -> None:
    """Splats, collision mesh, walkable map, camera path, metric grid and scene card in the browser."""
    from vid2sim.viewer.app import open_viewer, serve

    # bad input (unknown scene, no layer at all, port in use, unreadable episode) raises a ViewerError:
    # exit 2 with one line naming it (vid2sim.cli.errors)
    viewer = open_viewer(scene, registry=registry, episode=episode, episode_index=index, port=port, host=host,
                         budget=max_splats)
    serve(viewer, typer.echo)
