"""Scene bundle format: writer round trip and rejection of each kind of bad input."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from registry_fixtures import make_bundle, write_box_ply

from vid2sim.formats.bundle import COLLISION_PLY, validate_bundle
from vid2sim.formats.cameras import CAMERAS_PARQUET, load_cameras
from vid2sim.formats.errors import BundleError
from vid2sim.formats.scene import SCENE_JSON, check_scene_id
from vid2sim.formats.splat_ply import SPLATS_PLY
from vid2sim.formats.walkable import WALKABLE_NPZ, load_walkable


@pytest.fixture
def bundle(tmp_path):
    return make_bundle(tmp_path / "b", "street-01", extras=True)


def test_round_trip(bundle):
    info = validate_bundle(bundle)
    assert info.scene_id == "street-01"
    assert info.num_splats == 300
    assert info.frame_counts == {"all": 16, "train": 14, "test": 2}
    assert info.walkable_area_m2 == pytest.approx(36 * 0.25)
    assert len(info.bounds) == 6 and info.bounds[0] <= info.bounds[3]
    assert info.mesh_bounds == pytest.approx((-2, -1.5, -1, 2, 1.5, 1))
    assert {"scene.json", "splats.ply", "visual.ply", "colmap/points3D.txt"} <= set(info.artifacts)
    walk = load_walkable(bundle / WALKABLE_NPZ)
    assert walk.grid.dtype == np.uint8 and tuple(walk.origin) == (-1.0, -2.0) and walk.resolution == 0.5
    assert load_cameras(bundle / CAMERAS_PARQUET).num_rows == 16
    scene = json.loads((bundle / SCENE_JSON).read_text())
    assert scene["world_frame"] == {"units": "m", "up": "+z", "ground_z": 0, "scale_source": "test-fixture"}


@pytest.mark.parametrize("bad", ["", "../x", "/abs", "Upper", ".hidden", "a" * 65, "a b", "x/y", None, 3])
def test_bad_scene_ids(bad):
    with pytest.raises(BundleError, match="invalid scene_id"):
        check_scene_id(bad)


@pytest.mark.parametrize("good", ["a", "street-01", "x.y_z", "0" * 64])
def test_good_scene_ids(good):
    assert check_scene_id(good) == good


def _edit_scene(bundle, fn):
    p = bundle / SCENE_JSON
    s = json.loads(p.read_text())
    fn(s)
    p.write_text(json.dumps(s))


@pytest.mark.parametrize("edit, reason", [
    (lambda s: s.pop("source"), "missing required field"),
    (lambda s: s["source"].pop("sha256"), "missing required field"),
    (lambda s: s.update(colour="red"), "unknown field"),
    (lambda s: s["world_frame"].update(units="ft"), "units"),
    (lambda s: s["world_frame"].update(up="+y"), "up"),
    (lambda s: s.update(scene_id="../x"), "invalid scene_id"),
    (lambda s: s.update(scene_id="/abs"), "invalid scene_id"),
    (lambda s: s.update(scene_id="Street"), "invalid scene_id"),
    (lambda s: s.update(scene_id=""), "invalid scene_id"),
    (lambda s: s["source"].update(clip_end_s=-1), "clip window"),
    (lambda s: s.update(tags="x"), "tags"),
])
def test_bad_scene_json(bundle, edit, reason):
    _edit_scene(bundle, edit)
    with pytest.raises(BundleError, match=reason) as e:
        validate_bundle(bundle)
    assert "scene.json" in str(e.value)


def test_missing_scene_json(bundle):
    (bundle / SCENE_JSON).unlink()
    with pytest.raises(BundleError, match="scene.json.*missing scene.json"):
        validate_bundle(bundle)


def test_ply_without_3dgs_properties(bundle):
    write_box_ply(bundle / SPLATS_PLY)  # a mesh PLY: vertices have x y z only
    with pytest.raises(BundleError, match="splats.ply.*lacks 3DGS properties.*f_dc_0"):
        validate_bundle(bundle)


def test_unreadable_mesh(bundle):
    (bundle / COLLISION_PLY).write_bytes(b"ply\nformat garbage\n")
    with pytest.raises(BundleError, match="collision.ply"):
        validate_bundle(bundle)


def test_walkable_without_keys(bundle):
    np.savez(bundle / WALKABLE_NPZ, grid=np.zeros((2, 2), np.uint8), origin=np.zeros(2))
    with pytest.raises(BundleError, match="walkable.npz.*lacks key.*resolution"):
        validate_bundle(bundle)


def test_cameras_wrong_schema(bundle):
    t = pq.read_table(bundle / CAMERAS_PARQUET)
    t = t.set_column(t.schema.get_field_index("fx"), "fx", pa.array([1] * t.num_rows, pa.int64()))
    pq.write_table(t, bundle / CAMERAS_PARQUET)
    with pytest.raises(BundleError, match="cameras.parquet.*wrong cameras schema.*fx"):
        validate_bundle(bundle)


def test_write_bundle_failure_leaves_nothing(tmp_path, bundle):
    from vid2sim.formats.bundle import write_bundle

    scene = json.loads((bundle / SCENE_JSON).read_text())
    out = tmp_path / "out"
    with pytest.raises(BundleError, match="lacks 3DGS"):
        write_bundle(out, scene_json=scene, splats_ply=bundle / COLLISION_PLY, collision_ply=bundle / COLLISION_PLY,
                     walkable=(np.ones((2, 2), np.uint8), (0, 0), 1.0), cameras=load_cameras(bundle / CAMERAS_PARQUET),
                     preview_png=bundle / "preview.png")
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".out")] == []
    shutil.rmtree(bundle)
