"""The robot every scene is made for and driven by: one record the factory and the envs share.

The factory's walkable map clears the walker's body and keeps the robot's body band free of
collision geometry; the envs drive a box of the same size, mount their camera where the spec
says, and the fast render path measures its sim-ready splats from that camera. Every one of
them reads its defaults from `ROBOT` (`tests/test_robot_spec.py` fails when one drifts), and
the bundle stage records it in scene.json (`robot`, see `formats/scene.py`).

Constants and where they come from (details in `vid2sim/envs/config.py`):
- bicycle model: 0.8 m wheelbase, 30 deg maximum steering (the paper's appendix), top speed
  1.0 m/s (the official agent's move x 1 m/s, no reverse);
- footprint: a 0.9 m x 0.6 m x 0.6 m box (length x width x height) centred on the bicycle
  model's reference point, riding `ground_clearance_m` 0.15 m above the ground: its body band
  is 0.15-0.75 m above the ground, which the walkable map keeps free of collision geometry;
- walker body radius 0.25 m: the person who filmed walked there, so a vertical disc of this
  radius swept along the walked path is empty; the body carving, the corridor check and the
  walkable map's clearance use it (the envs add the robot's own clearance on top);
- camera: at the box's front face (0.45 m ahead of the centre), 0.65 m above the ground,
  looking forward, level; 128 x 72 px with Unity's default 60 deg vertical field of view
  (the paper gives only the 1280 x 720 sensor), centred principal point, square pixels.
Imports nothing from vid2sim.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any


@dataclass(frozen=True)
class RobotSpec:
    length_m: float = 0.9  # m, footprint box length (along the heading)
    width_m: float = 0.6  # m, footprint box width
    height_m: float = 0.6  # m, footprint box height
    ground_clearance_m: float = 0.15  # m, box bottom above the ground (z = 0)
    wheelbase_m: float = 0.8  # m, bicycle-model wheelbase
    max_steer_deg: float = 30.0  # deg, largest steering angle
    max_speed_mps: float = 1.0  # m/s, top speed (no reverse)
    walker_radius_m: float = 0.25  # m, body radius of the walker the factory's map clears
    camera_height_m: float = 0.65  # m, camera centre above the ground
    camera_forward_m: float = 0.45  # m, camera centre ahead of the robot centre (the box's front face)
    camera_width_px: int = 128  # px, observation image width
    camera_height_px: int = 72  # px, observation image height
    camera_vfov_deg: float = 60.0  # deg, vertical field of view (square pixels, centred principal point)

    @property
    def body_bottom_m(self) -> float:
        """Bottom of the body band (m above the ground): the box's underside."""
        return self.ground_clearance_m

    @property
    def body_top_m(self) -> float:
        """Top of the body band (m above the ground): the box's top."""
        return self.ground_clearance_m + self.height_m

    @property
    def camera_focal_px(self) -> float:
        """Focal length in pixels (fx = fy) of the camera's vertical field of view."""
        return 0.5 * self.camera_height_px / math.tan(math.radians(self.camera_vfov_deg) / 2)

    def to_dict(self) -> dict:
        """The record scene.json keeps under `robot` (field name -> value)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Any) -> "RobotSpec":
        """Read back `to_dict`; ValueError on a non-object, unknown or missing fields, or a
        non-positive size."""
        if not isinstance(data, dict):
            raise ValueError(f"robot must be an object, got {type(data).__name__}")
        names = [f.name for f in fields(cls)]
        unknown = sorted(set(data) - set(names))
        missing = [n for n in names if n not in data]
        if unknown or missing:
            raise ValueError(f"robot fields: unknown {unknown}, missing {missing}")
        for n in names:
            v = data[n]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"robot.{n} must be a finite number >= 0, got {v!r}")
        return cls(**{n: (int(data[n]) if n.endswith("_px") else float(data[n])) for n in names})


ROBOT = RobotSpec()
"""The project's robot: the defaults of the factory's and the envs' robot settings."""
