"""Configuration of the navigation envs: robot, camera, reward, episodes, task.

The robot's size, bicycle model and camera mount / intrinsics are the project's one robot
spec (`vid2sim.formats.robot.ROBOT`, shared with the factory, recorded in each bundle's
scene.json): `RobotConfig` and `CameraConfig` take their defaults from it.

Constants and where they come from:
- Bicycle model, 0.8 m wheelbase, 30 deg maximum steering: the paper's appendix (simulation
  set-up). The official Unity `CocoAgent` multiplies steer by 60 deg and halves the yaw rate;
  we follow the paper (yaw rate = v / L x tan(delta)).
- Top speed 1.0 m/s: the official agent's speed = move x 1 m/s with move clamped to [0, 1]
  (no reverse); a delivery robot's sidewalk speed.
- Footprint: a 0.9 m x 0.6 m x 0.6 m box (length x width x height) centred on the bicycle
  model's reference point, from 0.15 m to 0.75 m above the ground.
- Camera: at the front of the box, 0.65 m above the ground, looking forward, level. The paper
  gives no intrinsics, only the 1280x720 sensor; we use Unity's default 60 deg vertical field
  of view at 1280x720 (fx = fy = 623.5 px), scaled to 128x72 (fx = fy = 62.35, cx = 64, cy = 36).
- Camera jitter per episode (official Unity code): sinusoidal, position amplitude U(0, 0.02) m
  per axis, rotation amplitude U(0, 0.3) deg (x5 for roll), frequency U(2, 10) Hz, random phase;
  on for training, off for evaluation.
- Physics at 50 Hz, control at 5 Hz (10 physics substeps per action): the paper's appendix.
- Render fidelity (`EnvConfig.fidelity`): "exact" renders the bundle's splats as they are
  (`vid2sim.splats` StaticScene); "fast" renders the scene's sim-ready set (pruned to
  `FastRenderConfig.keep_mass` of the measured blend weight over robot views, one baked colour
  per splat, optionally fitted to exact renders of those views, opaque early stop at `t_stop`;
  kept on disk beside the checkouts) with the approximate fast kernels
  (`splats/cpu/env_fast_batch.py`), made once per scene at load (`envs/simready.py`). Default: fast
  for training (throughput), exact for evaluation (`training=False`: the figures reported).
  What fast trades is measured as PSNR against exact by `benchmarks/envs.py`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, Optional, Sequence, Union

from vid2sim.envs.augment import AugmentConfig
from vid2sim.envs.obstacles import ObstacleConfig
from vid2sim.formats.robot import ROBOT
from vid2sim.ranges import checked

Variant = Literal["rgb", "depth", "mesh-rgb"]
VARIANTS: tuple[str, ...] = ("rgb", "depth", "mesh-rgb")
FIDELITIES: tuple[str, ...] = ("exact", "fast")


@checked
@dataclass(frozen=True)
class RobotConfig:
    wheelbase: float = ROBOT.wheelbase_m  # m, bicycle-model wheelbase (paper)
    max_steer_deg: float = ROBOT.max_steer_deg  # deg, maximum steering angle (paper; official code: 60)
    max_speed: float = ROBOT.max_speed_mps  # m/s, top speed (official CocoAgent: move x 1 m/s)
    length: float = ROBOT.length_m  # m, footprint box length
    width: float = ROBOT.width_m  # m, footprint box width
    height: float = ROBOT.height_m  # m, footprint box height
    ground_clearance: float = ROBOT.ground_clearance_m  # m, box bottom above z = 0. Factory scenes agree with it
    # by construction: the physical layer (factory/geometry/walkable.py) drops collision geometry
    # lower than its step (0.1 m, raised to the ground noise) and blocks the map under every
    # other face below 1.8 m, so no walkable cell has mesh in this box's band; kerb drops are
    # blocked on the map (leaving it ends the episode)

    @property
    def max_steer(self) -> float:
        return math.radians(self.max_steer_deg)


@checked
@dataclass(frozen=True)
class CameraConfig:
    width: int = ROBOT.camera_width_px  # px, observation image width
    height: int = ROBOT.camera_height_px  # px, observation image height
    vfov_deg: float = ROBOT.camera_vfov_deg  # deg, vertical field of view (Unity default camera at 1280x720)
    mount_height: float = ROBOT.camera_height_m  # m above the ground
    mount_forward: float = ROBOT.camera_forward_m  # m ahead of the robot centre (the box's front face)
    near: float = 0.05  # m, near clipping distance
    far: float = 100.0  # m, far clipping distance
    cov_cull_alpha: float = 0.01  # screen-space covariance culling (paper appendix)
    depth_max: float = 20.0  # m, depth observation saturates here (uint8 = 255)
    jitter_pos: float = 0.02  # m, largest position jitter amplitude (per axis)
    jitter_rot_deg: float = 0.3  # deg, largest rotation jitter amplitude (roll: x 5)
    jitter_freq: tuple[float, float] = (2.0, 10.0)  # Hz, range the jitter frequency is drawn from

    @property
    def focal(self) -> float:
        return 0.5 * self.height / math.tan(math.radians(self.vfov_deg) / 2)


@checked
@dataclass(frozen=True)
class RewardConfig:
    """The paper's appendix: R = R_term + c1 R_dist + c2 R_steer + c3 R_crash + c4 R_time."""

    success: float = 10.0  # terminal reward on reaching the goal
    failure: float = -10.0  # terminal reward on failure (too many collisions, off the map, time out)
    c_dist: float = 1.0  # x (d_{t-1} - d_t)
    c_steer: float = 0.05  # x |steer_t - steer_{t-1}| x speed (normalised units)
    c_crash: float = 1.0  # per control step in collision
    c_time: float = 0.1  # per control step
    success_radius: float = 0.5  # m, the goal counts as reached within this distance
    max_collisions: int = 3  # failure when exceeded
    max_steps: int = 3000  # truncated with the failure reward


@checked
@dataclass(frozen=True)
class EpisodeConfig:
    geodesic_range: tuple[float, float] = (10.0, 30.0)  # m, start-goal geodesic distance range (paper)
    min_geodesic: float = 5.0  # m, shortest start-goal distance (paper: real-world range); smaller maps are refused
    # m kept from blocked cells by episodes and the expert (robot half-width 0.3 + tracking
    # margin), minus what the factory already inflated the map by (its robot_radius_m)
    clearance: float = 0.45
    # m kept from blocked cells by the start and the goal (same convention): the box's
    # half-diagonal (0.54 m) and a margin, so the robot touches nothing at the start whatever
    # its yaw and is not sent into spurs narrower than it can turn in (its turning circle is
    # 1.4 m); a map with no such cell falls back to `clearance`
    end_clearance: float = 0.6
    # m the expert's route prefers to keep from blocked cells (same convention; 0 or <= clearance:
    # the shortest path): cells closer cost more to cross (envs/planning.py), so the route runs
    # down the middle of a narrow sidewalk and a driver that strays from it still has room
    expert_comfort: float = 0.0
    start_yaw_noise_deg: float = 15.0  # deg, start heading: towards the path, plus up to this much noise
    pedestrians: tuple[int, int] = (1, 4)  # inclusive range per SocialNav episode (PointNav: none)
    proximity_radius: float = 0.2  # m, for the proximity-aware SNS


@checked
@dataclass(frozen=True)
class FastRenderConfig:
    """The fast render path (fidelity "fast"): sim-ready set and early stop.

    keep_mass: fraction of the measured blend weight the kept splats carry; fit_iterations:
    Adam steps fitting them to exact renders (0: none; ~1 min of one core per scene, paid once:
    the result is kept on disk, see envs/simready.py); views / seed: robot views the set is measured
    on (at least views_per_m2 per square metre of walkable map); t_stop: a pixel stops once its
    transmittance is below this (renormalised); cell_size: splats per culling cell;
    view_keep_mass / view_radius / view_heading_deg: view sets (`splats/cpu/env_view_sets.py`):
    each measured view keeps the splats carrying view_keep_mass of its own blend weight, and a
    frame draws the union of the sets of the measured views within view_radius of its camera
    looking within view_heading_deg of its direction (view_keep_mass 0: every frame draws the
    whole set)."""

    # GoPro factory scene (82k splats; PSNR vs exact at the scripted expert's poses, mean /
    # worst): keep 0.98 of the blend weight measured on 1024 views 36.3 / 27.1 dB (0.97: 34.6 /
    # 25.2; 0.99: 38.0 / 29.6); keep 0.85 + a 600-step colour fit on 256 views (the former
    # default) 28.5 / 19.2 dB: foliage and sky detail lives in many small splats, which pruning
    # drops and a fit cannot restore in views it was not fitted on
    keep_mass: float = 0.98  # fraction of the measured blend weight the kept splats carry
    fit_iterations: int = 0  # Adam steps fitting the kept splats' colours to exact renders (0: none)
    views: int = 1024  # robot views the sim-ready set is measured and fitted on
    seed: int = 0  # seed of those views
    t_stop: float = 0.05  # a pixel stops once its transmittance is below this (renormalised)
    cell_size: int = 64  # splats per culling cell (at most 64 with view sets)
    # View sets pay on large factory scenes, not on small ones, so they are opt-in. The expert's
    # poses (PSNR vs exact, mean / worst; render CPU ms per step): GoPro factory scene (48k
    # sim-ready splats) without 35.4 / 34.6 dB, 2.24 ms; view sets of 0.98 within 1.0 m / 30 deg
    # 34.9 / 34.1, 1.65-1.73 (a frame draws ~18k of the ~27k splats in its frustum); 0.99 within
    # 1.25 m / 35 deg 35.2 / 34.3, 1.74-2.05; 0.95 33.9 / 33.4, 1.43-1.52. A 20k-splat ground-truth
    # street: without 33.7 / 27.8 dB, 0.58 ms; with 0.98 32.4 / 28.0, 0.54 ms, and ~25 s more to
    # measure its 11.5k views (288 m^2 of map). A gentler set, 0.99 within 1.5 m / 40 deg from
    # 10 views per m^2: GoPro 35.2 / 34.3 dB, 1.76 ms; demo 38.7 / 35.6 dB (-0.05), 1.8 vs 2.0 ms;
    # the street 33.1 / 28.3 dB, 0.50 ms, 2.9k views
    view_keep_mass: float = 0.0  # each measured view's own set carries this of its weight (0: off)
    view_radius: float = 1.0  # m, a frame unites the sets of the measured views this close ...
    view_heading_deg: float = 30.0  # deg, ... looking within this angle of its own direction
    views_per_m2: float = 40.0  # with view sets: measured views per m^2 of walkable map (at least `views`)


@checked
@dataclass(frozen=True)
class EnvConfig:
    """Everything a NavEnv needs besides the scene source."""

    variant: str = "rgb"  # observation: "rgb" | "depth" (oracle) | "mesh-rgb" (baseline)
    frame_stack: int = 6  # observations stacked per step
    physics_hz: int = 50  # Hz, physics rate (a multiple of control_hz)
    control_hz: int = 5  # Hz, action rate
    training: bool = True  # camera jitter and augmentation on; False = evaluation
    jitter: Optional[bool] = None  # None: follows `training`
    robot: RobotConfig = field(default_factory=RobotConfig)  # bicycle model and footprint box
    camera: CameraConfig = field(default_factory=CameraConfig)  # the robot's camera and its jitter
    reward: RewardConfig = field(default_factory=RewardConfig)  # reward terms and episode limits
    episode: EpisodeConfig = field(default_factory=EpisodeConfig)  # start / goal sampling and clearances
    obstacles: ObstacleConfig = field(default_factory=ObstacleConfig)  # 0-5 on the corridor
    augment: Optional[AugmentConfig] = None  # None: enabled iff training
    lod: bool = False  # splat octree level of detail (approximate; exact fidelity only)
    fidelity: Optional[str] = None  # "exact" | "fast"; None: fast when training, else exact
    # one contact query per control step when the robot box stays clear of everything over all
    # its substeps (same result as the 10 substep queries; physics.clear_within); False: always
    # query each substep
    sweep_check: bool = True
    fast: FastRenderConfig = field(default_factory=FastRenderConfig)

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise ValueError(f"unknown variant {self.variant!r}; known: {', '.join(VARIANTS)}")
        if self.physics_hz % self.control_hz:
            raise ValueError("physics_hz must be a multiple of control_hz")
        if self.fidelity is not None and self.fidelity not in FIDELITIES:
            raise ValueError(f"unknown fidelity {self.fidelity!r}; known: {', '.join(FIDELITIES)}")

    @property
    def substeps(self) -> int:
        return self.physics_hz // self.control_hz

    @property
    def render_fidelity(self) -> str:
        """"fast" or "exact" (see the module docstring); mesh-rgb ignores it."""
        return self.fidelity or ("fast" if self.training else "exact")

    @property
    def use_jitter(self) -> bool:
        return self.training if self.jitter is None else self.jitter

    @property
    def augmentation(self) -> AugmentConfig:
        return self.augment if self.augment is not None else AugmentConfig(enabled=self.training)


SceneSource = Union[str, Sequence[str]]
