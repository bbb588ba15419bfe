"""Input that controls an allocation is capped before the allocation: a walkable.npz that declares
a huge grid, and a query whose result outgrows `--memory`, each end in one named error."""

from __future__ import annotations

import resource

import pytest
from bomb_files import write_walkable_bomb
from registry_fixtures import make_bundle
from typer.testing import CliRunner

from vid2sim.cli.app import app
from vid2sim.formats.errors import BundleTooLarge
from vid2sim.formats.walkable import MAX_WALKABLE_CELLS, load_walkable
from vid2sim.registry import Registry
from vid2sim.registry.query import BadQueryLimit, QueryLimits, ResultTooLarge


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def test_walkable_bomb_is_refused_before_it_inflates(tmp_path):
    rows = cols = 8200  # 67.2M cells: just over the cap, 67 MB inflated from ~70 KB
    assert rows * cols > MAX_WALKABLE_CELLS
    path = write_walkable_bomb(tmp_path / "walkable.npz", rows, cols)
    before = _peak_mb()
    with pytest.raises(BundleTooLarge, match=r"walkable.npz: grid declares 67,240,000 elements"):
        load_walkable(path)
    assert _peak_mb() - before < 50


def test_walkable_bomb_in_a_bundle_stores_nothing(tmp_path):
    bundle = make_bundle(tmp_path / "b", "bomb")
    write_walkable_bomb(bundle / "walkable.npz", 8200, 8200)
    r = CliRunner().invoke(app, ["registry", "add", str(bundle), "-r", str(tmp_path / "reg"), "--json"])
    assert r.exit_code == 2 and "over the cap of 67,108,864" in r.stderr
    assert not (tmp_path / "reg").exists()


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("caps")
    reg = Registry(tmp / "reg")
    reg.add(make_bundle(tmp / "b0", "s0"))
    return str(reg.root)


def test_query_result_is_capped_by_memory(root):
    sql = "select repeat('x', 100000) as s from range(20000)"  # 2 GB of rows
    with pytest.raises(ResultTooLarge, match="exceeds the cap of 64,000,000 bytes"):
        Registry(root).query_head(sql, limits=QueryLimits(memory="64MB", max_rows=100_000))
    r = CliRunner().invoke(app, ["registry", "query", sql, "-r", root, "--memory", "64MB", "--max-rows", "100000"])
    assert r.exit_code == 2 and "exceeds the cap" in r.stderr and r.stdout == ""


def test_query_under_the_cap_returns_rows(root):
    table, more = Registry(root).query_head("select repeat('x', 1000) as s from range(100)",
                                            limits=QueryLimits(memory="16MB"))
    assert table.num_rows == 100 and not more


@pytest.mark.parametrize("memory", ["abc", "-5MB", "1KB", "12XB", "", "nanMB"])
def test_odd_memory_values_are_named(root, memory):
    with pytest.raises(BadQueryLimit, match="memory limit"):
        QueryLimits(memory=memory)
    r = CliRunner().invoke(app, ["registry", "query", "select 1", "-r", root, "--memory", memory])
    assert r.exit_code == 2 and "memory limit" in r.stderr and "Traceback" not in r.output


def test_cameras_table_over_the_row_cap_is_refused_before_reading(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq
    from registry_fixtures import cameras_table

    from vid2sim.formats.cameras import MAX_CAMERA_ROWS, load_cameras

    bundle = make_bundle(tmp_path / "b", "many-frames")
    rows = cameras_table(16)
    pq.write_table(pa.concat_tables([rows] * (MAX_CAMERA_ROWS // 16 + 1)), bundle / "cameras.parquet",
                   compression="zstd")
    with pytest.raises(BundleTooLarge, match=r"cameras.parquet: declares 1,000,016 rows, over the cap"):
        load_cameras(bundle / "cameras.parquet")
    r = CliRunner().invoke(app, ["registry", "add", str(bundle), "-r", str(tmp_path / "reg")])
    assert r.exit_code == 2 and "over the cap of 1,000,000" in r.stderr
