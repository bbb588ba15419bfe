"""Two evaluation reports compared on their shared episodes (`vid2sim.training.compare`)."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import asdict, replace

import pytest

from vid2sim.envs.metrics import EpisodeRecord
from vid2sim.training.compare import UnpairedReports, keyed_records, paired_difference
from vid2sim.training.evaluate import EvalConfig, EvalReport, summarize


def report(successes: dict[str, list[bool]], **config) -> EvalReport:
    """A report as `evaluate` writes it: scenes in the given order, trial k the k-th record of its scene."""
    records, scenes = [], []
    for scene, wins in successes.items():
        for ok in wins:
            records.append(EpisodeRecord(ok, 10.0, 11.0 if ok else 4.0, 0 if ok else 1, 0, 0, 50, "success" if ok
                                         else "timeout"))
            scenes.append(scene)
    metrics, per_scene = summarize(records, scenes)
    conf = asdict(EvalConfig(registry="/reg", policy="p", trials=max(len(w) for w in successes.values()), **config))
    return EvalReport(conf, len(records), metrics, per_scene,
                      [{"scene_id": s, **asdict(r)} for s, r in zip(scenes, records)])


def test_the_difference_pairs_episodes_by_scene_and_trial_whatever_the_scene_order():
    a = report({"s1": [True, False, False, True], "s2": [False, False, True, True]})
    b = report({"s2": [True, False, True, True], "s1": [True, True, False, True]})  # other scene order
    c = paired_difference(a, b)
    assert c.episodes == 8 and c.mean_a == pytest.approx(0.5) and c.mean_b == pytest.approx(0.75)
    assert c.difference.mean == pytest.approx(0.25) and c.only_a == 0 and c.only_b == 2
    assert c.difference.low <= 0.25 <= c.difference.high
    back = paired_difference(b, a)
    assert back.difference.mean == pytest.approx(-0.25) and (back.only_a, back.only_b) == (2, 0)
    assert back.p_not_better == 1.0 and c.p_not_better < 0.5


def test_identical_reports_differ_by_nothing_and_only_shared_episodes_count():
    a = report({"s1": [True, False, True], "s2": [False, True, True]})
    same = paired_difference(a, a)
    assert same.difference.mean == 0.0 and same.difference.low == 0.0 == same.difference.high
    fewer = report({"s1": [False, False]})  # 2 trials of one scene: 2 shared episodes
    c = paired_difference(a, fewer)
    assert c.episodes == 2 and c.mean_a == 0.5 and c.mean_b == 0.0
    assert set(keyed_records(a)) == {("s1", 0), ("s1", 1), ("s1", 2), ("s2", 0), ("s2", 1), ("s2", 2)}


def test_other_metrics_use_the_episode_values():
    a = report({"s1": [True, True]})
    b = report({"s1": [True, False]})
    spl = paired_difference(a, b, "spl")
    assert spl.mean_a == pytest.approx(10 / 11) and spl.mean_b == pytest.approx(5 / 11)
    assert paired_difference(a, b, "cost").difference.mean == pytest.approx(0.5)


@pytest.mark.parametrize("change, field", [({"seed": 7}, "seed"), ({"obstacles": "none"}, "obstacles"),
                                           ({"max_steps": 600}, "max_steps"), ({"registry": "/other"}, "registry")])
def test_reports_of_other_episodes_are_refused_naming_the_setting(change, field):
    a = report({"s1": [True, False]})
    b = replace(a, config={**a.config, **change})
    with pytest.raises(UnpairedReports, match=f"^{field}: "):
        paired_difference(a, b)


def test_no_shared_episode_or_an_unknown_metric_is_refused():
    a = report({"s1": [True]})
    with pytest.raises(UnpairedReports, match="^episodes: "):
        paired_difference(a, report({"s2": [True]}))
    with pytest.raises(UnpairedReports, match="^metric: "):
        paired_difference(a, a, "speed")


def test_the_cli_compares_two_saved_reports_and_names_a_file_that_is_not_one(tmp_path):
    pa, pb, bad = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "bad.json"
    pa.write_text(report({"s1": [False, False, True]}).to_json())
    pb.write_text(report({"s1": [True, False, True]}).to_json())
    bad.write_text(json.dumps({"rows": []}))
    run = [sys.executable, "-m", "vid2sim.cli", "eval", "compare"]
    out = subprocess.run([*run, str(pa), str(pb), "--json"], capture_output=True, text=True, check=True).stdout
    got = json.loads(out)
    assert got["episodes"] == 3 and got["difference"]["mean"] == pytest.approx(1 / 3) and got["only_b"] == 1
    failed = subprocess.run([*run, str(pa), str(bad)], capture_output=True, text=True)
    assert failed.returncode == 2 and "REPORT_B" in failed.stderr and "not an evaluation report" in failed.stderr
