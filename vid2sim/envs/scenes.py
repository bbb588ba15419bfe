"""Scenes for the envs: resolve a registry scene source and load a bundle via the registry checkout.

A scene source is a scene id, a list of ids, or a split name (`split:train`, `split:test`,
`split:train_5` for the nested subset of size 5, with the registry's default split seed 0).
Bundles are always read from `Registry.checkout` (hash-verified), never from a factory folder.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np
import trimesh
from plyfile import PlyData

from vid2sim.registry import Registry
from vid2sim.formats.bundle import COLLISION_PLY, VISUAL_MESH_PLY
from vid2sim.formats.scene import SCENE_JSON, read_scene_json
from vid2sim.formats.splat_ply import SPLATS_PLY
from vid2sim.formats.walkable import WALKABLE_NPZ, WalkableGrid, load_walkable
from vid2sim.splats import GaussianModel, read_ply


class SceneError(RuntimeError):
    """A scene cannot be used by the envs; `reason` is a short name."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


@dataclass(frozen=True)
class MeshData:
    vertices: np.ndarray  # [V, 3] float32
    faces: np.ndarray  # [F, 3] int32
    face_colors: Optional[np.ndarray] = None  # [F, 3] uint8


@dataclass
class SceneAssets:
    """One checked-out bundle, loaded."""

    scene_id: str
    bundle_dir: Path
    splats: GaussianModel
    collision: MeshData
    walkable: WalkableGrid
    visual_mesh_path: Optional[Path]
    walkable_inflation: float = 0.0  # m the factory already shrank the walkable map by

    def content_key(self) -> str:
        """sha256 of the bundle's splats.ply (names the scene's derived sets, e.g. sim-ready)."""
        h = hashlib.sha256()
        with open(self.bundle_dir / SPLATS_PLY, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 22), b""):
                h.update(chunk)
        return h.hexdigest()


def walkable_inflation(scene_json: dict) -> float:
    """Robot radius the factory inflated obstacles by (pipeline.config.walkable.robot_radius_m);
    0 for maps that are not inflated (the synthetic street's ground truth)."""
    conf = scene_json.get("pipeline", {}).get("config", {})
    walk = conf.get("walkable", {}) if isinstance(conf, dict) else {}
    return float(walk.get("robot_radius_m", 0.0)) if isinstance(walk, dict) else 0.0


def resolve_scene_ids(registry: Registry, source: Union[str, Sequence[str]]) -> list[str]:
    """Scene source -> scene ids (see module docstring)."""
    if isinstance(source, str) and source.startswith("split:"):
        name = source[len("split:"):]
        split = registry.split(seed=0, train_sizes=_subset_sizes(name))
        if name == "train":
            ids = split.train
        elif name == "test":
            ids = split.test
        elif name.startswith("train_"):
            ids = split.train_subsets.get(int(name[6:]), [])
        else:
            raise SceneError("unknown_split", f"{source!r}: use split:train, split:test or split:train_N")
        if not ids:
            raise SceneError("empty_split", f"{source!r} selects no scene in {registry.root}")
        return list(ids)
    ids = [source] if isinstance(source, str) else list(source)
    if not ids:
        raise SceneError("no_scene", "empty scene list")
    return ids


def _subset_sizes(name: str) -> tuple[int, ...]:
    return (int(name[6:]),) if name.startswith("train_") and name[6:].isdigit() else ()


def checkout_dir() -> Path:
    """Where bundles are checked out: $VID2SIM_CHECKOUTS or ./vid2sim-checkouts."""
    return Path(os.environ.get("VID2SIM_CHECKOUTS", "vid2sim-checkouts"))


def load_scene(registry: Registry, scene_id: str, dest_root: Optional[Path] = None) -> SceneAssets:
    """Check a scene out of the registry and load its splats, collision mesh and walkable grid."""
    rec = registry.show(scene_id)
    dest = Path(dest_root or checkout_dir()) / rec.ref
    folder = registry.checkout(scene_id, dest=dest)
    visual = folder / VISUAL_MESH_PLY
    return SceneAssets(scene_id=scene_id, bundle_dir=folder, splats=read_ply(folder / SPLATS_PLY),
                       collision=read_collision(folder / COLLISION_PLY),
                       walkable=load_walkable(folder / WALKABLE_NPZ),
                       visual_mesh_path=visual if visual.is_file() else None,
                       walkable_inflation=walkable_inflation(read_scene_json(folder / SCENE_JSON)))


def read_collision(path: Path) -> MeshData:
    """Triangle mesh for physics (vertices [V, 3], faces [F, 3])."""
    mesh = trimesh.load(path, force="mesh", process=False)
    return MeshData(np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.int32))


def read_visual_mesh(path: Optional[Path], scene_id: str = "") -> MeshData:
    """Coloured visual mesh: per-face colours (red/green/blue on faces, or vertex colours averaged)."""
    if path is None or not Path(path).is_file():
        raise SceneError("no_visual_mesh", f"scene {scene_id!r} has no {VISUAL_MESH_PLY}: the "
                         "mesh-rgb variant needs the bundle's coloured visual mesh")
    ply = PlyData.read(str(path))
    v = ply["vertex"].data
    verts = np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float32)  # [V, 3]
    f = ply["face"].data
    key = "vertex_indices" if "vertex_indices" in f.dtype.names else "vertex_index"
    faces = np.stack(f[key]).astype(np.int32)  # [F, 3]
    if "red" in f.dtype.names:
        colors = np.stack([f["red"], f["green"], f["blue"]], 1).astype(np.uint8)
    elif "red" in v.dtype.names:
        vc = np.stack([v["red"], v["green"], v["blue"]], 1).astype(np.float32)  # [V, 3]
        colors = vc[faces].mean(1).round().astype(np.uint8)
    else:
        colors = np.full((len(faces), 3), 160, np.uint8)
    return MeshData(verts, faces, colors)
