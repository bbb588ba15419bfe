"""Non-finite or degenerate values in a bundle are refused with a named error."""

from __future__ import annotations

import io
import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from plyfile import PlyData
from registry_fixtures import make_bundle

from vid2sim.formats.errors import BundleError
from vid2sim.registry import Registry


def _ply(col: str, value: float, rows=slice(0, 1)):
    def edit(b):
        ply = PlyData.read(io.BytesIO((b / "splats.ply").read_bytes()))
        v = ply["vertex"].data
        for c in col.split(","):
            v[c][rows] = value
        ply.write(str(b / "splats.ply"))
    return edit


def _cam(col: str, value):
    def edit(b):
        t = pq.read_table(b / "cameras.parquet")
        vals = t.column(col).to_pylist()
        vals[3] = [value] * 16 if col == "cam_to_world" else value
        t = t.set_column(t.schema.get_field_index(col), t.schema.field(col), pa.array(vals, t.schema.field(col).type))
        pq.write_table(t, b / "cameras.parquet")
    return edit


def _metric(text: str):
    def edit(b):
        raw = (b / "scene.json").read_text()
        s = json.loads(raw)
        s["metrics"] = {"psnr": 1.0}
        (b / "scene.json").write_text(json.dumps(s).replace('"psnr": 1.0', f'"psnr": {text}'))
    return edit


CASES = {
    "NaN opacity": (_ply("opacity", np.nan), "opacities.*opacity"),
    "inf scale": (_ply("scale_1", np.inf), "scales.*scale_1"),
    "NaN position": (_ply("y", np.nan), "positions"),
    "NaN colour": (_ply("f_dc_0", np.nan), "colours"),
    "zero quaternion": (_ply("rot_0,rot_1,rot_2,rot_3", 0.0, slice(2, 4)), "2 splat.*zero rotation"),
    "NaN fx": (_cam("fx", float("nan")), "non-finite 'fx'"),
    "inf cx": (_cam("cx", float("inf")), "non-finite 'cx'"),
    "NaN pose": (_cam("cam_to_world", float("nan")), "cam_to_world"),
    "negative width": (_cam("width", -64), "'width' must be > 0"),
    "zero fy": (_cam("fy", 0.0), "'fy' must be > 0"),
    "NaN metric": (_metric("NaN"), "non-finite number NaN"),
    "Infinity metric": (_metric("-Infinity"), "non-finite number -Infinity"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_values_refused_nothing_stored(tmp_path, case):
    edit, pattern = CASES[case]
    b = make_bundle(tmp_path / "b", "ok-id")
    edit(b)
    root = tmp_path / "reg"
    with pytest.raises(BundleError, match=pattern):
        Registry(root).add(b)
    assert not root.exists()


def test_nan_metric_from_python_is_refused(tmp_path):
    from vid2sim.formats.scene import check_scene_json

    s = json.loads((make_bundle(tmp_path / "b", "x") / "scene.json").read_text())
    s["metrics"] = {"eval": {"psnr": float("nan")}}
    with pytest.raises(BundleError, match="finite"):
        check_scene_json(s)
