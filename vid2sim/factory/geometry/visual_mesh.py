"""Vertex-coloured visual mesh: the paper's mesh-RGB baseline (Video2Game-like observations).

Made from the same TSDF fusion as the collision mesh (meshing.fuse_tsdf, which calls it) but keeping the
ground; written as `visual_mesh.ply` (binary PLY, per-vertex red/green/blue uint8). The
baseline renders it with `render_rgb` (CPU ray casting) or any mesh renderer.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d

from vid2sim.factory.geometry.mesh_ops import remove_fragments, simplify, tidy
from vid2sim.factory.geometry.raycast import RaycastRenderer


def make_visual_mesh(mesh: o3d.geometry.TriangleMesh, target_faces: int = 300_000,
                     min_fragment_faces: int = 20) -> o3d.geometry.TriangleMesh:
    """Tidy a fused coloured mesh: drop tiny fragments, decimate to `target_faces`.

    Quadric decimation in open3d carries vertex colours along.
    """
    mesh = tidy(mesh)
    mesh = remove_fragments(mesh, min_fragment_faces, 0.0)
    mesh = simplify(mesh, target_faces)
    mesh.compute_vertex_normals()
    return mesh


def load_visual_mesh(path: Path) -> o3d.geometry.TriangleMesh:
    """Read a visual mesh; raises ValueError naming the file when empty or uncoloured."""
    mesh = o3d.io.read_triangle_mesh(str(path))
    if len(mesh.triangles) == 0:
        raise ValueError(f"{path}: no triangles (unreadable or empty mesh)")
    if not mesh.has_vertex_colors():
        raise ValueError(f"{path}: mesh has no vertex colours")
    return mesh


def render_rgb(renderer: RaycastRenderer, K: np.ndarray, cam_to_world: np.ndarray,
               width: int, height: int, background: tuple[int, int, int] = (0, 0, 0)
               ) -> np.ndarray:
    """RGB observation [H, W, 3] uint8 of a coloured mesh (background where rays miss)."""
    out = renderer.render(K, cam_to_world, width, height)
    if out.rgb is None:
        raise ValueError("mesh has no vertex colours to render")
    rgb = out.rgb.copy()
    rgb[out.face_id < 0] = np.asarray(background, np.uint8)
    return rgb
