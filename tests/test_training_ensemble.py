"""Ensembles of distilled students: the mean of the members' actions, saved and loaded like one student,
exported, evaluated, built from the command line; named errors for members that cannot drive together."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from vid2sim.cli.app import app
from vid2sim.training.distill import STUDENT_NAME
from vid2sim.training.ensemble import ENSEMBLE_META, EnsembleError, StudentEnsemble, build_ensemble, load_student
from vid2sim.training.evaluate import EvalConfig, evaluate
from vid2sim.training.export import NavPolicy, export_policy
from vid2sim.training.student import StudentConfig, StudentPolicy

TINY = StudentConfig(frames=2, pool=2, channels=(4, 4, 8, 8), frame_dim=16, vector_dim=8, hidden=16)
IMAGE, VECTOR = (6, 3, 72, 128), (6, 2)


def student_run(folder: Path, seed: int, config: StudentConfig = TINY, image_shape=IMAGE) -> Path:
    """A run folder holding one student with seeded random weights (what a distillation run leaves)."""
    torch.manual_seed(seed)
    folder.mkdir(parents=True)
    StudentPolicy(config, image_shape, VECTOR).eval().save(folder / STUDENT_NAME)
    return folder


def observations(n: int = 3, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return (rng.integers(0, 256, (n, *IMAGE), dtype=np.uint8), rng.normal(size=(n, *VECTOR)).astype(np.float32))


@pytest.fixture()
def three_runs(tmp_path) -> list[Path]:
    wider = StudentConfig(**{**TINY.to_dict(), "frames": 3, "pool": 4})  # members may preprocess differently
    return [student_run(tmp_path / "a", 0), student_run(tmp_path / "b", 1), student_run(tmp_path / "c", 2, wider)]


def test_the_ensemble_acts_as_the_mean_of_its_members_and_survives_save_and_load(three_runs, tmp_path):
    out = build_ensemble(three_runs, tmp_path / "ens")
    ensemble = load_student(out / STUDENT_NAME)
    assert isinstance(ensemble, StudentEnsemble) and len(ensemble.members) == 3
    meta = json.loads((out / ENSEMBLE_META).read_text())
    assert meta["members"] == [str(r.resolve()) for r in three_runs]
    assert [c["frames"] for c in meta["architecture"]["ensemble"]] == [2, 2, 3]
    image, vector = (torch.from_numpy(a) for a in observations())
    with torch.no_grad():
        members = [load_student(r / STUDENT_NAME)(image, vector) for r in three_runs]
        got = ensemble(image, vector)
    assert not torch.allclose(members[0], members[1])  # distinct students, so the mean is a real average
    torch.testing.assert_close(got, torch.stack(members).mean(0))
    assert got.shape == (3, 2) and got.abs().max() <= 1.0


def test_the_exported_ensemble_equals_the_loaded_one(three_runs, tmp_path):
    out = build_ensemble(three_runs, tmp_path / "ens")
    export = export_policy(out, tmp_path / "export")
    meta = json.loads((export / "policy.json").read_text())
    assert meta["method"] == "distill" and len(meta["architecture"]["ensemble"]) == 3
    image, vector = observations(seed=1)
    with torch.no_grad():
        expected = load_student(out / STUDENT_NAME)(torch.from_numpy(image), torch.from_numpy(vector)).numpy()
    for backend in ("onnx", "torch"):
        np.testing.assert_allclose(NavPolicy(export, backend).act_stacked(image, vector), expected, atol=1e-5)


def test_members_that_cannot_drive_together_are_refused_by_name(three_runs, tmp_path):
    with pytest.raises(EnsembleError, match="too_few_members"):
        build_ensemble(three_runs[:1], tmp_path / "one")
    small = student_run(tmp_path / "small", 3, image_shape=(6, 3, 36, 64))
    with pytest.raises(EnsembleError, match="observation_mismatch"):
        build_ensemble([three_runs[0], small], tmp_path / "mixed")
    nested = build_ensemble(three_runs[:2], tmp_path / "ens")
    with pytest.raises(EnsembleError, match="nested_ensemble"):
        build_ensemble([nested, three_runs[2]], tmp_path / "nested")
    with pytest.raises(FileNotFoundError, match="no policy"):
        build_ensemble([three_runs[0], tmp_path / "missing"], tmp_path / "gone")
    assert not (tmp_path / "mixed").exists() and not (tmp_path / "gone").exists()  # nothing half-written


def test_eval_policy_drives_the_ensemble(three_runs, tmp_path):
    from benchmarks.street_registry import build

    registry = build(tmp_path / "streets", [1])
    out = build_ensemble(three_runs[:2], tmp_path / "ens")
    scene = registry.list()[0].scene_id
    report = evaluate(EvalConfig(registry=str(registry.root), policy=str(out), scene_ids=[scene], trials=1,
                                 max_steps=10, checkout_root=str(tmp_path / "checkouts")))
    assert report.episodes == 1 and report.records[0]["steps"] <= 10


def test_the_command_builds_an_ensemble_and_names_a_bad_run(three_runs, tmp_path):
    runner = CliRunner()
    ok = runner.invoke(app, ["ensemble", *map(str, three_runs), "--out", str(tmp_path / "ens"), "--json"])
    assert ok.exit_code == 0, ok.output
    assert len(json.loads(ok.stdout)["members"]) == 3 and (tmp_path / "ens" / STUDENT_NAME).is_file()
    bad = runner.invoke(app, ["ensemble", str(three_runs[0]), str(tmp_path / "missing"), "--out", str(tmp_path / "x")])
    assert bad.exit_code == 2 and "missing" in bad.stderr and "Traceback" not in bad.output
