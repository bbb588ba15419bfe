"""The benchmark harness (benchmarks/common.py) and the docs renderer (benchmarks/render_docs.py)."""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "benchmarks"
sys.path.insert(0, str(BENCH))

import common  # noqa: E402  (benchmarks/common.py)
import render_docs  # noqa: E402  (benchmarks/render_docs.py)

TOP_KEYS = {"schema", "benchmark", "description", "status", "started_utc", "started_unix", "finished_utc",
            "duration_s", "command", "argv", "cwd", "args", "config", "env", "hardware", "load", "git", "versions",
            "notes", "rows"}


def tiny_run(out: Path, name: str = "tiny", value_scale: float = 1.0, cases=("grid 40x60", "grid 80x120"),
             **kw) -> Path:
    """A real (tiny) benchmark: time WalkableGrid.area_m2 on two grid sizes through the harness."""
    from vid2sim.formats.walkable import WalkableGrid

    ap = common.add_run_args(argparse.ArgumentParser())
    ap.add_argument("--reps", type=int, default=5)
    args = ap.parse_args(["--reps", "5", "--results", f"{out}/"])  # a folder: ends with "/"
    with common.Run(name, args, config={"what": "area_m2"}, **kw) as run:
        for case in cases:
            h, w = (int(x) for x in case.split()[1].split("x"))
            grid = WalkableGrid(np.ones((h, w), np.uint8), np.zeros(2), 0.1)
            area = grid.area_m2()
            run.record(case, "area_m2", area * value_scale, "m2", {"resolution_m": 0.1})
            run.record(case, "cells", np.int64(h * w))
        run.note("a tiny benchmark")
    return run.path


def test_run_writes_one_json_with_the_required_keys(tmp_path, capsys):
    path = tiny_run(tmp_path / "out")
    header = capsys.readouterr().out.splitlines()[0]
    assert header.startswith("# tiny: ") and "load " in header and "commit " in header
    assert re.fullmatch(r"tiny-\d{8}T\d{6}Z\.json", path.name) and path.parent == tmp_path / "out"
    assert [p.name for p in (tmp_path / "out").iterdir()] == [path.name]  # one file, no leftovers
    d = json.loads(path.read_text())
    assert TOP_KEYS <= set(d) and d["schema"] == common.SCHEMA and d["status"] == "ok"
    hw = d["hardware"]
    assert hw["cpu_model"] and hw["cores"] == os.cpu_count() and hw["memory_gib"] > 0 and "gpu" in hw
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists() and "flags" in cpuinfo.read_text():
        flags = set(next(ln for ln in cpuinfo.read_text().splitlines()
                         if ln.startswith("flags")).split(":", 1)[1].split())
        assert hw["simd"] in flags and hw["simd"] in common.SIMD_LEVELS
        wider = common.SIMD_LEVELS[:common.SIMD_LEVELS.index(hw["simd"])]
        assert not flags & set(wider)  # the widest the CPU has, not merely one it has
        assert re.fullmatch(r"\S+ family \d+ model \d+", hw["cpu_id"])
    assert len(d["load"]["start"]) == 3 and len(d["load"]["end"]) == 3
    assert re.fullmatch(r"[0-9a-f]{40}", d["git"]["commit"]) and isinstance(d["git"]["dirty"], bool)
    assert d["versions"]["python"].endswith(sys.version.split()[0]) and d["versions"]["numpy"] == np.__version__
    assert d["args"] == {"reps": 5} and d["config"] == {"what": "area_m2"} and d["notes"] == ["a tiny benchmark"]
    assert d["command"].split()[0].endswith("python") or "python" in d["command"]
    rows = d["rows"]
    assert len(rows) == 4 and all(set(r) == set(common.ROW_KEYS) for r in rows)
    assert rows[0] == {"benchmark": "tiny", "case": "grid 40x60", "metric": "area_m2",
                       "value": pytest.approx(40 * 60 * 0.01), "unit": "m2", "config": {"resolution_m": 0.1}}
    assert rows[1]["value"] == 2400 and isinstance(rows[1]["value"], int)  # numpy scalar -> plain JSON


def test_results_path_env_and_values(tmp_path, monkeypatch):
    monkeypatch.setenv(common.RESULTS_ENV, str(tmp_path / "env.json"))
    with common.Run("envpath", quiet=True) as run:
        run.record("c", "nan", float("nan"))
        run.record("c", "inf", np.float32("inf"))
        run.record_all("c", {"ok": True, "text": "a|b", "none": None, "arr": np.arange(2)}, {"ok": ""})
    d = json.loads((tmp_path / "env.json").read_text())
    assert [r["value"] for r in d["rows"]] == ["nan", "inf", True, "a|b", None, [0, 1]]
    assert "VID2SIM_BENCH_RESULTS" not in d["env"]


def test_failed_run_is_marked_and_not_rendered(tmp_path):
    with pytest.raises(RuntimeError):
        with common.Run("broken", results=tmp_path / "r" / "broken.json", quiet=True) as run:
            run.record("c", "m", 1.0)
            raise RuntimeError("boom")
    d = json.loads((tmp_path / "r" / "broken.json").read_text())
    assert d["status"] == "failed: RuntimeError: boom" and len(d["rows"]) == 1
    render_docs.render(tmp_path / "r", tmp_path / "docs")
    assert not (tmp_path / "docs" / "broken.md").exists()


def test_renderer_page_names_command_commit_hardware_and_latest_case(tmp_path):
    old = tiny_run(tmp_path / "res", value_scale=1.0)
    d = json.loads(old.read_text())
    d["started_utc"], d["started_unix"] = "2000-01-01T00:00:00+00:00", 946684800.0  # clearly the older run
    old.write_text(json.dumps(d))
    new = tiny_run(tmp_path / "res", value_scale=2.0, cases=("grid 40x60",), quiet=True)
    assert new != old
    pages = render_docs.render(tmp_path / "res", tmp_path / "docs")
    assert {p.name for p in pages} == {"tiny.md", "index.md"}
    page = (tmp_path / "docs" / "tiny.md").read_text()
    latest = json.loads(new.read_text())
    assert f"`{latest['command']}`" in page
    assert latest["git"]["commit"][:12] in page and latest["hardware"]["cpu_model"] in page
    assert "## Run of 2000-01-01 00:00 UTC" in page  # case "grid 80x120" still comes from the old run
    newer, older = page.split("## Run of 2000-01-01")
    assert "| grid 40x60 | 48 | 2400 |" in newer and "grid 40x60" not in older  # latest run wins the case
    assert "| grid 80x120 | 96 | 9600 |" in older
    index = (tmp_path / "docs" / "index.md").read_text()
    assert "[tiny](tiny.md)" in index and "benchmarks/registry.py" in index  # no results for registry here
    before = page
    render_docs.render(tmp_path / "res", tmp_path / "docs")
    assert (tmp_path / "docs" / "tiny.md").read_text() == before  # rendering is deterministic


def test_back_to_back_runs_latest_wins(tmp_path):
    first = tiny_run(tmp_path, value_scale=1.0, cases=("grid 10x10",), quiet=True)
    second = tiny_run(tmp_path, value_scale=3.0, cases=("grid 10x10",), quiet=True)
    assert first != second  # same second or not, two files
    render_docs.render(tmp_path, tmp_path / "docs")
    page = (tmp_path / "docs" / "tiny.md").read_text()
    assert "| grid 10x10 | 3 | 100 |" in page and page.count("## Run of") == 1


def test_quick_benchmark_script_as_a_subprocess(tmp_path):
    """benchmarks/envs_assets.py with few repetitions (a few seconds): header, table, results file."""
    env = {**os.environ, common.RESULTS_ENV: str(tmp_path) + "/"}
    p = subprocess.run([sys.executable, str(BENCH / "envs_assets.py"), "--reps", "3"], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    lines = p.stdout.splitlines()
    assert lines[0].startswith("# envs_assets: ") and "ms CPU" in p.stdout
    files = list(tmp_path.glob("envs_assets-*.json"))
    assert len(files) == 1
    d = json.loads(files[0].read_text())
    assert d["status"] == "ok" and d["args"]["reps"] == 3 and d["command"].endswith("envs_assets.py --reps 3")
    cases = {r["case"] for r in d["rows"]}
    assert any(c.startswith("augment.apply") for c in cases)
    assert {r["metric"] for r in d["rows"]} == {"cpu_ms", "wall_ms"}
    assert len(cases) == sum(": " in ln and "ms CPU" in ln for ln in lines)  # every printed line is recorded


def test_meshing_variants_go_by_name():
    import meshing  # benchmarks/meshing.py

    assert {"default", "blocks", "blocks_fill", "legacy", "map_0.05m", "no_lump_rule"} <= set(meshing.VARIANTS)
    assert meshing.DEFAULT_VARIANT == "default"
    ns = argparse.Namespace(only="map_0.05m, no_lump_rule,default", ablation=False, variant="default")
    assert meshing.variant_names(ns) == ["map_0.05m", "no_lump_rule", "default"]
    with pytest.raises(SystemExit, match="unknown variant"):
        meshing.variant_names(argparse.Namespace(only="26,25,6", ablation=False, variant="default"))
    assert all(re.fullmatch(r"[a-z0-9_.]+", n) for n in meshing.VARIANTS)
