"""Triangle-mesh clean-up shared by the collision and the visual mesh (open3d, in place)."""

from __future__ import annotations

import numpy as np
import open3d as o3d


def remove_fragments(mesh: o3d.geometry.TriangleMesh, min_faces: int, min_extent_m: float
                     ) -> o3d.geometry.TriangleMesh:
    """Drop connected components with < min_faces faces or a bbox diagonal < min_extent_m."""
    if len(mesh.triangles) == 0:
        return mesh
    labels, counts, _ = mesh.cluster_connected_triangles()
    labels, counts = np.asarray(labels), np.asarray(counts)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    pts = v[f].reshape(-1, 3)  # [3F, 3]
    lab3 = np.repeat(labels, 3)
    k = len(counts)
    lo = np.full((k, 3), np.inf)
    hi = np.full((k, 3), -np.inf)
    np.minimum.at(lo, lab3, pts)
    np.maximum.at(hi, lab3, pts)
    diag = np.linalg.norm(hi - lo, axis=1)  # [k]
    keep_cluster = (counts >= min_faces) & (diag >= min_extent_m)
    mesh.remove_triangles_by_mask(~keep_cluster[labels])
    mesh.remove_unreferenced_vertices()
    return mesh


def simplify(mesh: o3d.geometry.TriangleMesh, target_faces: int) -> o3d.geometry.TriangleMesh:
    """Quadric decimation to at most `target_faces` faces (no-op when already small)."""
    if target_faces <= 0 or len(mesh.triangles) <= target_faces:
        return mesh
    out = mesh.simplify_quadric_decimation(target_number_of_triangles=int(target_faces))
    return tidy(out)


def tidy(mesh: o3d.geometry.TriangleMesh) -> o3d.geometry.TriangleMesh:
    mesh.remove_duplicated_vertices()
    mesh.remove_degenerate_triangles()
    mesh.remove_duplicated_triangles()
    mesh.remove_unreferenced_vertices()
    return mesh
