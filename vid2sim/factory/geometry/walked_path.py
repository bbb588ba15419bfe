"""The walked path: the video's camera path resampled along the ground, shared by the geometry
stages (carving, walkable growth) and the corridor check in `factory/evaluation/corridor.py`."""

from __future__ import annotations

import numpy as np

from vid2sim.formats.robot import ROBOT

# The walker's body: a vertical disc of this radius swept along the walked path is proven
# empty (the person who filmed walked there). The body carving, the corridor check and the
# walkable map's clearance all use it. From the robot spec (`formats/robot.py`), 0.25 m.
BODY_RADIUS_M = ROBOT.walker_radius_m


class CorridorError(ValueError):
    """Bad input to the corridor check (reason names the problem)."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason, self.detail = reason, detail


def walked_path(camera_path: np.ndarray, step_m: float) -> np.ndarray:
    """Camera positions [T, 3] resampled along the polyline every step_m: [S, 3]."""
    path = np.asarray(camera_path, np.float64).reshape(-1, 3)
    if len(path) == 0 or not np.all(np.isfinite(path)):
        raise CorridorError("bad_camera_path", f"need finite [T, 3] positions, got {len(path)}")
    seg = np.linalg.norm(np.diff(path[:, :2], axis=0), axis=1)  # [T-1] ground distance
    s = np.concatenate([[0.0], np.cumsum(seg)])  # [T]
    if s[-1] <= 0:
        return path[:1].copy()
    q = np.linspace(0.0, s[-1], int(np.ceil(s[-1] / step_m)) + 1)  # [S]
    return np.stack([np.interp(q, s, path[:, k]) for k in range(3)], axis=1)
