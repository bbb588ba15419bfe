"""Scene layers of one bundle folder, each read on its own so that a bundle missing a layer
still shows the others; `SceneLayers.missing` names each absent or unreadable layer and why.

Reads scene.json, splats.ply, collision.ply, walkable.npz and cameras.parquet (formats/).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional, TypeVar

import numpy as np
import trimesh

from vid2sim.formats.bundle import COLLISION_PLY, check_mesh
from vid2sim.formats.cameras import CAMERAS_PARQUET, load_cameras
from vid2sim.formats.errors import BundleError
from vid2sim.formats.scene import SCENE_JSON, read_scene_json
from vid2sim.formats.splat_ply import SPLATS_PLY, check_splats
from vid2sim.formats.walkable import WALKABLE_NPZ, WalkableGrid, load_walkable
from vid2sim.viewer.errors import NotABundle
from vid2sim.viewer.splats import DEFAULT_BUDGET, SplatLayer, read_splat_layer

T = TypeVar("T")


@dataclass
class CameraPath:
    """Source-video cameras: centres [N, 3], camera-to-world [N, 4, 4] (OpenCV axes), fx, size."""

    centers: np.ndarray
    cam_to_world: np.ndarray
    fov_y: np.ndarray  # [N] rad
    aspect: np.ndarray  # [N] width / height


@dataclass
class SceneLayers:
    folder: Path
    scene_id: str
    scene: Optional[dict]  # scene.json (None when missing)
    splats: Optional[SplatLayer]
    mesh: Optional[trimesh.Trimesh]
    walkable: Optional[WalkableGrid]
    cameras: Optional[CameraPath]
    missing: dict[str, str] = field(default_factory=dict)  # file name -> reason

    def bounds(self, focus: bool = False) -> np.ndarray:
        """[2, 3] box around what the scene shows (splats, mesh, walkable, cameras); `focus`: around
        the walkable map and the camera path only (where the robot goes), when the bundle has them."""
        pts = [np.zeros((1, 3))]
        if focus and (self.walkable is not None or self.cameras is not None):
            return self._box(pts, with_splats=False, with_mesh=False)
        return self._box(pts, with_splats=True, with_mesh=True)

    def _box(self, pts: list, with_splats: bool, with_mesh: bool) -> np.ndarray:
        if with_splats and self.splats is not None:
            pts.append(np.quantile(self.splats.centers, [0.02, 0.98], axis=0))
        if with_mesh and self.mesh is not None:
            pts.append(np.asarray(self.mesh.bounds))
        if self.walkable is not None:
            lo, hi = self.walkable.origin, self.walkable.extent_max()
            pts.append(np.array([[lo[0], lo[1], 0.0], [hi[0], hi[1], 0.0]]))
        if self.cameras is not None:
            pts.append(self.cameras.centers)
        allp = np.concatenate(pts)
        return np.stack([allp.min(0), allp.max(0)])


def _try(missing: dict[str, str], name: str, read: Callable[[], T]) -> Optional[T]:
    try:
        return read()
    except BundleError as e:
        missing[name] = e.reason
    except Exception as e:  # a layer file another tool wrote badly: show the rest
        missing[name] = f"unreadable ({type(e).__name__}: {e})"
    return None


def _splats(path: Path, budget: int) -> SplatLayer:
    check_splats(path)
    return read_splat_layer(path, budget)


def _mesh(path: Path) -> trimesh.Trimesh:
    check_mesh(path)
    return trimesh.load(str(path), force="mesh", process=False)


def _cameras(path: Path) -> CameraPath:
    t = load_cameras(path)
    c2w = np.asarray(t.column("cam_to_world").to_pylist(), np.float64).reshape(-1, 4, 4)
    order = np.argsort(np.asarray(t.column("timestamp").to_pylist()))
    h = np.asarray(t.column("height").to_pylist(), np.float64)
    w = np.asarray(t.column("width").to_pylist(), np.float64)
    fy = np.asarray(t.column("fy").to_pylist(), np.float64)
    c2w = c2w[order]
    return CameraPath(centers=c2w[:, :3, 3], cam_to_world=c2w, fov_y=(2 * np.arctan(h / (2 * fy)))[order],
                      aspect=(w / h)[order])


def load_layers(folder: Path, budget: int = DEFAULT_BUDGET) -> SceneLayers:
    """Read every layer of the bundle at `folder`; raise NotABundle when it holds none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise NotABundle(f"{folder}: no such folder")
    missing: dict[str, str] = {}
    scene = _try(missing, SCENE_JSON, lambda: read_scene_json(folder / SCENE_JSON))
    layers = SceneLayers(
        folder=folder, scene_id=scene["scene_id"] if scene else folder.name, scene=scene,
        splats=_try(missing, SPLATS_PLY, lambda: _splats(folder / SPLATS_PLY, budget)),
        mesh=_try(missing, COLLISION_PLY, lambda: _mesh(folder / COLLISION_PLY)),
        walkable=_try(missing, WALKABLE_NPZ, lambda: load_walkable(folder / WALKABLE_NPZ)),
        cameras=_try(missing, CAMERAS_PARQUET, lambda: _cameras(folder / CAMERAS_PARQUET)),
        missing=missing)
    if len(missing) == 5:
        raise NotABundle(f"{folder}: not a scene bundle (no readable scene.json, splats.ply, collision.ply, "
                         "walkable.npz or cameras.parquet)")
    return layers


def missing_summary(layers: SceneLayers) -> str:
    """One line naming each missing layer and why ('' when complete)."""
    return "; ".join(f"{name}: {why}" for name, why in layers.missing.items())
