"""`registry query` is read-only SQL over the manifests, nothing more.

Each attack the issue reproduced runs against a real registry through the real CLI and must be
refused with one named line, leaving no file behind.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from registry_fixtures import make_bundle
from typer.testing import CliRunner

from vid2sim.cli.app import app
from vid2sim.registry import Registry
from vid2sim.registry.query import QueryError, QueryLimits


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("q")
    reg = Registry(tmp / "reg")
    for i in range(3):
        reg.add(make_bundle(tmp / f"b{i}", f"s{i}", seed=i))
    return str(reg.root)


def _q(root: str, sql: str, *extra: str):
    return CliRunner().invoke(app, ["registry", "query", sql, "-r", root, *extra])


def test_plain_selects_still_work(root):
    r = _q(root, "select scene_id from latest order by 1", "--json")
    assert r.exit_code == 0 and [x["scene_id"] for x in json.loads(r.stdout)] == ["s0", "s1", "s2"]


ATTACKS = {
    "read a file": ("select content from read_text('/etc/passwd')", "Permission"),
    "read parquet": ("select * from read_parquet('{tmp}/*.parquet')", "Permission"),
    "copy to a file": ("copy (select 1) to '{tmp}/out.csv'", "one read-only SELECT"),
    "attach + create": ("attach '{tmp}/x.db' as x; create table x.t as select 1", "one read-only SELECT"),
    "install": ("install httpfs", "one read-only SELECT"),
    "load": ("load httpfs", "one read-only SELECT"),
    "unlock config": ("set enable_external_access = true", "one read-only SELECT"),
    "pragma": ("pragma version", "one read-only SELECT"),
    "two statements": ("select 1; select 2", "one read-only SELECT"),
    "create in memory": ("create table t as select 1", "one read-only SELECT"),
    "table function over url": ("select * from read_csv('http://127.0.0.1:9/x.csv')", "Permission"),
}


@pytest.mark.parametrize("case", sorted(ATTACKS))
def test_attack_is_refused_with_one_line(root, tmp_path, case):
    sql, why = ATTACKS[case]
    r = _q(root, sql.format(tmp=tmp_path))
    assert r.exit_code == 2, r.output
    assert r.stderr.startswith("error: ") and r.stderr.count("\n") == 1 and why in r.stderr, r.stderr
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_huge_result_is_cut_at_the_row_limit(root):
    r = _q(root, "select * from range(100000000)", "--json", "--max-rows", "50")
    assert r.exit_code == 0 and len(json.loads(r.stdout)) == 50 and "first 50 rows" in r.stderr
    with pytest.raises(QueryError, match="more than 10 rows"):
        Registry(root).query("select * from range(1000)", limits=QueryLimits(max_rows=10))


def test_memory_limit_stops_a_greedy_query(root):
    sql = "select list(range) from (select * from range(10000000)) group by range % 3"
    with pytest.raises(QueryError, match="(?i)memory|out of"):
        Registry(root).query(sql, limits=QueryLimits(memory="16MB", max_rows=5))


def test_time_limit_interrupts(root):
    sql = "select count(*) from range(100000000) a, range(100000000) b"
    with pytest.raises(QueryError, match="time limit"):
        Registry(root).query(sql, limits=QueryLimits(timeout_s=1.0))


@pytest.mark.slow
def test_shadow_file_never_printed_by_real_process(root):
    r = subprocess.run([sys.executable, "-m", "vid2sim.cli", "registry", "query",
                        "select content from read_text('/etc/passwd')", "-r", root], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and "root:" not in r.stdout + r.stderr and "Traceback" not in r.stderr
