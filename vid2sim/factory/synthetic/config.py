"""Configuration of the synthetic street: layout, camera, walking motion, outputs."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from vid2sim.ranges import checked


@checked
@dataclass(frozen=True)
class StreetConfig:
    """One procedural street and the hand-held walk through it.

    World frame: metric metres, z up, sidewalk surface at z = 0 (the ground plane),
    walking direction +x, facades on the left (+y), road on the right (-y, z = -kerb_height).
    """

    seed: int = 0
    # --- layout ---
    length_m: float = 20.0  # street length the walk covers (geometry extends beyond it)
    margin_m: float = 25.0  # extra street before/after so the view never ends in a void
    sidewalk_width: float = 3.2
    kerb_width: float = 0.25
    kerb_height: float = 0.12
    road_width: float = 7.0
    facade_height_range: tuple[float, float] = (7.0, 16.0)
    building_width_range: tuple[float, float] = (5.0, 11.0)
    facade_setback_range: tuple[float, float] = (0.0, 0.6)  # extra depth behind the sidewalk edge
    far_side_buildings: bool = True  # a facade row across the road (texture for SfM)
    n_poles: int = 5
    n_planters: int = 4
    n_parked_boxes: int = 4
    # --- video ---
    fps: float = 30.0
    duration_s: float = 10.0
    width: int = 854
    height: int = 480
    hfov_deg: float = 70.0  # pinhole, fx = fy = (width / 2) / tan(hfov / 2)
    # --- walk ---
    capture_height: float = 1.5  # mean camera height above the sidewalk (m)
    walk_speed: float = 1.4  # m/s
    walk_lateral: float = 0.5  # fraction of the sidewalk width from the kerb
    step_hz: float = 2.0  # vertical bob frequency (steps per second)
    bob_amplitude: float = 0.03  # m
    sway_amplitude: float = 0.025  # m, lateral, at half the step frequency
    yaw_jitter_deg: float = 2.0
    pitch_jitter_deg: float = 1.0
    roll_jitter_deg: float = 1.0
    pitch_deg: float = -4.0  # mean downward tilt
    yaw_deg: float = 0.0  # mean heading offset from +x (positive = towards the facades)
    # --- outputs ---
    write_frames: bool = False  # frames/frame_00000.png
    write_depth: bool = True  # depth/frame_00000.png, uint16 millimetres, 0 = sky/too far
    write_normals: bool = False  # normals/frame_00000.npy, float16 [H, W, 3] camera frame
    video_crf: int = 16
    gt_grid_resolution: float = 0.05  # walkable GT grid (m per cell)
    # --- lighting ---
    sun_direction: tuple[float, float, float] = (0.35, -0.55, 0.76)  # towards the sun, world frame (normalised)
    ambient: float = 0.50  # sky light on a vertical surface (x albedo)
    sun_strength: float = 0.55  # direct sun at normal incidence (x albedo)

    @property
    def fx(self) -> float:
        return (self.width / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def n_frames(self) -> int:
        return int(round(self.duration_s * self.fps))

    @property
    def path_length(self) -> float:
        return self.walk_speed * self.duration_s


PRESETS: dict[str, StreetConfig] = {
    "default": StreetConfig(),
    # 10 s, 480p, 30 fps: the clip `vid2sim demo` builds (benchmarks/sfm.py uses it too)
    "demo": StreetConfig(duration_s=10.0),
    # tiny and fast for unit tests
    "test": StreetConfig(duration_s=1.0, width=160, height=90, write_depth=True),
}


def varied(seed: int, base: str = "test") -> StreetConfig:
    """A street whose layout, furniture and light are drawn from `seed` (the geometry's own
    randomness also follows the seed): sidewalk 2.4-4.5 m wide, kerb 0.06-0.18 m high, road
    5-10 m, low to tall facades set back 0-1.2 m, 1-8 poles, 0-6 planters, 0-6 parked cars, the
    sun anywhere from low to high and from any side, ambient 0.35-0.65. Used for the training
    studies, where 35 streets must really differ."""
    rng = np.random.default_rng([seed, 7717])
    low = rng.uniform(4.0, 9.0)
    elevation, azimuth = np.radians(rng.uniform(15.0, 75.0)), rng.uniform(-np.pi, np.pi)
    sun = (float(np.cos(elevation) * np.cos(azimuth)), float(np.cos(elevation) * np.sin(azimuth)),
           float(np.sin(elevation)))
    return preset(base, seed=seed, sidewalk_width=float(rng.uniform(2.4, 4.5)),
                  kerb_height=float(rng.uniform(0.06, 0.18)), kerb_width=float(rng.uniform(0.15, 0.35)),
                  road_width=float(rng.uniform(5.0, 10.0)),
                  facade_height_range=(float(low), float(low + rng.uniform(2.0, 10.0))),
                  building_width_range=(float(rng.uniform(3.5, 6.0)), float(rng.uniform(7.0, 14.0))),
                  facade_setback_range=(0.0, float(rng.uniform(0.0, 1.2))),
                  far_side_buildings=bool(rng.random() < 0.8), n_poles=int(rng.integers(1, 9)),
                  n_planters=int(rng.integers(0, 7)), n_parked_boxes=int(rng.integers(0, 7)),
                  sun_direction=sun, ambient=float(rng.uniform(0.35, 0.65)),
                  sun_strength=float(rng.uniform(0.35, 0.75)))


def preset(name: str, **overrides: object) -> StreetConfig:
    """A named config with field overrides, e.g. preset("test", seed=3)."""
    if name not in PRESETS:
        raise KeyError(f"unknown synthetic street preset {name!r}; known: {sorted(PRESETS)}")
    return replace(PRESETS[name], **overrides)
