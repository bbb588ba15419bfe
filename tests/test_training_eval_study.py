"""Evaluation statistics, study count checks and plot (quick); expert eval and a study end to end (slow)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from dataclasses import replace

import numpy as np
import pytest
import ray

from tests.conftest import PROJECT_ROOT
from vid2sim.envs.metrics import EpisodeRecord
from vid2sim.training.config import SACConfig
from vid2sim.training.evaluate import (EvalConfig, EvalReport, Interval, bootstrap_ci, evaluate, run_observation_kwargs,
                                       summarize)
from vid2sim.training.privileged import PRIVILEGED_ID
from vid2sim.training.rollouts import init_ray
from vid2sim.training.study import StudyConfig, StudyError, StudyRow, check_counts, plot, run_study, study_runs


def rec(success: bool, path: float, hits: int = 0) -> EpisodeRecord:
    return EpisodeRecord(success=success, shortest_length=10.0, path_length=path, collision_events=hits,
                         collision_steps=hits, proximity_steps=0, steps=50)


def test_summary_by_hand():
    records = [rec(True, 10.0), rec(True, 20.0, 1), rec(False, 5.0, 2), rec(True, 12.5)]
    metrics, per_scene = summarize(records, ["a", "a", "b", "b"])
    assert metrics["sr"].mean == pytest.approx(0.75)
    assert metrics["spl"].mean == pytest.approx((1.0 + 0.5 + 0.0 + 0.8) / 4)
    assert metrics["cost"].mean == pytest.approx(0.75)
    assert per_scene["a"]["spl"] == pytest.approx(0.75) and per_scene["b"]["sr"] == 0.5
    assert metrics["sr"].low <= 0.75 <= metrics["sr"].high


def test_eval_report_saved_then_loaded_is_equal():
    records = [rec(True, 10.0), rec(False, 5.0, 2)]
    metrics, per_scene = summarize(records, ["a", "b"])
    report = EvalReport(config={"trials": 1}, episodes=2, metrics=metrics, per_scene=per_scene,
                        records=[{"success": True}, {"success": False}])
    loaded = EvalReport.from_json(report.to_json())
    assert loaded == report and isinstance(loaded.metrics["sr"], Interval)


def test_a_runs_camera_and_ray_settings_are_evaluated_with_it(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "student.pt").write_bytes(b"")
    (run / "config.json").write_text(json.dumps({"env_kwargs": {
        "camera": {"vfov_deg": 90.0}, "n_rays": 9, "training": True, "fidelity": "fast"}}))
    assert run_observation_kwargs(str(run)) == {"camera": {"vfov_deg": 90.0}, "n_rays": 9}
    assert run_observation_kwargs("expert") == {}


def test_bootstrap_interval_shrinks_with_more_episodes():
    rng = np.random.default_rng(0)
    small, large = bootstrap_ci(rng.random(10) < 0.5), bootstrap_ci(rng.random(1000) < 0.5)
    assert large.high - large.low < small.high - small.low
    assert bootstrap_ci(np.ones(5)).low == 1.0


def test_counts_larger_than_the_pool_are_a_named_error():
    assert check_counts([5, 1, 3, 1], 5) == [1, 3, 5]
    with pytest.raises(StudyError, match=r"bad_count: .*\[15\].*1\.\.4"):
        check_counts([1, 15, 3], 4)
    with pytest.raises(StudyError, match="bad_count"):
        check_counts([0], 4)


def test_study_plot(tmp_path):
    rows = [StudyRow(n, s, "", [], sr, sr * 0.8, 0.1, 100, 1.0)
            for n, s, sr in [(1, 0, 0.2), (1, 1, 0.4), (3, 0, 0.5), (3, 1, 0.7)]]
    path = plot(rows, tmp_path / "study.png")
    assert path.stat().st_size > 1000


@pytest.fixture(scope="module")
def street_registry(tmp_path_factory):
    from benchmarks.street_registry import build
    return build(tmp_path_factory.mktemp("streets"), [1, 2, 3, 4, 5]).root


@pytest.mark.slow
def test_expert_reaches_goals_on_held_out_scene(street_registry, tmp_path):
    report = evaluate(EvalConfig(registry=str(street_registry), policy="expert", trials=3, env_id=PRIVILEGED_ID,
                                 checkout_root=str(tmp_path)))
    assert report.episodes == 3 and report.metrics["sr"].mean >= 2 / 3
    out = json.loads(report.to_json())
    assert set(out["metrics"]) >= {"sr", "spl", "cost", "sns"}


@pytest.mark.slow
def test_eval_passes_env_kwargs(street_registry, tmp_path):
    """`EvalConfig.env_kwargs` reach the env: a 5-step limit leaves the expert no time to reach a goal."""
    report = evaluate(EvalConfig(registry=str(street_registry), policy="expert", trials=2, env_id=PRIVILEGED_ID,
                                 checkout_root=str(tmp_path), env_kwargs={"n_rays": 5, "max_steps": 5}))
    assert report.episodes == 2 and report.metrics["sr"].mean == 0.0
    assert all(row["steps"] <= 5 for row in report.records)


@pytest.mark.slow
def test_study_end_to_end_on_ray(street_registry, tmp_path):
    path = os.pathsep.join([str(PROJECT_ROOT), os.environ.get("PYTHONPATH", "")])
    init_ray(num_cpus=2, runtime_env={"env_vars": {"PYTHONPATH": path}})
    try:
        sac = SACConfig(learning_starts=20, batch_size=8, buffer_size=200, net_arch=(16, 16))
        config = StudyConfig(registry=str(street_registry), out_dir=str(tmp_path), counts=[1, 99], seeds=1,
                             total_steps=40, n_envs=1, trials=1, sac=sac, env_id=PRIVILEGED_ID,
                             env_module="vid2sim.training.privileged")
        with pytest.raises(StudyError, match="bad_count"):
            run_study(config)
        rows = run_study(replace(config, counts=[1, 4]))
    finally:
        ray.shutdown()
    assert sorted(r.count for r in rows) == [1, 4]
    assert (tmp_path / "study.png").exists()
    assert json.loads((tmp_path / "study.json").read_text())["counts"] == [1, 4]


@pytest.mark.slow
def test_distill_study_end_to_end_on_ray(street_registry, tmp_path):
    from vid2sim.training.config import DistillConfig
    from vid2sim.training.student import StudentConfig

    path = os.pathsep.join([str(PROJECT_ROOT), os.environ.get("PYTHONPATH", "")])
    init_ray(num_cpus=2, runtime_env={"env_vars": {"PYTHONPATH": path}})
    try:
        distill = DistillConfig(steps_per_round=40, updates_per_round=4, batch_size=8, train_max_steps=30,
                                student=StudentConfig(channels=(4, 4, 8, 8), frame_dim=8, vector_dim=8, hidden=16))
        config = StudyConfig(registry=str(street_registry), out_dir=str(tmp_path), counts=[1, 4], seeds=1,
                             total_steps=40, n_envs=2, trials=1, method="distill", stuck_steps=10,
                             env_kwargs={"training": True, "fidelity": "exact"}, distill=distill, eval_max_steps=20)
        rows = run_study(config)
    finally:
        ray.shutdown()
    assert sorted(r.count for r in rows) == [1, 4]
    assert all((Path(r.run_dir) / "student.pt").is_file() and len(r.success) == 1 for r in rows)
    study = json.loads((tmp_path / "study.json").read_text())
    assert study["config"]["method"] == "distill" and "sr_ci_low" in study["aggregate"]["1"]


def test_a_study_trains_its_seeds_from_first_seed_for_every_count():
    config = StudyConfig(registry="r", out_dir="o", counts=[1, 5], seeds=2, first_seed=3)
    assert study_runs(config, [1, 5]) == [(1, 3), (1, 4), (5, 3), (5, 4)]
    assert study_runs(replace(config, first_seed=0, seeds=1), [1, 5]) == [(1, 0), (5, 0)]


def test_a_study_run_again_reuses_finished_runs_and_redoes_changed_ones(street_registry, tmp_path):
    from vid2sim.training.config import DistillConfig
    from vid2sim.training.student import StudentConfig
    from vid2sim.training.study import ROW_NAME, run_one

    distill = DistillConfig(steps_per_round=20, updates_per_round=2, batch_size=8, train_max_steps=20,
                            student=StudentConfig(channels=(4, 4, 8, 8), frame_dim=8, vector_dim=8, hidden=16))
    config = StudyConfig(registry=str(street_registry), out_dir=str(tmp_path), counts=[1], seeds=1, total_steps=20,
                         n_envs=1, trials=1, method="distill", env_kwargs={"training": True, "fidelity": "exact"},
                         distill=distill, eval_max_steps=5)
    first = run_one(config, 1, 0, ["synthetic-street-s1"])
    student = tmp_path / "n1_s0" / "student.pt"
    trained_at = student.stat().st_mtime_ns
    again = run_one(config, 1, 0, ["synthetic-street-s1"])
    assert again == first and student.stat().st_mtime_ns == trained_at  # reused, not retrained
    changed = run_one(replace(config, trials=2), 1, 0, ["synthetic-street-s1"])
    assert len(changed.success) == 2 * len(first.success) and student.stat().st_mtime_ns > trained_at
    recorded = json.loads((tmp_path / "n1_s0" / ROW_NAME).read_text())
    assert recorded["settings"]["eval"]["trials"] == 2


def test_a_study_report_gathers_the_folders_finished_runs_with_its_settings(street_registry, tmp_path):
    """study.json / study.png cover every finished run of the folder made with the study's settings,
    whichever invocation trained it; runs of another protocol or on other scenes than the split's
    nested subset stay out; an empty folder is a named error."""
    from vid2sim.training.config import DistillConfig
    from vid2sim.training.student import StudentConfig
    from vid2sim.registry import Registry
    from vid2sim.training.study import report_study, run_one

    distill = DistillConfig(steps_per_round=20, updates_per_round=2, batch_size=8, train_max_steps=20,
                            student=StudentConfig(channels=(4, 4, 8, 8), frame_dim=8, vector_dim=8, hidden=16))
    config = StudyConfig(registry=str(street_registry), out_dir=str(tmp_path), counts=[1], seeds=1, total_steps=20,
                         n_envs=1, trials=1, method="distill", env_kwargs={"training": True, "fidelity": "exact"},
                         distill=distill, eval_max_steps=5)
    with pytest.raises(StudyError, match="no_finished_runs"):
        report_study(config)
    first = Registry(str(street_registry)).split(seed=0, train_sizes=[1]).train_subsets[1]  # the study's train-1
    seed0 = run_one(config, 1, 0, first)
    seed1 = run_one(replace(config, trials=2), 1, 1, first)  # another protocol
    run_one(config, 1, 2, ["synthetic-street-s1"] if first != ["synthetic-street-s1"] else ["synthetic-street-s2"])
    (tmp_path / "n99_s0").mkdir()  # a count beyond the pool, never finished: ignored
    rows = report_study(replace(config, counts=[4], seeds=2, first_seed=5))  # counts / seeds asked do not matter
    assert rows == [seed0]
    study = json.loads((tmp_path / "study.json").read_text())
    assert study["counts"] == [1] and study["aggregate"]["1"]["seeds"] == 1 and (tmp_path / "study.png").is_file()
    assert report_study(replace(config, trials=2)) == [seed1]
