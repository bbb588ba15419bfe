"""Episode replay in a viser scene: the robot's box along its path, the planned and taken paths,
obstacles and pedestrians, the goal, collisions marked in red, the robot's camera view in the
GUI panel beside the 3-D view, and a step slider with Play / Pause. Reads the episode MP4 for
the camera view (`VideoFrames`); writes nothing."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import viser

from vid2sim.formats.episode_trace import EpisodeTrace
from vid2sim.viewer.episode import EpisodeSource, VideoFrames

ROBOT_RGB = (250, 200, 0)
COLLIDED_RGB = (230, 30, 30)
GOAL_RGB = (220, 30, 30)
TAKEN_RGB = (40, 190, 40)
PLANNED_RGB = (30, 120, 220)
OBSTACLE_RGB = (250, 120, 20)
PEDESTRIAN_RGB = (200, 40, 200)
OBSTACLE_SIZE = (0.5, 0.5, 0.8)  # m, marker box of an obstacle
PEDESTRIAN_SIZE = (0.5, 0.5, 1.7)  # m, marker box of a pedestrian
MARK_Z = 0.05  # m, paths and marks above the ground


def yaw_wxyz(yaw: float) -> tuple[float, float, float, float]:
    return (float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2)))


def _lift(xy: np.ndarray, z: float = MARK_Z) -> np.ndarray:
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    return np.concatenate([xy, np.full((len(xy), 1), z)], 1)


@dataclass
class EpisodePlayer:
    """The replay's scene nodes, GUI and playback state."""

    server: viser.ViserServer
    source: EpisodeSource
    robot: viser.BoxHandle
    slider: viser.GuiSliderHandle
    play: viser.GuiButtonHandle
    status: viser.GuiMarkdownHandle
    camera: Optional[viser.GuiImageHandle]
    frames: Optional[VideoFrames]
    actors: list = field(default_factory=list)
    playing: bool = False
    _lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def trace(self) -> EpisodeTrace:
        return self.source.trace

    def show_step(self, k: int) -> None:
        """Move the robot, obstacles and pedestrians to step k and show its camera frame."""
        t = self.trace
        k = int(np.clip(k, 0, t.steps - 1))
        with self._lock, self.server.atomic():
            x, y = t.xy[k]
            self.robot.position = (x, y, t.robot["height_m"] / 2)
            self.robot.wxyz = yaw_wxyz(t.yaw[k])
            self.robot.color = COLLIDED_RGB if t.collided[k] else ROBOT_RGB
            self._actors(k)
            hits = int(np.sum(t.collided[: k + 1]))
            self.status.content = (f"step **{k}** / {t.steps - 1} ({k / t.fps:.1f} s) · contacts so far: "
                                   f"**{hits}** · end: **{t.end or '-'}**")
            if self.frames is not None and self.camera is not None:
                img = self.frames.frame(k)
                if img is not None:
                    self.camera.image = img

    def _actors(self, k: int) -> None:
        t = self.trace
        want = [(p, OBSTACLE_RGB, OBSTACLE_SIZE) for p in t.obstacles[k]]
        want += [(p, PEDESTRIAN_RGB, PEDESTRIAN_SIZE) for p in t.pedestrians[k]]
        while len(self.actors) < len(want):
            i = len(self.actors)
            self.actors.append(self.server.scene.add_box(f"/episode/actors/{i}", color=want[i][1],
                                                         dimensions=want[i][2]))
        for i, node in enumerate(self.actors):
            node.visible = i < len(want)
            if i < len(want):
                (x, y), color, size = want[i]
                node.position, node.color, node.dimensions = (x, y, size[2] / 2), color, size

    def run(self) -> None:
        """Playback loop (a daemon thread): advances the slider at the episode's fps while playing."""
        while True:
            time.sleep(1.0 / max(self.trace.fps, 1.0))
            if self.playing:
                nxt = self.slider.value + 1
                if nxt >= self.trace.steps:
                    self.playing = False
                    self.play.label = "Play"
                else:
                    self.slider.value = nxt


def _static_marks(server: viser.ViserServer, t: EpisodeTrace) -> None:
    if len(t.planned_path) >= 2:
        server.scene.add_spline_catmull_rom("/episode/planned_path", _lift(t.planned_path), color=PLANNED_RGB,
                                            thickness=0.04)
    if t.steps >= 2:
        server.scene.add_line_segments("/episode/taken_path", np.stack([_lift(t.xy[:-1]), _lift(t.xy[1:])], 1),
                                       colors=TAKEN_RGB, thickness=0.06)
    server.scene.add_icosphere("/episode/goal", radius=0.3, color=GOAL_RGB, position=tuple(_lift(t.goal, 0.3)[0]))
    hits = np.asarray(t.xy, np.float64)[np.asarray(t.collided, bool)]
    if len(hits):
        server.scene.add_point_cloud("/episode/collisions", _lift(hits, 0.1).astype(np.float32),
                                     colors=COLLIDED_RGB, point_size=0.25, point_shape="circle")


def look_at_episode(server: viser.ViserServer, t: EpisodeTrace) -> None:
    """Initial camera: above and behind the episode's start, its path and goal in view."""
    pts = np.concatenate([np.asarray(t.xy, np.float64), np.asarray(t.goal, np.float64).reshape(1, 2)])
    centre = np.append((pts.min(0) + pts.max(0)) / 2, 0.0)
    span = max(float(np.linalg.norm(pts.max(0) - pts.min(0))), 6.0)
    heading = np.asarray(t.goal, np.float64) - np.asarray(t.xy[0], np.float64)
    back = -heading / max(float(np.linalg.norm(heading)), 1e-6)
    server.initial_camera.look_at = tuple(centre)
    server.initial_camera.position = tuple(centre + np.append(back * 0.7 * span, 0.6 * span))


def show_episode(server: viser.ViserServer, source: EpisodeSource) -> EpisodePlayer:
    """Add the replay to the scene and its controls to the GUI; starts at step 0."""
    t = source.trace
    _static_marks(server, t)
    look_at_episode(server, t)
    r = t.robot
    robot = server.scene.add_box("/episode/robot", color=ROBOT_RGB,
                                 dimensions=(r["length_m"], r["width_m"], r["height_m"]))
    folder = server.gui.add_folder("Episode", order=-1)
    with folder:
        frames = VideoFrames(source.video, t.view_width_px) if source.video else None
        first = frames.frame(0) if frames else None
        camera = server.gui.add_image(first, label="robot camera") if first is not None else None
        if camera is None:
            server.gui.add_markdown(f"*no camera view: the episode video is missing beside {source.trace_file}*")
        status = server.gui.add_markdown("")
        slider = server.gui.add_slider("step", min=0, max=max(t.steps - 1, 1), step=1, initial_value=0)
        play = server.gui.add_button("Play")
    player = EpisodePlayer(server, source, robot, slider, play, status, camera, frames)

    @slider.on_update
    def _(_event) -> None:
        player.show_step(slider.value)

    @play.on_click
    def _(_event) -> None:
        if not player.playing and slider.value >= t.steps - 1:
            slider.value = 0
        player.playing = not player.playing
        play.label = "Pause" if player.playing else "Play"

    player.show_step(0)
    threading.Thread(target=player.run, daemon=True, name="episode-playback").start()
    return player
