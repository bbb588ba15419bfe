"""Triangle-mesh clean-up shared by the collision and the visual mesh (open3d, in place)."""

from __future__ import annotations

import numpy as np
import open3d as o3d
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


def edge_components(faces: np.ndarray) -> np.ndarray:
    """Connected-component label [F] (0..k-1) of each face of faces [F, 3] (vertex indices),
    faces that share an edge being connected: the partition of open3d's
    `cluster_connected_triangles`, 3-4x faster (a face-edge graph through scipy). Unlike
    `floaters.face_components`, which joins faces by vertex position (and nearness)."""
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    if len(faces) == 0:
        return np.zeros(0, np.int64)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, edge_id = np.unique(edges[:, 0] * (int(faces.max()) + 1) + edges[:, 1], return_inverse=True)
    n_f = len(faces)
    face_id = np.tile(np.arange(n_f), 3)  # [3F], the face of each edge slot
    n = n_f + int(edge_id.max()) + 1
    graph = coo_matrix((np.ones(3 * n_f, np.int8), (face_id, n_f + edge_id.reshape(-1))),
                       shape=(n, n))  # faces and edges as nodes, a face linked to its 3 edges
    return connected_components(graph, directed=False)[1][:n_f]


def remove_fragments(mesh: o3d.geometry.TriangleMesh, min_faces: int, min_extent_m: float
                     ) -> o3d.geometry.TriangleMesh:
    """Drop connected components with < min_faces faces or a bbox diagonal < min_extent_m."""
    if len(mesh.triangles) == 0:
        return mesh
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    labels = edge_components(f)  # [F]: every component holds a face, so labels are 0..k-1
    counts = np.bincount(labels)  # [k] faces per component
    order = np.argsort(labels, kind="stable")  # faces grouped by component
    tri = v[f[order]]  # [F, 3, 3]
    starts = np.r_[0, np.cumsum(counts)[:-1]]  # [k] first face of each component
    lo = np.minimum.reduceat(tri.min(axis=1), starts)  # [k, 3] bbox per component
    hi = np.maximum.reduceat(tri.max(axis=1), starts)
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


def canonical_order(mesh: o3d.geometry.TriangleMesh) -> o3d.geometry.TriangleMesh:
    """The same mesh with its vertices sorted by (x, y, z) and its triangles sorted, each rotated
    to start at its smallest vertex index (orientation kept): one order for one set of vertices
    and triangles, whatever order a multi-threaded extraction produced them in. Duplicate
    vertices are merged first (`tidy`); other attributes are dropped."""
    mesh = tidy(mesh)
    v = np.asarray(mesh.vertices)  # [V, 3]
    f = np.asarray(mesh.triangles)  # [F, 3]
    order = np.lexsort((v[:, 2], v[:, 1], v[:, 0]))  # [V] new -> old
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))  # old -> new
    f = rank[f]
    first = f.argmin(axis=1)  # [F] rotate so the smallest index leads
    f = f[np.arange(len(f))[:, None], (first[:, None] + np.arange(3)) % 3]
    f = f[np.lexsort((f[:, 2], f[:, 1], f[:, 0]))]
    return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v[order]), o3d.utility.Vector3iVector(f))
