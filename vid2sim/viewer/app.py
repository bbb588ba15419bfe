"""The viewer application: a scene, an episode in its scene, or a registry page, served by viser.

`open_viewer(...)` starts the server and returns a `Viewer` (the tests drive it); `serve` blocks
until Ctrl-C. Reads bundles (or registry checkouts) and episode files; writes checkouts only.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import viser

from vid2sim.viewer.episode import resolve_episode
from vid2sim.viewer.episode_view import EpisodePlayer, show_episode
from vid2sim.viewer.errors import ViewerError
from vid2sim.viewer.layers import SceneLayers, load_layers, missing_summary
from vid2sim.viewer.registry_page import show_registry
from vid2sim.viewer.scene_view import SceneView, show_scene
from vid2sim.viewer.server import DEFAULT_PORT, start_server, url
from vid2sim.viewer.source import open_registry, resolve_bundle
from vid2sim.viewer.splats import DEFAULT_BUDGET


@dataclass
class Viewer:
    server: viser.ViserServer
    url: str
    layers: Optional[SceneLayers] = None
    scene: Optional[SceneView] = None
    player: Optional[EpisodePlayer] = None
    registry_gui: list = field(default_factory=list)
    messages: list[str] = field(default_factory=list)  # what the viewer said (missing layers, ...)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def show(self, layers: SceneLayers, hidden: tuple[str, ...] = ()) -> None:
        """Replace the shown scene with `layers` (a notification names any missing layer)."""
        with self._lock:
            if self.scene is not None:
                self.scene.remove()
            self.layers, self.scene = layers, show_scene(self.server, layers, hidden)
            self.messages.clear()  # they speak of the scene shown
            if layers.missing:
                msg = f"{layers.scene_id}: showing what is there; missing {missing_summary(layers)}"
                self.messages.append(msg)
                self.notify("Missing layers", msg, "yellow")

    def notify(self, title: str, body: str, color: str) -> None:
        """A notification in every open browser tab."""
        for client in self.server.get_clients().values():
            client.add_notification(title, body, auto_close_seconds=None, color=color)

    def stop(self) -> None:
        if self.player is not None and self.player.frames is not None:
            self.player.frames.close()
        self.server.stop()


def _opener(viewer: Viewer, registry: Optional[str], budget: int, checkouts: Optional[Path]
            ) -> Callable[[str], None]:
    def open_scene(scene_id: str) -> None:
        try:
            viewer.show(load_layers(resolve_bundle(scene_id, registry, checkouts), budget))
        except ViewerError as e:
            viewer.notify("Cannot open scene", str(e), "red")
    return open_scene


def open_viewer(target: Optional[str] = None, *, registry: Optional[str] = None, episode: Optional[Path] = None,
                episode_index: int = 0, port: int = DEFAULT_PORT, host: str = "127.0.0.1",
                budget: int = DEFAULT_BUDGET, checkouts: Optional[Path] = None) -> Viewer:
    """Start the viewer on a scene (folder or id), an episode, or (neither) the registry page.

    Every input is resolved before the port is taken, so bad input fails without a server.
    Registry scenes are checked out under `checkouts` (default $VID2SIM_CHECKOUTS)."""
    source = resolve_episode(episode, episode_index) if episode is not None else None
    layers, reg = None, None
    if source is not None:
        registry = registry or source.registry
        layers = load_layers(resolve_bundle(target or source.trace.scene_id, registry, checkouts), budget)
    elif target is not None:
        layers = load_layers(resolve_bundle(target, registry, checkouts), budget)
    else:
        reg = open_registry(registry)
    server = start_server(host, port, label="vid2sim")
    viewer = Viewer(server, url(server))

    @server.on_client_connect
    def _(client: viser.ClientHandle) -> None:  # a tab opened later still hears about missing layers
        for msg in viewer.messages:
            client.add_notification("Missing layers", msg, auto_close_seconds=None, color="yellow")
    if layers is not None:
        viewer.show(layers, hidden=("collision mesh", "camera path") if source is not None else ())
    if source is not None:
        viewer.player = show_episode(server, source)
    if reg is not None:
        viewer.registry_gui = show_registry(server, reg, _opener(viewer, str(reg.root), budget, checkouts))
    return viewer


def serve(viewer: Viewer, echo: Callable[[str], None] = print) -> None:
    """Print where the viewer is and block until interrupted."""
    for msg in viewer.messages:
        echo(f"warning: {msg}")
    echo(f"viewer: {viewer.url}  (Ctrl-C stops it)")
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()


__all__ = ["Viewer", "open_viewer", "serve"]
