"""benchmarks/distill.py reuses a run folder only for the scenes it trained on, and goes on from a
finished shorter run only of the same settings."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

import distill as distill_bench  # noqa: E402  (benchmarks/distill.py)


def test_a_run_folder_trained_on_other_scenes_is_refused(tmp_path):
    (tmp_path / "config.json").write_text(json.dumps({"scene_ids": ["street-v1", "street-v2"]}))
    distill_bench.check_same_scenes(tmp_path, ["street-v2", "street-v1"])  # the same scenes: reused
    distill_bench.check_same_scenes(tmp_path, None)  # the split's training side: not checked
    distill_bench.check_same_scenes(tmp_path / "new", ["street-v3"])  # no run there yet
    refused = r"trained on 2 scenes \(street-v1, street-v2, \.\.\.\), the call asks for a different set of 3"
    with pytest.raises(SystemExit, match=refused):
        distill_bench.check_same_scenes(tmp_path, ["street-v1", "street-v2", "street-v3"])


def test_a_longer_run_goes_on_from_a_finished_shorter_one_and_counts_both_budgets(tmp_path):
    from dataclasses import replace

    from benchmarks.street_registry import build
    from tests.test_training_distill import tiny_config

    registry = build(tmp_path / "streets", [1, 2]).root
    config = tiny_config(registry, tmp_path / "run_120", 120)
    short = distill_bench.train_or_reuse(config)
    source = tmp_path / "run_120"
    (source / "eval_gt_splat_held-out.json").write_text("{}")  # an evaluation report stays behind
    before = {p.name: p.read_bytes() for p in [source / "config.json", *sorted((source / "data").iterdir())]}
    longer = replace(config, run_dir=str(tmp_path / "run_180"), total_steps=180)
    budget = distill_bench.train_or_reuse(longer, start_from=source)
    assert budget["env_steps"] == 180 and budget["started_from"] == {"run": str(source), "env_steps": 120}
    assert budget["train_cpu_s"] >= short["train_cpu_s"] and budget["train_wall_s"] >= short["train_wall_s"]
    run = tmp_path / "run_180"
    assert sorted(p.name for p in (run / "data").iterdir()) == ["round_000.npz", "round_001.npz", "round_002.npz"]
    assert not (run / "eval_gt_splat_held-out.json").exists()
    assert json.loads((run / "config.json").read_text())["total_steps"] == 180
    assert {p.name: p.read_bytes() for p in [source / "config.json", *sorted((source / "data").iterdir())]} == before
    assert distill_bench.train_or_reuse(longer, start_from=source) == budget  # finished: reused
    other = replace(longer, run_dir=str(tmp_path / "run_180_seed4"), seed=4)
    with pytest.raises(SystemExit, match=r"trained with other settings \(seed\)"):
        distill_bench.train_or_reuse(other, start_from=source)
    with pytest.raises(SystemExit, match="already has 120 env steps, the call asks for 120"):
        distill_bench.train_or_reuse(replace(config, run_dir=str(tmp_path / "again")), start_from=source)
    with pytest.raises(SystemExit, match="not a finished run"):
        distill_bench.train_or_reuse(replace(longer, run_dir=str(tmp_path / "x")), start_from=tmp_path / "none")
    (tmp_path / "interrupted").mkdir()
    with pytest.raises(SystemExit, match="an unfinished run is already there"):
        distill_bench.train_or_reuse(replace(longer, run_dir=str(tmp_path / "interrupted")), start_from=source)
    assert not list(tmp_path.glob("*.partial"))
