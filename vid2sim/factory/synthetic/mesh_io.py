"""Read/write the GT scene mesh as PLY with per-face material, instance and colour."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement


def write_mesh_ply(path: Path, vertices: np.ndarray, triangles: np.ndarray,
                   face_material: np.ndarray | None = None, face_color: np.ndarray | None = None,
                   face_instance: np.ndarray | None = None) -> Path:
    """Binary PLY: vertex x y z (float32), face vertex_indices (+ material, instance, red green blue)."""
    v = np.empty(len(vertices), [("x", "f4"), ("y", "f4"), ("z", "f4")])
    v["x"], v["y"], v["z"] = np.asarray(vertices, np.float32).T
    fields = [("vertex_indices", "i4", (3,))]
    if face_material is not None:
        fields.append(("material", "u1"))
    if face_instance is not None:
        fields.append(("instance", "i4"))
    if face_color is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    f = np.empty(len(triangles), fields)
    f["vertex_indices"] = np.asarray(triangles, np.int32)
    if face_material is not None:
        f["material"] = face_material
    if face_instance is not None:
        f["instance"] = face_instance
    if face_color is not None:
        c = np.clip(np.asarray(face_color) * 255 + 0.5, 0, 255).astype(np.uint8)
        f["red"], f["green"], f["blue"] = c.T
    path = Path(path)
    PlyData([PlyElement.describe(v, "vertex"), PlyElement.describe(f, "face")]).write(str(path))
    return path


def read_mesh_ply(path: Path) -> dict[str, np.ndarray]:
    """vertices [V, 3] float64, triangles [F, 3] int32, and face_material when present."""
    ply = PlyData.read(str(path))
    v = ply["vertex"]
    f = ply["face"].data
    out = {"vertices": np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float64),
           "triangles": np.stack(f["vertex_indices"]).astype(np.int32)}
    if "material" in f.dtype.names:
        out["face_material"] = np.asarray(f["material"], np.uint8)
    return out
