"""Mesh clean-up (`factory/geometry/mesh_ops.py`): the scipy face components agree with open3d's
`cluster_connected_triangles`, and fragment removal keeps what is large enough."""

import numpy as np
import open3d as o3d

from vid2sim.factory.geometry.mesh_ops import canonical_order, edge_components, remove_fragments, simplify


def mesh_of(vertices, faces) -> o3d.geometry.TriangleMesh:
    return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(vertices, np.float64)),
                                     o3d.utility.Vector3iVector(np.asarray(faces, np.int32)))


def same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """Two labelings [F] describe the same partition (a bijection between their labels)."""
    pairs = np.unique(np.c_[a, b], axis=0)
    return len(pairs) == len(np.unique(a)) == len(np.unique(b))


def test_edge_components_match_open3d_on_pieces_and_a_shared_vertex():
    boxes = [o3d.geometry.TriangleMesh.create_box(1, 1, 1).translate((3.0 * i, 0, 0))
             for i in range(3)]
    sphere = o3d.geometry.TriangleMesh.create_sphere(0.5, 12).translate((0, 4, 0))
    whole = boxes[0] + boxes[1] + boxes[2] + sphere
    # two triangles touching at one vertex only: not connected through an edge
    v = np.r_[np.asarray(whole.vertices), [[0, 8, 0], [1, 8, 0], [0, 9, 0], [-1, 8, 0], [0, 7, 0]]]
    n = len(whole.vertices)
    f = np.r_[np.asarray(whole.triangles), [[n, n + 1, n + 2], [n, n + 3, n + 4]]]
    mesh = mesh_of(v, f)
    labels = edge_components(f)
    ref = np.asarray(mesh.cluster_connected_triangles()[0])
    assert len(np.unique(labels)) == 6  # three boxes, a sphere, two lone triangles
    assert same_partition(labels, ref)


def test_edge_components_match_open3d_on_a_random_soup():
    rng = np.random.default_rng(0)
    f = rng.integers(0, 400, (600, 3))
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    mesh = mesh_of(rng.random((400, 3)), f)
    assert same_partition(edge_components(f), np.asarray(mesh.cluster_connected_triangles()[0]))


def test_remove_fragments_drops_small_and_short_pieces():
    big = o3d.geometry.TriangleMesh.create_sphere(1.0, 20)  # many faces, 2 m across
    tiny = o3d.geometry.TriangleMesh.create_sphere(0.05, 20).translate((5, 0, 0))  # 0.1 m across
    few = o3d.geometry.TriangleMesh.create_box(1, 1, 1).translate((0, 5, 0))  # 12 faces
    out = remove_fragments(big + tiny + few, min_faces=40, min_extent_m=0.25)
    assert len(out.triangles) == len(big.triangles)
    assert np.allclose(np.asarray(out.vertices).mean(0), 0.0, atol=1e-6)


def _shuffled(mesh: o3d.geometry.TriangleMesh, seed: int) -> o3d.geometry.TriangleMesh:
    """The same surface with vertices and triangles in another order, each triangle rotated."""
    rng = np.random.default_rng(seed)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    perm = rng.permutation(len(v))  # new -> old
    rank = np.empty_like(perm)
    rank[perm] = np.arange(len(perm))
    f = rank[f][rng.permutation(len(f))]
    f = np.roll(f, rng.integers(0, 3), axis=1)  # rotation keeps the orientation
    return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v[perm]), o3d.utility.Vector3iVector(f))


def test_canonical_order_is_the_same_for_any_input_order_and_keeps_the_surface():
    sphere = o3d.geometry.TriangleMesh.create_sphere(1.0, 20)
    ref = canonical_order(o3d.geometry.TriangleMesh(sphere))
    for seed in range(3):
        got = canonical_order(_shuffled(sphere, seed))
        assert np.array_equal(np.asarray(got.vertices), np.asarray(ref.vertices))
        assert np.array_equal(np.asarray(got.triangles), np.asarray(ref.triangles))
        # decimation after the canonical order gives one result, as the meshing stage needs
        a, b = simplify(ref, 300), simplify(got, 300)
        assert np.array_equal(np.asarray(a.triangles), np.asarray(b.triangles))
    v, f = np.asarray(ref.vertices), np.asarray(ref.triangles)
    assert len(f) == len(sphere.triangles) and len(v) == len(sphere.vertices)
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    outward = (normals * v[f].mean(axis=1)).sum(axis=1) > 0
    assert outward.all()  # every triangle kept its orientation
