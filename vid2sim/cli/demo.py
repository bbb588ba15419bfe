"""The end of `vid2sim demo`: one episode of the scripted expert in the new scene (an MP4 of its
camera view beside the top-down map, and the trace the viewer replays), then the commands that
open the scene and the episode in the viewer.

Reads the registry (checks the scene out under $VID2SIM_CHECKOUTS); writes
WORKDIR/episode/episode-0.mp4 and episode-0.trace.json.
"""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Callable, Optional


def demo_episode(registry: str, scene_id: str, out: Path, seed: int = 0) -> Path:
    """Drive the scripted expert through `scene_id` for one PointNav episode -> the MP4 path."""
    import gymnasium

    import vid2sim.envs  # noqa: F401  (registers the env ids)
    from vid2sim.envs.expert import PurePursuitExpert
    from vid2sim.envs.recording import record_episodes

    env = gymnasium.make("vid2sim/PointNav-v0", registry=registry, scenes=scene_id, training=False)
    try:
        return record_episodes(env, out, 1, PurePursuitExpert(), seed=seed)[0]
    finally:
        env.close()


def viewer_commands(registry: str, scene_id: str, trace: Optional[Path]) -> list[str]:
    """The shell commands that open the scene (and the episode) in the viewer."""
    reg = shlex.quote(str(registry))
    cmds = [f".venv/bin/vid2sim view {shlex.quote(scene_id)} --registry {reg}"]
    if trace is not None:
        cmds.append(f".venv/bin/vid2sim view --episode {shlex.quote(str(trace))} --registry {reg}")
    return cmds


def finish_demo(scene_id: str, registry: Optional[str], workdir: str, echo: Callable[[str], None] = print) -> Path:
    """Record the demo episode and print where it is and how to look at it."""
    from vid2sim.formats.episode_trace import trace_path
    from vid2sim.registry.store import default_root

    root = str(Path(registry or default_root()).resolve()) if "://" not in str(registry or "") else str(registry)
    video = demo_episode(root, scene_id, Path(workdir).resolve() / "episode")
    trace = trace_path(video)
    echo(f"episode (scripted expert, camera view + top-down map): {video}")
    echo("open the scene and the episode in the browser viewer:")
    for cmd in viewer_commands(root, scene_id, trace if trace.is_file() else None):
        echo(f"  {cmd}")
    return video
