"""Floaters in a collision mesh: small pieces that nothing holds up (reconstruction phantoms).

`face_components` labels the connected pieces of a triangle mesh (pieces closer than a join
distance count as one object); `floater_faces` marks the pieces that are small and whose lowest
vertex lies clearly above the local ground; `lump_tops` marks what trimming the sub-step faces
leaves of a noise lump that peaks just above the step; `carved_pieces` marks the small pieces
that the free-space carving cut (part of their depth lay in space proven empty);
`small_pieces` the pieces with little surface. The walkable stage (`walkable.physical_layer`) drops
floaters when `WalkableConfig.floater_max_area_m2` > 0 (off by default;
docs/studies/physical_layer.md),
and lump tops, carved pieces and small pieces after the trim (on).
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


def face_components(vertices: np.ndarray, faces: np.ndarray, join_m: float = 0.0) -> np.ndarray:
    """Connected-component label [F] of each face of (vertices [V, 3], faces [F, 3]); faces
    sharing a vertex position (to 1e-6 m), or with vertices within join_m of each other, are
    connected."""
    if len(faces) == 0:
        return np.zeros(0, np.int64)
    _, vid = np.unique(np.round(vertices * 1e6), axis=0, return_inverse=True)
    vid = vid.reshape(-1)
    f = vid[faces]  # [F, 3] merged vertex ids
    a, b = [f[:, 0], f[:, 1]], [f[:, 1], f[:, 2]]
    if join_m > 0:
        pairs = cKDTree(vertices).query_pairs(join_m, output_type="ndarray")  # [E, 2]
        a, b = a + [vid[pairs[:, 0]]], b + [vid[pairs[:, 1]]]
    a, b = np.concatenate(a), np.concatenate(b)
    n = int(vid.max()) + 1
    graph = coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(n, n))
    return connected_components(graph, directed=False)[1][f[:, 0]]


def floater_faces(vertices: np.ndarray, faces: np.ndarray, vertex_height: np.ndarray,
                  gap_m: float, max_area_m2: float, join_m: float = 0.0,
                  max_low_m: float = np.inf) -> np.ndarray:
    """Faces [F] bool of floaters: connected components (pieces within join_m of each other
    joined: one surface split by cleanup stays one object) whose lowest vertex lies more than
    gap_m above the local ground (nothing holds them up; vertex_height [V] is each vertex's
    height above it) and whose area is below max_area_m2 (real overhangs, canopies and facades
    are large; real small obstacles stand on the ground). Components whose lowest vertex lies
    above max_low_m are left alone."""
    if len(faces) == 0 or max_area_m2 <= 0:
        return np.zeros(len(faces), bool)
    lab = face_components(vertices, faces, join_m)  # [F]
    h = vertex_height[faces].min(axis=1)  # [F] lowest vertex above the ground
    low = np.full(int(lab.max()) + 1, np.inf)
    np.minimum.at(low, lab, h)
    comp_area = piece_areas(vertices, faces, lab)
    floater = (low > gap_m) & (low < max_low_m) & (comp_area < max_area_m2)  # [C]
    return floater[lab]


def lump_tops(vertices: np.ndarray, faces: np.ndarray, kept: np.ndarray,
              vertex_height: np.ndarray, max_top_m: float) -> np.ndarray:
    """Faces [F] bool among the kept ones (kept [F] bool: faces left after a trim) that form a
    connected piece which the trim cut (it shares a vertex with a dropped face) and whose
    highest vertex lies below max_top_m above the local ground (vertex_height [V])."""
    out = np.zeros(len(faces), bool)
    if not kept.any() or kept.all():
        return out
    kf = faces[kept]  # [K, 3]
    lab = face_components(vertices, kf)  # [K]
    n = int(lab.max()) + 1
    dropped_vertex = np.zeros(len(vertices), bool)
    dropped_vertex[faces[~kept].reshape(-1)] = True
    cut = np.zeros(n, bool)
    np.logical_or.at(cut, lab, dropped_vertex[kf].any(axis=1))
    top = np.full(n, -np.inf)
    np.maximum.at(top, lab, vertex_height[kf].max(axis=1))
    out[np.flatnonzero(kept)] = (cut & (top < max_top_m))[lab]
    return out


def piece_areas(vertices: np.ndarray, faces: np.ndarray, lab: np.ndarray) -> np.ndarray:
    """Area [C] (m^2) of each component label of `face_components`."""
    tri = vertices[faces]  # [F, 3, 3]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    return np.bincount(lab, weights=area, minlength=int(lab.max()) + 1)


def carved_pieces(vertices: np.ndarray, faces: np.ndarray, carved_points: np.ndarray,
                  max_area_m2: float, near_m: float, min_points: int,
                  lab: Optional[np.ndarray] = None) -> np.ndarray:
    """Faces [F] bool of the pieces the carving cut: connected components smaller than
    max_area_m2 with at least min_points of carved_points [M, 3] (depth the carving removed as
    lying in proven-empty space, e.g. inside the body the walker swept) within near_m of their
    vertices (each carved point counts for the piece of its nearest vertex). The carving
    dropped the part of such a piece that lay in the empty space; what it left just outside is
    the same phantom, not a real object (a solid object does not reach into space the walker's
    body went through). lab: the faces' `face_components` labels, when already computed."""
    carved_points = np.asarray(carved_points, np.float64).reshape(-1, 3)
    if len(faces) == 0 or len(carved_points) == 0 or max_area_m2 <= 0:
        return np.zeros(len(faces), bool)
    lab = face_components(vertices, faces) if lab is None else lab  # [F]
    vlab = np.full(len(vertices), -1, np.int64)
    for k in range(3):
        vlab[faces[:, k]] = lab
    d, nearest = cKDTree(vertices).query(carved_points, distance_upper_bound=near_m)  # [M]
    hit = vlab[nearest[np.isfinite(d)]]
    n = int(lab.max()) + 1
    count = np.bincount(hit[hit >= 0], minlength=n)  # [C] carved points per piece
    cut = (count >= min_points) & (piece_areas(vertices, faces, lab) < max_area_m2)
    return cut[lab]


def small_pieces(vertices: np.ndarray, faces: np.ndarray, min_area_m2: float,
                 lab: Optional[np.ndarray] = None) -> np.ndarray:
    """Faces [F] bool of the connected components with less than min_area_m2 of surface
    (lab: the faces' `face_components` labels, when already computed)."""
    if len(faces) == 0 or min_area_m2 <= 0:
        return np.zeros(len(faces), bool)
    lab = face_components(vertices, faces) if lab is None else lab
    return (piece_areas(vertices, faces, lab) < min_area_m2)[lab]
