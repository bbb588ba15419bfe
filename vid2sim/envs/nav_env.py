"""`NavEnv`: PointNav / SocialNav on a registry scene (Gymnasium API).

Env contract
- `reset(seed=None, options=None) -> (obs, info)`: samples the scene (when several), start,
  goal (A* geodesic in the scene's range), camera jitter (training only). `options` may hold
  `scene_id` to force a scene. The same seed gives the same episode, observation for observation.
- `step(action) -> (obs, reward, terminated, truncated, info)`. action: float [2] in [-1, 1]:
  a[0] speed (clamped to [0, 1] x max_speed: no reverse, as the official agent), a[1] steering
  (x 30 deg). Out-of-range values are clipped; NaN or inf raise `InvalidActionError` before
  anything changes (the episode goes on with the next valid action). Once a step has returned
  terminated or truncated, further steps raise `EpisodeEndedError` until `reset()` (the
  Gymnasium contract); `step()` before a successful `reset()` raises `ResetNeededError`. A
  `reset()` that raises (e.g. `SceneError` for a scene with no free start) leaves no episode:
  the env stays usable and the next `reset()` starts afresh.
- obs: Dict `image` uint8 [6, C, 72, 128] (oldest first; C = 3 rgb / mesh-rgb, 1 depth where
  0..255 = 0..20 m), `vector` float32 [6, 2] (distance to goal in m, heading to goal / pi).
- terminated: success (<= 0.5 m from the goal), left the walkable map, > 3 collision events.
  truncated: the 3000-step limit (reward -10 as the paper, reported as truncation).
- Each episode: 0-5 obstacles on the A* corridor (`EnvConfig.obstacles`); SocialNav adds 1-4
  pedestrians (`EpisodeConfig.pedestrians`) stepped once per control step. Augmentation and
  camera jitter are on when `training` (default), off for evaluation (`training=False`).
- Render fidelity (`EnvConfig.fidelity`): "fast" (default when training: the scene's sim-ready
  set through the approximate fast kernels, 36 dB mean / 27 dB worst PSNR vs exact at the
  expert's poses on the GoPro factory scene) or
  "exact" (default for evaluation); see `envs/config.py` and `envs/simready.py`.
- info: distance, collided, collision_events, end, reward terms, scene_id; on the last step
  also `nav_episode` (a `metrics.EpisodeRecord`; not `episode`, which SB3's Monitor owns).
"""

from __future__ import annotations

import math
import time
from collections import defaultdict, deque
from dataclasses import is_dataclass, replace
from pathlib import Path
from typing import Any, Optional, Sequence, Union, get_args, get_type_hints

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from vid2sim.envs.actors import EpisodeActors
from vid2sim.envs.augment import Augmenter
from vid2sim.envs.camera import Jitter, intrinsics, world_to_camera
from vid2sim.envs.config import EnvConfig
from vid2sim.envs.episodes import Episode, sample_episode
from vid2sim.envs.metrics import EpisodeRecord
from vid2sim.envs.physics import CONTACT_EPS, SWEEP_MARGIN, RobotState
from vid2sim.envs.planning import path_length
from vid2sim.envs.rendering import depth_to_u8
from vid2sim.envs.reward import RewardTerms, StepOutcome, reward
from vid2sim.envs.scenes import SceneError, resolve_scene_ids
from vid2sim.envs.world import SceneWorld, build_world
from vid2sim.registry import Registry

TASKS = ("pointnav", "socialnav")
MAX_LOADED_SCENES = 4
START_TRIES = 32
PARTS = ("render", "physics", "obstacles", "pedestrians", "augment", "reward")


class InvalidActionError(ValueError):
    """An action with NaN or infinite entries, or of the wrong shape."""


class ResetNeededError(RuntimeError):
    """`step()` without a running episode: no `reset()` yet, or the last one raised."""


class EpisodeEndedError(ResetNeededError):
    """`step()` after the episode ended (terminated or truncated): call `reset()` first."""


class NavEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}

    def __init__(self, registry: Union[str, Path, Registry], scenes: Union[str, Sequence[str]],
                 task: str = "pointnav", config: Optional[EnvConfig] = None,
                 render_mode: Optional[str] = None, checkout_root: Optional[Union[str, Path]] = None,
                 **config_overrides: Any) -> None:
        if task not in TASKS:
            raise ValueError(f"unknown task {task!r}; known: {', '.join(TASKS)}")
        self.task = task
        self.config = _with_overrides(config or EnvConfig(), config_overrides)
        self.render_mode = render_mode
        self.registry = registry if isinstance(registry, Registry) else Registry(registry)
        self.scene_ids = resolve_scene_ids(self.registry, scenes)
        self.checkout_root = Path(checkout_root) if checkout_root else None
        self.scene_weights: Optional[np.ndarray] = None  # [n_scenes] reset's draw of the scene (None: uniform)
        self._worlds: dict[str, SceneWorld] = {}
        self.world = self._world(self.scene_ids[0])  # refuses an unusable first scene now
        c = self.config
        chans = 1 if c.variant == "depth" else 3
        self.observation_space = spaces.Dict({
            "image": spaces.Box(0, 255, (c.frame_stack, chans, c.camera.height, c.camera.width), np.uint8),
            "vector": spaces.Box(np.tile(np.array([0.0, -1.0], np.float32), (c.frame_stack, 1)),
                                 np.tile(np.array([1e4, 1.0], np.float32), (c.frame_stack, 1)),
                                 dtype=np.float32)})
        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.timings: dict[str, float] = defaultdict(float)
        self.episode: Optional[Episode] = None  # None: no running episode (step refuses)
        self.ended = False  # the last step returned terminated or truncated
        self.last_depth: Optional[np.ndarray] = None  # [H, W] m of the latest frame (inf: nothing)
        self.actors: Optional[EpisodeActors] = None
        self.augmenter = Augmenter(self.config.augmentation)
        self.K = intrinsics(self.config.camera)

    # ------------------------------------------------------------------ scenes
    def _world(self, scene_id: str) -> SceneWorld:
        if scene_id not in self._worlds:
            if len(self._worlds) >= MAX_LOADED_SCENES:
                oldest = next(iter(self._worlds))
                self._worlds.pop(oldest).close()
            self._worlds[scene_id] = build_world(self.registry, scene_id, self.config,
                                                 self.checkout_root)
        return self._worlds[scene_id]

    def set_scene_weights(self, weights: Optional[Sequence[float]]) -> None:
        """How often later resets draw each of `scene_ids` (relative weights, one per scene; None: all
        alike, the default). A reset's `options["scene_id"]` still wins."""
        if weights is None:
            self.scene_weights = None
            return
        w = np.asarray(weights, np.float64)
        if w.shape != (len(self.scene_ids),) or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
            raise ValueError(f"scene weights {list(np.atleast_1d(w))}: need {len(self.scene_ids)} finite "
                             f"non-negative weights, not all zero, one per scene of {self.scene_ids}")
        self.scene_weights = w / w.sum()

    def _draw_scene(self, rng: np.random.Generator) -> str:
        if self.scene_weights is None:
            return self.scene_ids[int(rng.integers(len(self.scene_ids)))]
        return self.scene_ids[int(rng.choice(len(self.scene_ids), p=self.scene_weights))]

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        super().reset(seed=seed)
        self.episode, self.ended = None, False  # no episode until this reset has succeeded
        if self.actors is not None:
            self.actors.remove()
            self.actors = None
        try:
            return self._start_episode(options or {})
        except BaseException:
            self.episode = None  # a failed reset leaves no half-made episode behind
            if self.actors is not None:
                self.actors.remove()
                self.actors = None
            raise

    def _start_episode(self, options: dict):
        rng = self.np_random
        scene_id = options.get("scene_id") or self._draw_scene(rng)
        self.world = self._world(scene_id)
        c = self.config
        ep = self._sample_free_start(rng, scene_id)
        self.episode = ep
        lo, hi = c.episode.pedestrians
        peds = int(rng.integers(lo, hi + 1)) if self.task == "socialnav" else 0
        self.actors = EpisodeActors(self.world.physics.client)
        inflation = self.world.assets.walkable_inflation
        self.actors.spawn(self.world.assets.walkable, self.world.planner, ep.path, rng, c.obstacles, peds,
                          pre_inflated=inflation, comfort=max(0.0, c.episode.expert_comfort - inflation))
        self.shortest = path_length(self.actors.shortest_path)
        self.augmenter.reset(rng)
        self.state = RobotState(float(ep.start[0]), float(ep.start[1]), ep.start_yaw)
        self.jitter = Jitter.sample(c.camera, rng) if c.use_jitter else Jitter.none()
        self.t = 0.0
        self.steps = 0
        self.prev_steer = 0.0
        self.prev_collided = False
        self.collision_events = self.collision_steps = self.proximity_steps = 0
        self.clear_steps = 0  # control steps whose substeps needed no contact query
        self.travelled = 0.0
        self.trace = [(self.state.x, self.state.y)]
        frame = self._frame()
        vec = self._goal_vector()
        self.frames = deque([frame] * c.frame_stack, maxlen=c.frame_stack)
        self.vectors = deque([vec] * c.frame_stack, maxlen=c.frame_stack)
        return self._obs(), self._info(None)

    def _sample_free_start(self, rng: np.random.Generator, scene_id: str) -> Episode:
        """An episode whose start pose does not touch the collision mesh (places the robot)."""
        c, phys = self.config, self.world.physics
        for _ in range(START_TRIES):
            ep = sample_episode(self.world.planner, rng, self.world.span, c.episode, scene_id,
                                self.world.ends)
            phys.place(float(ep.start[0]), float(ep.start[1]), ep.start_yaw)
            if phys.depth <= CONTACT_EPS:
                return ep
        raise SceneError("no_free_start", f"scene {scene_id!r}: {START_TRIES} sampled starts on the "
                         "walkable map all touch the collision mesh")

    def step(self, action):
        if self.ended:
            raise EpisodeEndedError("the episode has ended (terminated or truncated): call reset() "
                                    "before step()")
        if self.episode is None:
            raise ResetNeededError("no running episode: call reset() before step()")
        speed_n, steer_n = self._check_action(action)
        c = self.config
        prev_dist = self.distance()
        t_obs, t_ped = self.actors.step(1.0 / c.control_hz, (self.state.x, self.state.y))
        self.timings["obstacles"] += t_obs
        self.timings["pedestrians"] += t_ped
        t0 = time.process_time()
        collided = self._drive(speed_n * c.robot.max_speed, steer_n * c.robot.max_steer)
        t1 = time.process_time()
        self.timings["physics"] += t1 - t0
        self.steps += 1
        self.t += 1.0 / c.control_hz
        if collided and not self.prev_collided:
            self.collision_events += 1
        self.collision_steps += int(collided)
        self.prev_collided = collided
        r = c.robot
        if not collided and self.actors.near_pedestrian(
                self.state.x, self.state.y, self.state.yaw, r.length / 2, r.width / 2,
                c.episode.proximity_radius):
            self.proximity_steps += 1
        outcome = StepOutcome(prev_dist, self.distance(), abs(steer_n - self.prev_steer), speed_n,
                              collided, self.collision_events,
                              self.world.walkable.is_walkable(self.state.x, self.state.y), self.steps)
        self.prev_steer = steer_n
        terms = reward(outcome, c.reward)
        self.timings["reward"] += time.process_time() - t1
        self.frames.append(self._frame())
        self.vectors.append(self._goal_vector())
        info = self._info(terms)
        info["collided"] = collided
        if terms.end:
            info["nav_episode"] = self.record(terms.end)
        self.ended = bool(terms.terminated or terms.truncated)
        return self._obs(), float(terms.total), terms.terminated, terms.truncated, info

    def render(self) -> Optional[np.ndarray]:
        """rgb_array: the latest camera frame [H, W, 3] uint8 (depth shown as grey)."""
        if self.render_mode != "rgb_array" or self.episode is None:
            return None
        f = self.frames[-1]
        return np.repeat(f, 3, 0).transpose(1, 2, 0) if f.shape[0] == 1 else f.transpose(1, 2, 0)

    def close(self) -> None:
        if self.actors is not None:
            self.actors.remove()
            self.actors = None
        for w in self._worlds.values():
            w.close()
        self._worlds.clear()

    # ------------------------------------------------------------------ internals
    def _check_action(self, action) -> tuple[float, float]:
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (2,):
            raise InvalidActionError(f"action must have 2 entries (speed, steering), got shape "
                                     f"{np.shape(action)}")
        if not np.isfinite(a).all():
            raise InvalidActionError(f"action must be finite, got {a.tolist()}")
        a = np.clip(a, -1.0, 1.0)
        return float(max(a[0], 0.0)), float(a[1])

    def _drive(self, speed: float, steer: float) -> bool:
        """Physics substeps for one control step; True when any substep was blocked."""
        c = self.config
        dt = 1.0 / c.physics_hz
        if c.sweep_check and self._drive_clear(speed, steer, dt):
            return False
        collided = False
        for _ in range(c.substeps):
            x0, y0 = self.state.x, self.state.y
            self.state, hit = self.world.physics.step(self.state, speed, steer, dt)
            collided |= bool(hit)
            self.travelled += math.hypot(self.state.x - x0, self.state.y - y0)
        self.trace.append((self.state.x, self.state.y))
        return collided

    def _drive_clear(self, speed: float, steer: float, dt: float) -> bool:
        """The control step's substeps without contact queries, when the box stays clear of
        everything for all of them (one `clear_within` query at the start pose): the same
        poses, travel and (no) contact as the substep loop. False (nothing done) otherwise."""
        phys, s0 = self.world.physics, self.state
        if phys.depth > 0.0:
            return False
        poses, st, reach = [], s0, 0.0
        for _ in range(self.config.substeps):
            x, y, yaw = phys.propose(st, speed, steer, dt)
            st = RobotState(x, y, yaw, speed, steer)
            poses.append(st)
            reach = max(reach, phys.reach_of(s0.x, s0.y, s0.yaw, x, y, yaw))
        if not phys.clear_within(reach + SWEEP_MARGIN):
            return False
        for p in poses:
            self.travelled += math.hypot(p.x - s0.x, p.y - s0.y)
            s0 = p
        phys.move_free(st.x, st.y, st.yaw)
        self.state = st
        self.clear_steps += 1
        self.trace.append((st.x, st.y))
        return True

    def _frame(self) -> np.ndarray:
        """Camera image [C, H, W] uint8 at the current pose."""
        t0 = time.process_time()
        c = self.config
        w2c = world_to_camera(self.state.x, self.state.y, self.state.yaw, c.camera,
                              self.jitter.at(self.t))
        self.last_world_to_cam = w2c  # [4, 4], the pose of the latest frame
        rgb, depth = self.world.view.draw(w2c)
        self.timings["render"] += time.process_time() - t0
        rgb, depth, t_obs, t_ped = self.actors.draw_over(rgb, depth, self.K, w2c)
        self.last_depth = depth  # [H, W] m (inf: nothing), the latest frame's depth, actors included
        self.timings["obstacles"] += t_obs
        self.timings["pedestrians"] += t_ped
        if c.variant == "depth":
            return depth_to_u8(depth, c.camera.depth_max)[None]
        t0 = time.process_time()
        rgb = self.augmenter.apply(rgb, depth)
        self.timings["augment"] += time.process_time() - t0
        return np.ascontiguousarray(rgb.transpose(2, 0, 1))

    def distance(self) -> float:
        g = self.episode.goal
        return math.hypot(g[0] - self.state.x, g[1] - self.state.y)

    def _goal_vector(self) -> np.ndarray:
        g = self.episode.goal
        bearing = math.atan2(g[1] - self.state.y, g[0] - self.state.x) - self.state.yaw
        heading = (bearing + math.pi) % (2 * math.pi) - math.pi
        return np.array([self.distance(), heading / math.pi], np.float32)

    def _obs(self) -> dict[str, np.ndarray]:
        return {"image": np.stack(self.frames), "vector": np.stack(self.vectors)}

    def _info(self, terms: Optional[RewardTerms]) -> dict[str, Any]:
        info: dict[str, Any] = {"scene_id": self.episode.scene_id, "distance": self.distance(),
                                "geodesic": self.episode.geodesic, "steps": self.steps,
                                "collision_events": self.collision_events, "end": ""}
        if terms is not None:
            info.update(end=terms.end, reward_terms={
                "terminal": terms.terminal, "distance": terms.distance, "steer": terms.steer,
                "crash": terms.crash, "time": terms.time})
        return info

    def record(self, end: str) -> EpisodeRecord:
        """Metrics record of the episode so far."""
        return EpisodeRecord(success=end == "success", shortest_length=self.shortest,
                             path_length=self.travelled, collision_events=self.collision_events,
                             collision_steps=self.collision_steps,
                             proximity_steps=self.proximity_steps, steps=self.steps, end=end,
                             start_pose=(float(self.episode.start[0]), float(self.episode.start[1]),
                                         float(self.episode.start_yaw)),
                             goal=(float(self.episode.goal[0]), float(self.episode.goal[1])),
                             end_pose=tuple(float(v) for v in self.robot_pose()))

    def expert_path(self) -> np.ndarray:
        """A* waypoints [K, 2] the scripted expert follows (obstacles avoided; the comfortable route
        when `EpisodeConfig.expert_comfort` is set)."""
        return self.actors.expert_path

    def replan_expert_path(self) -> Optional[np.ndarray]:
        """Re-plan the expert's A* path from the robot's position (None: no path from here)."""
        return self.actors.replan(self.state.x, self.state.y)

    def robot_pose(self) -> tuple[float, float, float]:
        return self.state.x, self.state.y, self.state.yaw

    def topdown_state(self) -> dict[str, Any]:
        """What the recorder draws (`RecordEpisode`'s top-down state); positions in metres, world frame."""
        w = self.world
        return {"grid": w.assets.walkable.grid, "origin": w.assets.walkable.origin,
                "resolution": w.assets.walkable.resolution,
                "robot_xy": np.array([self.state.x, self.state.y]), "robot_yaw": self.state.yaw,
                "path": np.array(self.trace), "planned_path": self.episode.path,
                "goal": np.asarray(self.episode.goal), "obstacles": self.actors.obstacle_xy(),
                "pedestrians": self.actors.pedestrian_xy()}


def _with_overrides(conf: Any, overrides: dict[str, Any]) -> Any:
    """conf with fields replaced; a dict given for a nested config replaces fields of it (so a
    JSON-saved run can set e.g. `episode={"expert_comfort": 0.8}`), and builds that config from its
    defaults where the field holds None (`augment={"enabled": False}`)."""
    if not overrides:
        return conf
    nested = {k: _with_overrides(inner, v) for k, v in overrides.items()
              if isinstance(v, dict) and (inner := _nested_config(conf, k)) is not None}
    return replace(conf, **{**overrides, **nested})


def _nested_config(conf: Any, name: str) -> Any:
    """The dataclass config in field `name` of `conf` (its type's defaults where it holds None), else None."""
    value = getattr(conf, name, None)
    if value is not None:
        return value if is_dataclass(value) else None
    hint = get_type_hints(type(conf)).get(name)
    kinds = [t for t in (get_args(hint) or (hint,)) if isinstance(t, type) and is_dataclass(t)]
    return kinds[0]() if kinds else None
