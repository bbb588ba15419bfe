"""Teacher-student distillation on a tiny budget: it runs, saves, resumes, exports the trained student,
evaluates; the student's preprocessing and augmentation; named errors for bad input."""

from __future__ import annotations

import json
import math
import os

import gymnasium as gym
import numba
import numpy as np
import pytest
import ray
import torch
from stable_baselines3.common.vec_env import VecEnvWrapper

from tests.conftest import PROJECT_ROOT
from vid2sim.ranges import RangeError
from vid2sim.training.config import DistillConfig, TrainConfig
from vid2sim.training.distill import (DEPTH_GRID, STUDENT_NAME, Batch, Dataset, DistillError, action_loss,
                                      ema_decay_at, env_specs, fit, make_optimizer, scene_groups, train_distill)
from vid2sim.training.evaluate import EvalConfig, ObservationMismatch, evaluate, load_student
from vid2sim.training.export import NavPolicy, export_policy
from vid2sim.training.rollouts import init_ray
from vid2sim.training.student import (SpatialSoftmax, StudentConfig, StudentPolicy, pursuit_steering,
                                      random_shift)
from vid2sim.training.wrappers import (TeacherError, TeacherLabels, check_depth_grid, depth_blocks,
                                       route_waypoints)

TINY = StudentConfig(frames=2, pool=2, channels=(4, 4, 8, 8), frame_dim=16, vector_dim=8, hidden=16)


@pytest.fixture(scope="module")
def street_registry(tmp_path_factory):
    from benchmarks.street_registry import build
    return build(tmp_path_factory.mktemp("streets"), [1, 2, 3]).root


def tiny_config(registry, run_dir, total_steps: int, n_actors: int = 0) -> TrainConfig:
    # exact fidelity while training: the fast path would first fit a sim-ready set per scene (~1 min)
    return TrainConfig(run_dir=str(run_dir), total_steps=total_steps, registry=str(registry), n_envs=2,
                       n_actors=n_actors, seed=3, method="distill", stuck_steps=10,
                       env_kwargs={"training": True, "fidelity": "exact"},
                       distill=DistillConfig(steps_per_round=60, updates_per_round=4, batch_size=8,
                                             train_max_steps=40, student=TINY))


def fit_conf(updates: int, batch_size: int, **weights: float) -> DistillConfig:
    """The learner settings `fit` reads: `updates` steps of `batch_size`, no random shift, no mirror
    (unless `mirror=` says otherwise)."""
    return DistillConfig(updates_per_round=updates, batch_size=batch_size, shift_pad=0, **{"mirror": 0.0, **weights})


@pytest.fixture(scope="module")
def distilled(street_registry, tmp_path_factory):
    run = tmp_path_factory.mktemp("distill") / "run"
    first = train_distill(tiny_config(street_registry, run, 120))
    return run, first


def test_runs_saves_and_logs(distilled):
    run, result = distilled
    assert result.num_timesteps == 120 and len(result.history) == 2
    assert [row["beta"] for row in result.history] == [1.0, 0.5]  # round 0 is behaviour cloning
    assert all(row["labels"] + row["dropped_stuck"] == 60 for row in result.history)
    assert json.loads((run / "config.json").read_text())["method"] == "distill"
    assert json.loads((run / "student.json").read_text())["student"]["channels"] == [4, 4, 8, 8]
    for name in ("round_000.npz", "round_001.npz"):
        shard = Batch.load(run / "data" / name)
        assert shard.frames.dtype == np.uint8 and shard.frames.shape[1:] == (2, 3, 36, 64)
        assert np.abs(shard.actions).max() <= 1.0 and len(shard.actions) == len(shard.vectors)
    assert (run / STUDENT_NAME).is_file() and (run / "checkpoints" / "last.pt").is_file()
    assert any((run / "tb").rglob("events.out.tfevents.*"))


def test_resume_goes_on_at_the_next_round(distilled, street_registry):
    run, first = distilled
    shard0 = (run / "data" / "round_000.npz").read_bytes()
    resumed = train_distill(tiny_config(street_registry, run, 180), resume=True)
    assert resumed.num_timesteps == 180
    assert [row["round"] for row in resumed.history] == [0, 1, 2]
    assert resumed.history[:2] == first.history
    assert (run / "data" / "round_000.npz").read_bytes() == shard0  # shards are written once
    assert resumed.history[2]["dataset"] == sum(row["labels"] for row in resumed.history)


def test_exported_student_equals_the_trained_one(distilled, tmp_path):
    run, _ = distilled
    student = load_student(run / STUDENT_NAME)
    out = export_policy(run, tmp_path / "export")
    meta = json.loads((out / "policy.json").read_text())
    assert meta["method"] == "distill" and meta["architecture"]["frames"] == 2
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (3, 6, 3, 72, 128), dtype=np.uint8)
    vector = rng.normal(size=(3, 6, 2)).astype(np.float32)
    with torch.no_grad():
        expected = student(torch.from_numpy(image), torch.from_numpy(vector)).numpy()
    for backend in ("onnx", "torch"):
        np.testing.assert_allclose(NavPolicy(out, backend).act_stacked(image, vector), expected, atol=1e-5)


def test_eval_policy_reads_the_student_and_checks_its_observation(distilled, street_registry, tmp_path):
    run, _ = distilled
    report = evaluate(EvalConfig(registry=str(street_registry), policy=str(run), trials=1, max_steps=20,
                                 checkout_root=str(tmp_path)))
    assert report.episodes >= 1 and 0.0 <= report.metrics["sr"].mean <= 1.0
    with pytest.raises(ObservationMismatch, match="observation_mismatch"):
        evaluate(EvalConfig(registry=str(street_registry), policy=str(run), trials=1, max_steps=5,
                            variant="depth", checkout_root=str(tmp_path)))


def test_preprocessed_inputs_give_the_deployed_actions():
    torch.manual_seed(0)
    student = StudentPolicy(TINY, (6, 3, 72, 128), (6, 2)).eval()
    image = torch.randint(0, 256, (4, 6, 3, 72, 128), dtype=torch.uint8)
    vector = torch.randn(4, 6, 2)
    stored = student.preprocess(image).numpy().astype(np.uint8)  # what the learner keeps
    assert stored.shape == (4, *student.input_shape)
    with torch.no_grad():
        np.testing.assert_array_equal(student.act(torch.from_numpy(stored), vector).numpy(),
                                      student(image, vector).numpy())
    expected = image[:, -2:].float().reshape(8, 3, 36, 2, 64, 2).mean(dim=(3, 5)).round().reshape(4, 2, 3, 36, 64)
    np.testing.assert_array_equal(stored, expected.numpy().astype(np.uint8))


def test_channels_last_encoder_agrees_with_the_contiguous_one_and_survives_a_checkpoint():
    torch.manual_seed(0)
    student = StudentPolicy(TINY, (6, 3, 72, 128), (6, 2)).eval()
    conv = student.encoder[0].weight
    assert conv.is_contiguous(memory_format=torch.channels_last) and not conv.is_contiguous()
    plain = StudentPolicy.from_checkpoint(student.checkpoint()).eval()
    plain.encoder.to(memory_format=torch.contiguous_format)  # the reference layout
    frames = torch.randint(0, 256, (5, *student.input_shape)).float()  # [5, 2, 3, 36, 64]
    vector = torch.randn(5, 6, 2)
    with torch.no_grad():
        torch.testing.assert_close(student.act(frames, vector), plain.act(frames, vector), atol=1e-5, rtol=0)
        loaded = StudentPolicy.from_checkpoint(student.checkpoint()).eval()
        assert loaded.encoder[0].weight.is_contiguous(memory_format=torch.channels_last)
        assert torch.equal(loaded.act(frames, vector), student.act(frames, vector))


def test_training_runs_on_the_configured_threads_and_gives_the_process_its_own_back(street_registry, tmp_path):
    before = min(2, numba.config.NUMBA_NUM_THREADS)
    torch.set_num_threads(2)
    numba.set_num_threads(before)
    inside = []
    train_distill(tiny_config(street_registry, tmp_path / "run", 60),
                  log=lambda row: inside.append((torch.get_num_threads(), numba.get_num_threads())))
    assert inside == [(1, 1)]  # DistillConfig.threads = 1
    assert (torch.get_num_threads(), numba.get_num_threads()) == (2, before)


def test_frame_stride_picks_every_kth_frame_back_from_the_latest():
    student = StudentPolicy(StudentConfig(frames=3, frame_stride=2, pool=1), (6, 1, 4, 4), (6, 2))
    image = torch.arange(6, dtype=torch.uint8).reshape(1, 6, 1, 1, 1).expand(1, 6, 1, 4, 4)
    assert student.preprocess(image)[0, :, 0, 0, 0].tolist() == [1.0, 3.0, 5.0]


def assert_exported_drives_alike(student: StudentPolicy, folder, image: torch.Tensor, vector: torch.Tensor,
                                 driven: torch.Tensor) -> None:
    """The student saved into `folder` and exported: both exported backends drive as `driven`."""
    student.save(folder / STUDENT_NAME)
    out = export_policy(folder, folder / "export")
    for backend in ("onnx", "torch"):
        np.testing.assert_allclose(NavPolicy(out, backend).act_stacked(image.numpy(), vector.numpy()),
                                   driven.numpy(), atol=1e-5)


def test_a_short_vector_history_reads_only_the_latest_goal_vectors_and_exports(tmp_path):
    """vector_history 1: the older goal vectors (which reveal the steering just applied) change nothing,
    the latest one does; the exported graph takes the env's whole [6, 2] history and agrees."""
    torch.manual_seed(0)
    student = StudentPolicy(StudentConfig(**{**TINY.to_dict(), "vector_history": 1}), (6, 3, 72, 128), (6, 2)).eval()
    image = torch.randint(0, 256, (3, 6, 3, 72, 128), dtype=torch.uint8)
    vector = torch.randn(3, 6, 2)
    older = vector.clone()
    older[:, :-1] = torch.randn(3, 5, 2)
    latest = vector.clone()
    latest[:, -1] += 1.0
    with torch.no_grad():
        base = student(image, vector)
        torch.testing.assert_close(student(image, older), base)
        assert (student(image, latest) - base).abs().max() > 1e-4
    student.save(tmp_path / "student.pt")
    again = StudentPolicy.load(tmp_path / "student.pt")
    with torch.no_grad():
        torch.testing.assert_close(again(image, vector), base)
    with pytest.raises(ValueError, match="latest 6"):
        StudentPolicy(StudentConfig(**{**TINY.to_dict(), "vector_history": 6}), (6, 3, 72, 128), (3, 2))
    with pytest.raises(RangeError, match="vector_history"):
        StudentConfig(vector_history=0)


def test_a_steering_gain_turns_harder_when_driving_not_in_the_loss_and_exports(tmp_path):
    """steer_gain g: the driven steering is tanh(g x the pre-activation) (sign kept, larger, in [-1, 1]),
    the speed and the learner's outputs unchanged; a saved copy and the exported graph drive with it."""
    torch.manual_seed(0)
    student = StudentPolicy(TINY, (6, 3, 72, 128), (6, 2)).eval()
    image = torch.randint(0, 256, (5, 6, 3, 72, 128), dtype=torch.uint8)
    vector = torch.randn(5, 6, 2)
    harder = student.driving_with(steer_gain=2.5)
    assert student.config.steer_gain == 1.0 and harder.config.steer_gain == 2.5
    with torch.no_grad():
        base, driven = student(image, vector), harder(image, vector)
        torch.testing.assert_close(driven[:, 0], base[:, 0])
        torch.testing.assert_close(driven[:, 1], torch.tanh(2.5 * torch.atanh(base[:, 1])), atol=1e-5, rtol=1e-4)
        assert (driven[:, 1].abs() > base[:, 1].abs()).all() and (driven[:, 1].sign() == base[:, 1].sign()).all()
        pre = harder.preprocess(image)
        torch.testing.assert_close(harder.outputs(pre, vector).actions, base)  # what the loss sees
    harder.save(tmp_path / STUDENT_NAME)
    loaded = StudentPolicy.load(tmp_path / STUDENT_NAME)
    with torch.no_grad():
        torch.testing.assert_close(loaded(image, vector), driven)
    out = export_policy(loaded, tmp_path / "export")
    np.testing.assert_allclose(NavPolicy(out, "torch").act_stacked(image.numpy(), vector.numpy()), driven.numpy(),
                               atol=1e-5)
    with pytest.raises(RangeError, match="steer_gain"):
        StudentConfig(steer_gain=0.0)
    with pytest.raises(ValueError, match="steer_gain"):
        StudentConfig(steer_bins=5, steer_gain=2.0)


def test_the_mirror_average_treats_left_and_right_alike_and_exports(tmp_path):
    """mirror_average: the driven action is the mean of the action and the mirrored action of the
    mirrored view, so the mirrored view gets exactly the mirrored action; saved and exported alike."""
    torch.manual_seed(0)
    student = StudentPolicy(TINY, (6, 3, 72, 128), (6, 2)).eval()
    image = torch.randint(0, 256, (5, 6, 3, 72, 128), dtype=torch.uint8)
    vector = torch.randn(5, 6, 2)
    flip = torch.tensor([1.0, -1.0])
    both = student.driving_with(mirror_average=True)
    with torch.no_grad():
        plain, mirrored_plain = student(image, vector), student(image.flip(-1), vector * flip)
        driven, mirrored = both(image, vector), both(image.flip(-1), vector * flip)
        torch.testing.assert_close(driven, 0.5 * (plain + mirrored_plain * flip))
        torch.testing.assert_close(mirrored, driven * flip)
        assert not torch.allclose(mirrored_plain, plain * flip, atol=1e-3)  # the plain student is not symmetric
    assert_exported_drives_alike(both, tmp_path, image, vector, driven)
    with pytest.raises(ValueError, match="not driving settings"):
        student.driving_with(frames=3)


def test_keypoint_features_are_expected_positions_that_mirror_and_export(tmp_path):
    """keypoints K: each frame's features are K expected (x, y) cell positions in [-1, 1]; a map
    flipped left to right negates every x and keeps every y; saved and exported alike."""
    torch.manual_seed(0)
    head = SpatialSoftmax(8, 5, 8, keypoints=4)
    maps = torch.rand(3, 8, 5, 8) * 4.0
    points = head(maps).reshape(3, 4, 2)
    assert points.abs().max() <= 1.0
    flipped = head(maps.flip(-1)).reshape(3, 4, 2)
    torch.testing.assert_close(flipped[..., 0], -points[..., 0])
    torch.testing.assert_close(flipped[..., 1], points[..., 1])
    peak = torch.zeros(1, 8, 5, 8)
    peak[0, :, 4, 7] = 50.0  # every channel peaks in the bottom-right cell
    with torch.no_grad():
        head.project.weight.copy_(torch.eye(4, 8)[:, :, None, None])
        head.project.bias.zero_()
    torch.testing.assert_close(head(peak).reshape(4, 2), torch.ones(4, 2), atol=1e-3, rtol=0)
    student = StudentPolicy(StudentConfig(**{**TINY.to_dict(), "keypoints": 4}), (6, 3, 72, 128), (6, 2)).eval()
    assert student.frame_head[0].in_features == 8
    image = torch.randint(0, 256, (5, 6, 3, 72, 128), dtype=torch.uint8)
    vector = torch.randn(5, 6, 2)
    with torch.no_grad():
        driven = student(image, vector)
    assert_exported_drives_alike(student, tmp_path, image, vector, driven)
    with pytest.raises(RangeError, match="keypoints"):
        StudentConfig(keypoints=-1)


def test_random_shift_crops_the_padded_frames_with_one_offset_per_sample():
    frames = torch.arange(2 * 2 * 1 * 6 * 8, dtype=torch.float32).reshape(2, 2, 1, 6, 8)
    assert torch.equal(random_shift(frames, 0), frames)
    out = random_shift(frames, 2, torch.Generator().manual_seed(1))
    padded = torch.nn.functional.pad(frames.reshape(2, 2, 6, 8), (2, 2, 2, 2), mode="replicate")
    for b in range(2):
        hits = [(dy, dx) for dy in range(5) for dx in range(5)
                if torch.equal(out[b].reshape(2, 6, 8), padded[b, :, dy:dy + 6, dx:dx + 8])]
        assert len(hits) == 1  # one offset, shared by both frames of the sample


def test_dataset_cap_drops_the_oldest_rounds():
    def batch(n, value):
        return Batch(np.full((n, 1, 1, 2, 2), value, np.uint8), np.zeros((n, 6, 2), np.float32),
                     np.full((n, 2), value / 10, np.float32))
    data = Dataset(max_samples=25)
    for k in range(4):
        data.add(batch(10, k))
    arrays = data.arrays()
    assert len(arrays.actions) == 25 and arrays.frames[0, 0, 0, 0, 0] == 1 and arrays.frames[-1, 0, 0, 0, 0] == 3


def test_dataset_even_eviction_keeps_every_round_in_proportion():
    def batch(n, value):
        return Batch(np.full((n, 1, 1, 2, 2), value, np.uint8), np.zeros((n, 6, 2), np.float32),
                     np.arange(n, dtype=np.float32)[:, None].repeat(2, 1))
    data = Dataset(max_samples=40, eviction="even")
    for k in range(8):
        data.add(batch(20, k))
    arrays = data.arrays()
    rounds = arrays.frames[:, 0, 0, 0, 0]
    counts = np.bincount(rounds, minlength=8)
    assert len(data) <= 40 and counts.min() >= 3  # every round, the teacher's first ones too, keeps a share
    assert counts.max() - counts.min() <= 3  # ... of about the same size (rounds were the same size)
    first = arrays.actions[rounds == 0, 0]
    assert first.min() == 0 and first.max() == 19  # spread over the round, not its head or tail
    with pytest.raises(DistillError, match="bad_eviction"):
        Dataset(10, eviction="random")
    with pytest.raises(ValueError, match="eviction"):
        DistillConfig(eviction="random")


def test_scene_groups_use_every_scene():
    assert scene_groups(["a", "b", "c", "d", "e"], 2) == [["a", "c", "e"], ["b", "d"]]
    assert scene_groups(["a"], 3) == [["a"], ["a"], ["a"]]
    with pytest.raises(DistillError, match="no_scenes"):
        scene_groups([], 2)


def test_a_teacher_that_cannot_act_is_a_named_error():
    import tests.training_envs  # noqa: F401  (registers tests/GoalSeek-v0, which has no A* path)
    with pytest.raises(TeacherError, match="teacher_unavailable"):
        TeacherLabels(gym.make("tests/GoalSeek-v0"))


def test_bad_distill_settings_are_refused():
    with pytest.raises(ValueError, match="steps_per_round"):
        DistillConfig(steps_per_round=0)
    with pytest.raises(ValueError, match="beta_decay"):
        DistillConfig(beta_decay=1.5)
    with pytest.raises(ValueError, match="frames"):
        StudentConfig(frames=7)
    with pytest.raises(ValueError, match="frame_stride"):
        StudentConfig(frames=3, frame_stride=3)
    with pytest.raises(ValueError, match="method"):
        TrainConfig(run_dir="x", total_steps=10, method="ppo")


@pytest.mark.slow
def test_collection_on_ray_actors(street_registry, tmp_path):
    path = os.pathsep.join([str(PROJECT_ROOT), os.environ.get("PYTHONPATH", "")])
    init_ray(num_cpus=2, runtime_env={"env_vars": {"PYTHONPATH": path}})
    try:
        result = train_distill(tiny_config(street_registry, tmp_path / "ray-run", 60, n_actors=2))
    finally:
        ray.shutdown()
    assert result.num_timesteps == 60 and result.history[0]["labels"] > 0


def test_resume_refuses_other_options_and_missing_runs(distilled, tmp_path):
    from typer.testing import CliRunner

    from vid2sim.cli.app import app
    run, _ = distilled
    before = (run / "config.json").read_text()
    result = CliRunner().invoke(app, ["train", "--registry", "x", "--run", str(run), "--resume", "--envs", "3",
                                      "--set", "seed=2"])
    assert result.exit_code == 2 and "error: --envs, --set: refused with --resume" in result.output
    assert (run / "config.json").read_text() == before
    missing = tmp_path / "no-run"
    result = CliRunner().invoke(app, ["train", "--registry", "x", "--run", str(missing), "--resume"])
    assert result.exit_code == 2 and "not a run folder" in result.output and not missing.exists()


def test_a_copied_run_resumes_in_its_new_folder(distilled, street_registry, tmp_path):
    import shutil

    from typer.testing import CliRunner

    from vid2sim.cli.app import app
    run, _ = distilled
    copy = tmp_path / "copy"
    shutil.copytree(run, copy)
    before = (run / "checkpoints" / "last.pt").read_bytes()
    result = CliRunner().invoke(app, ["train", "--registry", str(street_registry), "--run", str(copy), "--resume",
                                      "--steps", "180"])
    assert result.exit_code == 0, result.output
    assert torch.load(copy / "checkpoints" / "last.pt", weights_only=False)["num_timesteps"] == 180
    assert (run / "checkpoints" / "last.pt").read_bytes() == before  # the original is left alone
    assert json.loads((copy / "config.json").read_text())["run_dir"] == str(copy)


def test_dataset_gather_reads_rows_across_rounds_without_concatenating():
    def batch(n, value):
        return Batch(np.full((n, 1, 1, 2, 2), value, np.uint8), np.full((n, 6, 2), value, np.float32),
                     np.stack([np.full(n, value, np.float32), np.arange(n, dtype=np.float32)], 1))
    data = Dataset(max_samples=25)
    for k in range(4):
        data.add(batch(10, k))  # 30 rows kept (rounds 1-3), the newest 25 sampled
    assert len(data) == 30 and data.rows() == 25
    whole = np.concatenate([p.actions for p in data.parts])[-25:]
    idx = np.array([0, 24, 3, 3, 12, 5, 20])
    got = data.gather(idx)
    np.testing.assert_array_equal(got.actions, whole[idx])
    np.testing.assert_array_equal(got.frames[:, 0, 0, 0, 0], whole[idx, 0])
    np.testing.assert_array_equal(got.vectors[:, 0, 0], whole[idx, 0])
    assert got.actions[0].tolist() == [1.0, 5.0]  # the 6th row of round 1: its first 5 fall outside the cap
    empty = Dataset(max_samples=5)
    empty.add(batch(0, 0))  # a round whose labels were all dropped leaves an empty dataset, no error
    assert len(empty) == 0 and empty.rows() == 0
    with pytest.raises(DistillError, match="no_labels"):
        empty.gather(np.zeros(1, np.int64))


def test_training_envs_render_without_augmentation_unless_asked_and_old_runs_keep_theirs(tmp_path):
    config = tiny_config("reg", tmp_path / "run", 100)
    config.scene_ids = ["a", "b"]
    assert not config.distill.augment
    assert all(s.kwargs["augment"] == {"enabled": False} for s in env_specs(config))
    config.distill.augment = True
    assert env_specs(config)[0].kwargs["augment"] == {"enabled": True}
    config.env_kwargs["augment"] = {"enabled": False, "fog_prob": 0.5}  # given: kept as given
    assert env_specs(config)[0].kwargs["augment"] == {"enabled": False, "fog_prob": 0.5}
    config.env_kwargs.pop("augment")
    recorded = config.to_dict()
    recorded["distill"].pop("augment")  # a run folder written before the fields existed: augmented,
    recorded["distill"].pop("ema_decay")  # the last weights
    old = TrainConfig.from_dict(recorded).distill
    assert old.augment and old.ema_decay == 0.0 and config.distill.ema_decay == 0.999
    config.distill.augment = False
    assert not TrainConfig.from_dict(config.to_dict()).distill.augment


def test_the_teachers_route_keeps_its_comfort_distance_unless_the_env_arguments_say_otherwise(tmp_path):
    config = tiny_config("reg", tmp_path / "run", 100)
    config.scene_ids = ["a", "b"]
    assert config.distill.teacher_comfort == 0.8
    assert all(s.kwargs["episode"] == {"expert_comfort": 0.8} for s in env_specs(config))
    config.env_kwargs["episode"] = {"expert_comfort": 0.5, "clearance": 0.5}  # given: kept as given
    assert env_specs(config)[0].kwargs["episode"] == {"expert_comfort": 0.5, "clearance": 0.5}
    config.env_kwargs.pop("episode")
    recorded = config.to_dict()
    recorded["distill"].pop("teacher_comfort")  # a run folder written before the fields existed
    recorded["distill"].pop("weight_decay")
    old = TrainConfig.from_dict(recorded).distill
    assert old.teacher_comfort == 0.0 and old.weight_decay == 0.0  # resumes with its own teacher and Adam
    assert config.distill.weight_decay == 0.5
    assert TrainConfig.from_dict(config.to_dict()).distill.teacher_comfort == 0.8
    config.distill.teacher_comfort = 0.0  # the shortest route: the env's default, nothing passed
    assert "episode" not in env_specs(config)[0].kwargs


def test_weight_decay_comes_from_the_config_also_over_an_old_adam_state():
    student = StudentPolicy(TINY, (6, 3, 72, 128), (6, 2))
    old = torch.optim.Adam(student.parameters(), lr=3e-4)  # what runs saved before the setting existed
    student.act(torch.zeros(1, 2, 3, 36, 64), torch.zeros(1, 6, 2)).sum().backward()
    old.step()
    optimizer = make_optimizer(student, DistillConfig(weight_decay=0.5, learning_rate=1e-2), old.state_dict())
    assert all(g["weight_decay"] == 0.5 and g["decoupled_weight_decay"] for g in optimizer.param_groups)
    assert len(optimizer.state) == len(old.state)  # the moments are kept
    weight = student.head[-1].weight
    before = weight.detach().clone()
    optimizer.zero_grad(set_to_none=False)  # zero gradients: only the decay moves the weights
    for group in optimizer.param_groups:
        for p in group["params"]:
            optimizer.state[p]["exp_avg"].zero_()
    optimizer.step()
    assert torch.allclose(weight.detach(), before * (1 - 1e-2 * 0.5), atol=1e-7)


def check_shard_clearance(shard: Batch) -> None:
    assert shard.clearance.shape == (len(shard.actions), 5) and shard.clearance.dtype == np.float32
    assert 0.0 < shard.clearance.min() and shard.clearance.max() <= 1.0


def check_shard_depth(shard: Batch) -> None:
    assert shard.depth.shape == (len(shard.actions), *DEPTH_GRID) and shard.depth.dtype == np.uint8
    assert shard.depth.min() < 200 and (shard.depth < 255).mean() > 0.3  # the street is in view, near enough


def check_shard_waypoints(shard: Batch) -> None:
    route = shard.waypoints  # [N, 4, 2]
    assert route.shape == (len(shard.actions), 4, 2) and route.dtype == np.float32
    steps = np.hypot(*np.diff(route, axis=1).transpose(2, 0, 1))  # [N, 3] chords of 0.5 m arcs
    assert steps.max() <= 0.5 + 1e-4 and np.median(steps) > 0.45
    assert np.median(route[:, -1, 0]) > 1.0  # the route runs ahead of the robot


@pytest.mark.parametrize("target, student_field, weight, check_shard, falls_to", [
    ("clearance", {"clearance_rays": 5}, "clearance_weight", check_shard_clearance, 0.5),
    ("waypoint", {"waypoints": 4, "drive_waypoints": True}, "waypoint_weight", check_shard_waypoints, 0.5),
    ("depth", {"depth_target": True}, "depth_weight", check_shard_depth, 0.7),  # measured: about 0.06 -> 0.03
])
def test_an_auxiliary_target_is_collected_learnt_and_left_out_of_the_export(
        street_registry, tmp_path, target, student_field, weight, check_shard, falls_to):
    config = tiny_config(street_registry, tmp_path / "run", 60)
    config.distill.student = StudentConfig(**{**TINY.to_dict(), **student_field})
    if student_field.get("drive_waypoints"):  # its pure pursuit steers the env's robot, not the default one
        config.env_kwargs["robot"] = {"wheelbase": 0.7, "max_steer_deg": 35.0}
    result = train_distill(config)
    shard = Batch.load(tmp_path / "run" / "data" / "round_000.npz")
    check_shard(shard)
    assert f"{target}_loss" in result.history[0]
    student = load_student(tmp_path / "run" / STUDENT_NAME)
    if student_field.get("drive_waypoints"):
        assert (student.config.wheelbase, student.config.max_steer_deg) == (0.7, 35.0)
    optimizer = make_optimizer(student, DistillConfig(learning_rate=3e-3))
    rng = np.random.default_rng(0)
    before = fit(student, optimizer, shard, fit_conf(1, 32, **{weight: 1.0}), rng)[f"{target}_loss"]
    after = fit(student, optimizer, shard, fit_conf(150, 32, **{weight: 1.0}), rng)[f"{target}_loss"]
    assert after < falls_to * before  # the head learns the target
    with pytest.raises(DistillError, match=f"{target}_mismatch"):  # rounds collected without the target
        fit(student, optimizer, Batch(shard.frames[:4], shard.vectors[:4], shard.actions[:4]),
            fit_conf(1, 4, **{weight: 1.0}), rng)
    out = export_policy(tmp_path / "run", tmp_path / "export")  # the graph is the action head alone
    image = np.random.default_rng(1).integers(0, 256, (2, 6, 3, 72, 128), dtype=np.uint8)
    vector = np.zeros((2, 6, 2), np.float32)
    with torch.no_grad():
        trained = load_student(tmp_path / "run" / STUDENT_NAME)
        expected = trained(torch.from_numpy(image), torch.from_numpy(vector)).numpy()
    np.testing.assert_allclose(NavPolicy(out, "onnx").act_stacked(image, vector), expected, atol=1e-5)


def test_route_waypoints_are_points_along_the_route_in_the_robots_frame():
    path = np.stack([np.linspace(0.0, 4.0, 41), np.full(41, 2.0)], axis=1)  # [41, 2] along +x at y = 2
    points = route_waypoints(path, 10, (1.0, 1.5, math.pi / 2), 3)  # robot at (1, 1.5) facing +y
    # along the route from x = 1: (1.5, 2), (2, 2), (2.5, 2); forward is +y, left is -x
    np.testing.assert_allclose(points, [[0.5, -0.5], [0.5, -1.0], [0.5, -1.5]], atol=1e-6)
    tail = route_waypoints(path, 38, (3.8, 2.0, 0.0), 3)  # past the end: the end repeats
    np.testing.assert_allclose(tail, [[0.2, 0.0], [0.2, 0.0], [0.2, 0.0]], atol=1e-6)


def test_pursuit_on_a_route_is_the_teachers_steering():
    """The student's pure pursuit of the route point 1 m along it steers as the teacher's formula
    atan(2 L sin(alpha) / l_d) does for that point, over the steering limit, clipped to [-1, 1]."""
    from vid2sim.formats.robot import ROBOT
    route = torch.tensor([[[0.5, 0.05], [0.95, 0.3], [1.4, 0.6]],
                          [[0.5, -0.1], [1.0, -0.05], [1.5, 0.0]],
                          [[0.3, 0.4], [0.2, 0.98], [0.0, 1.5]]])  # [3, 3, 2]
    steering = pursuit_steering(route, 1.0)
    for b in range(3):
        x, y = route[b, 1].tolist()
        alpha, ld = math.atan2(y, x), math.hypot(x, y)
        want = math.atan2(2 * ROBOT.wheelbase_m * math.sin(alpha), ld) / math.radians(ROBOT.max_steer_deg)
        assert steering[b].item() == pytest.approx(max(-1.0, min(1.0, want)), abs=1e-5)
    assert steering[2].item() == 1.0  # a point to the left beyond the steering limit: full lock
    torch.testing.assert_close(pursuit_steering(route, 0.75),
                               pursuit_steering(0.5 * (route[:, :1] + route[:, 1:2]), 0.5))
    x, y = route[1, 1].tolist()  # another robot: its wheelbase and steering limit
    want = math.atan2(2 * 0.6 * math.sin(math.atan2(y, x)), math.hypot(x, y)) / math.radians(40.0)
    assert pursuit_steering(route, 1.0, 0.6, 40.0)[1].item() == pytest.approx(want, abs=1e-5)
    with pytest.raises(ValueError, match="waypoints"):
        StudentConfig(drive_waypoints=True)
    with pytest.raises(ValueError, match="lookahead"):
        StudentConfig(waypoints=2, drive_waypoints=True, lookahead=1.5)


def test_depth_blocks_keep_each_blocks_nearest_depth():
    depth = np.full((72, 128), np.inf, np.float32)  # nothing in view: saturated
    depth[40:44, 8:10] = 1.0  # inside block (5, 1)
    depth[41, 9] = 0.5  # nearer, same block
    depth[0, 0] = 10.0  # beyond the range: saturated
    depth[70, 127] = np.nan  # a bad pixel counts as nothing
    blocks = depth_blocks(depth, DEPTH_GRID)
    assert blocks.shape == DEPTH_GRID and blocks.dtype == np.uint8
    assert blocks[5, 1] == round(0.5 / 5.0 * 255) and blocks[0, 0] == 255 and blocks[8, 15] == 255
    assert (np.delete(blocks.ravel(), 5 * 16 + 1) == 255).all()
    with pytest.raises(ValueError, match="equal blocks"):
        check_depth_grid((7, 16), (72, 128))


def test_ema_decay_warms_up_then_holds():
    assert ema_decay_at(0.999, 0) == pytest.approx(0.1)  # the first update nearly copies the student
    assert ema_decay_at(0.999, 400) == pytest.approx(401 / 410)
    assert ema_decay_at(0.999, 100_000) == 0.999


def test_the_weight_average_is_the_final_student_and_resumes(street_registry, tmp_path):
    config = tiny_config(street_registry, tmp_path / "run", 120)
    config.distill.ema_decay = 0.9
    train_distill(config)
    ckpt = torch.load(tmp_path / "run" / "checkpoints" / "last.pt", map_location="cpu", weights_only=False)
    final = torch.load(tmp_path / "run" / STUDENT_NAME, map_location="cpu", weights_only=False)["state_dict"]
    live = ckpt["student"]["state_dict"]
    averaged = {k[len("module."):]: v for k, v in ckpt["averaged"].items() if k.startswith("module.")}
    assert int(ckpt["averaged"]["n_averaged"]) == 2 * config.distill.updates_per_round
    assert all(torch.equal(final[k], averaged[k]) for k in final)  # student.pt is the average ...
    assert any(not torch.equal(final[k], live[k]) for k in final)  # ... not the last weights
    config.total_steps = 180
    resumed = train_distill(config, resume=True)
    ckpt = torch.load(tmp_path / "run" / "checkpoints" / "last.pt", map_location="cpu", weights_only=False)
    assert resumed.num_timesteps == 180 and int(ckpt["averaged"]["n_averaged"]) == 3 * config.distill.updates_per_round


def test_steer_weight_counts_hard_turns_more():
    labels = torch.tensor([[0.5, 0.0], [0.5, -1.0]])
    predicted = torch.tensor([[0.5, 0.2], [0.5, -0.6]])  # squared errors per sample: 0.02, 0.08
    assert action_loss(predicted, labels).item() == pytest.approx(0.05)
    assert action_loss(predicted, labels, steer_weight=3.0).item() == pytest.approx((0.02 + 4 * 0.08) / 5)
    with pytest.raises(ValueError, match="steer_weight"):
        DistillConfig(steer_weight=-1.0)


def test_two_hot_targets_keep_the_label_and_the_decoder_keeps_one_mode():
    from vid2sim.training.student import steer_from_logits, two_hot

    labels = torch.tensor([-1.0, -0.37, 0.0, 0.55, 1.0])
    target = two_hot(labels, 11)
    values = torch.linspace(-1, 1, 11)
    torch.testing.assert_close(target.sum(1), torch.ones(5))
    torch.testing.assert_close((target * values).sum(1), labels)
    assert ((target > 0).sum(1) <= 2).all()
    bimodal = torch.full((1, 11), -10.0)
    bimodal[0, 0], bimodal[0, 10] = 2.0, 1.5  # hard left more likely than hard right: not their average
    assert steer_from_logits(bimodal, values).item() == pytest.approx(-1.0, abs=1e-3)
    peaked = torch.log(two_hot(torch.tensor([0.33]), 11) + 1e-9)
    assert steer_from_logits(peaked, values).item() == pytest.approx(0.33, abs=1e-3)


def test_steering_bins_learn_a_turn_that_regression_averages_away(tmp_path):
    """The same observation labelled hard right 60 % and hard left 40 % of the time: a regressed
    steering learns their mean (~0.2), the bins learn the more likely turn; the export keeps it."""
    rng = np.random.default_rng(0)
    n = 256
    frames = np.repeat(rng.integers(0, 256, (1, 2, 3, 36, 64), dtype=np.uint8), n, axis=0)
    steering = np.where(rng.random(n) < 0.6, 0.9, -0.9).astype(np.float32)
    data = Batch(frames, np.zeros((n, 6, 2), np.float32), np.stack([np.full(n, 0.5, np.float32), steering], 1))
    learnt = {}
    for bins in (0, 21):
        torch.manual_seed(0)
        student = StudentPolicy(StudentConfig(**{**TINY.to_dict(), "steer_bins": bins}), (6, 3, 72, 128), (6, 2))
        optimizer = make_optimizer(student, DistillConfig(learning_rate=3e-3, weight_decay=0.0))
        fit(student, optimizer, data, fit_conf(200, 64), np.random.default_rng(1))
        with torch.no_grad():
            learnt[bins] = student.act(torch.from_numpy(frames[:1]).float(), torch.zeros(1, 6, 2))[0].numpy()
    assert abs(learnt[0][1] - 0.18) < 0.15  # the average of the two turns
    assert learnt[21][1] > 0.75 and abs(learnt[21][0] - 0.5) < 0.1  # the likelier turn, the speed regressed
    student.save(tmp_path / STUDENT_NAME)
    out = export_policy(tmp_path, tmp_path / "export")
    image = rng.integers(0, 256, (3, 6, 3, 72, 128), dtype=np.uint8)
    vector = rng.normal(size=(3, 6, 2)).astype(np.float32)
    with torch.no_grad():
        expected = load_student(tmp_path / STUDENT_NAME)(torch.from_numpy(image), torch.from_numpy(vector)).numpy()
    for backend in ("onnx", "torch"):
        np.testing.assert_allclose(NavPolicy(out, backend).act_stacked(image, vector), expected, atol=1e-5)
    with pytest.raises(ValueError, match="steer_bins"):
        StudentConfig(steer_bins=2)


def test_a_mirrored_state_flips_its_views_and_negates_its_steering_and_heading():
    rng = np.random.default_rng(0)
    n = 4
    data = Batch(rng.integers(0, 256, (n, 2, 3, 36, 64), dtype=np.uint8), rng.normal(size=(n, 6, 2)).astype(np.float32),
                 rng.uniform(-1, 1, (n, 2)).astype(np.float32), rng.uniform(0, 1, (n, 9)).astype(np.float32),
                 rng.integers(0, 256, (n, *DEPTH_GRID), dtype=np.uint8), None,
                 rng.normal(size=(n, 4, 2)).astype(np.float32))
    rows = np.array([True, False, True, False])
    seen = data.mirrored(rows)
    np.testing.assert_array_equal(seen.frames[0, :, :, :, 0], data.frames[0, :, :, :, -1])  # left edge <- right edge
    np.testing.assert_array_equal(seen.frames[1], data.frames[1])  # rows not drawn are untouched
    np.testing.assert_array_equal(seen.vectors[rows, :, 0], data.vectors[rows, :, 0])  # distance kept
    np.testing.assert_array_equal(seen.vectors[rows, :, 1], -data.vectors[rows, :, 1])  # heading negated
    np.testing.assert_array_equal(seen.actions[rows], data.actions[rows] * np.float32([1, -1]))  # speed kept
    np.testing.assert_array_equal(seen.clearance[2], data.clearance[2, ::-1])
    np.testing.assert_array_equal(seen.depth[2], data.depth[2, :, ::-1])
    np.testing.assert_array_equal(seen.waypoints[2], data.waypoints[2] * np.float32([1, -1]))  # route: y negated
    twice = seen.mirrored(rows)
    for field in ("frames", "vectors", "actions", "clearance", "depth", "waypoints"):
        np.testing.assert_array_equal(getattr(twice, field), getattr(data, field))  # and the original is a copy
    in_place = data.take(np.arange(n))  # a copy, mirrored where it lies
    assert in_place.mirror_rows(rows) is in_place
    for field in ("frames", "vectors", "actions", "clearance", "depth", "waypoints"):
        np.testing.assert_array_equal(getattr(in_place, field), getattr(seen, field))
    with pytest.raises(ValueError, match="mirror"):
        DistillConfig(mirror=1.5)


def test_mirrored_samples_teach_the_mirrored_turn():
    """Every label says "the bright side is on the left: turn left"; with mirrored samples the
    student also learns to turn right when the bright side is on the right."""
    n = 64
    left = np.zeros((n, 2, 3, 36, 64), np.uint8)
    left[..., :32] = 255
    data = Batch(left, np.zeros((n, 6, 2), np.float32), np.tile(np.float32([[0.5, 0.8]]), (n, 1)))
    torch.manual_seed(0)
    student = StudentPolicy(TINY, (6, 3, 72, 128), (6, 2))
    optimizer = make_optimizer(student, DistillConfig(learning_rate=3e-3, weight_decay=0.0))
    fit(student, optimizer, data, DistillConfig(updates_per_round=200, batch_size=32, shift_pad=0, mirror=0.5),
        np.random.default_rng(1))
    with torch.no_grad():
        views = torch.from_numpy(np.stack([left[0], left[0, ..., ::-1]])).float()
        steering = student.act(views, torch.zeros(2, 6, 2))[:, 1].numpy()
    assert steering[0] > 0.5 and steering[1] < -0.5


class InfoLog(VecEnvWrapper):
    """Passes a VecEnv through and keeps each step's `collided` flags and dones [n_envs]."""

    def __init__(self, venv):
        super().__init__(venv)
        self.collided, self.dones = [], []

    def reset(self):
        return self.venv.reset()

    @property
    def reset_infos(self):  # the wrapped env's (the teacher's labels of each new episode)
        return self.venv.reset_infos

    @reset_infos.setter
    def reset_infos(self, value):  # VecEnv.__init__ sets its own; the wrapped env's are read
        pass

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        self.collided.append(np.array([bool(i.get("collided", False)) for i in infos]))
        self.dones.append(dones.copy())
        return obs, rewards, dones, infos


def expected_hard_flags(collided: list, dones: list, hard_steps: int) -> np.ndarray:
    """[T, n_envs] the states of the `hard_steps` steps (of the same episode) before each contact's onset."""
    c, d = np.array(collided), np.array(dones)
    flags, start, before = np.zeros_like(c), np.zeros(c.shape[1], int), np.zeros(c.shape[1], bool)
    for t in range(len(c)):
        for i in range(c.shape[1]):
            if c[t, i] and not before[i]:
                flags[max(start[i], t + 1 - hard_steps):t + 1, i] = True
            before[i] = c[t, i] and not d[t, i]
            if d[t, i]:
                start[i] = t + 1
    return flags


def test_collection_flags_the_states_before_each_contact(street_registry, tmp_path):
    from vid2sim.training.distill import Collector
    from vid2sim.training.sac import make_vec_env
    config = tiny_config(street_registry, tmp_path / "run", 200)
    from vid2sim.training.sac import resolve_scenes
    config.scene_ids = resolve_scenes(config)
    env = InfoLog(make_vec_env(env_specs(config), 0))
    torch.manual_seed(0)
    student = StudentPolicy(TINY, (6, 3, 72, 128), (6, 2)).eval()
    with torch.no_grad():  # drives straight on at full speed whatever it sees, so it runs into things
        student.head[-1].weight.zero_()
        student.head[-1].bias.copy_(torch.tensor([5.0, 0.0]))
    try:
        batch, stats = Collector(env, student, 0).collect(400, beta_k=0.0, drop_stuck=False, hard_steps=4)
    finally:
        env.close()
    flags = expected_hard_flags(env.collided, env.dones, 4)  # [200, 2]
    assert flags.any() and not flags.all()  # the straight drives touched something, not from the start
    np.testing.assert_array_equal(batch.hard, flags.reshape(-1))  # rows are step-major, envs within a step
    assert stats.hard == int(flags.sum())


def test_a_hard_fraction_of_each_batch_comes_from_the_flagged_states():
    n = 200
    frames = np.zeros((n, 2, 3, 4, 4), np.uint8)  # what the student below reads (8 x 8 frames pooled by 2)
    hard = np.zeros(n, bool)
    hard[[5, 77, 150]] = True
    data = Dataset(max_samples=n)
    data.add(Batch(frames, np.zeros((n, 6, 2), np.float32), np.zeros((n, 2), np.float32), hard=hard))
    np.testing.assert_array_equal(data.hard_rows(), [5, 77, 150])
    seen = []

    class Recording(Dataset):
        def gather(self, idx):
            seen.append(np.asarray(idx))
            return super().gather(idx)
    rec = Recording(max_samples=n)
    rec.parts, rec.seen = data.parts, data.seen
    student = StudentPolicy(TINY, (6, 3, 8, 8), (6, 2))
    optimizer = make_optimizer(student, DistillConfig())
    fit(student, optimizer, rec, fit_conf(20, 16, hard_fraction=0.25), np.random.default_rng(0))
    drawn = np.concatenate([s[-4:] for s in seen])  # the last quarter of each batch: the flagged states
    assert set(drawn.tolist()) <= {5, 77, 150} and len(set(drawn.tolist())) == 3
    seen.clear()
    fit(student, optimizer, rec, fit_conf(20, 16), np.random.default_rng(0))  # 0: uniform batches
    assert np.isin(np.concatenate(seen), [5, 77, 150]).mean() < 0.1
    old = Batch(frames, np.zeros((n, 6, 2), np.float32), np.zeros((n, 2), np.float32))
    assert not old.hard.any()  # shards written before the flags read as none flagged


def test_scene_weights_steer_the_resets_draw_and_bad_weights_are_named(street_registry, tmp_path):
    from vid2sim.envs.nav_env import NavEnv
    env = NavEnv(street_registry, _two_scenes(street_registry), fidelity="exact", checkout_root=tmp_path)
    try:
        a, b = env.scene_ids
        env.set_scene_weights([0.0, 1.0])
        assert {env.reset(seed=s)[1]["scene_id"] for s in range(6)} == {b}
        assert env.reset(seed=0, options={"scene_id": a})[1]["scene_id"] == a  # options still win
        env.set_scene_weights(None)
        assert {env.reset(seed=s)[1]["scene_id"] for s in range(12)} == {a, b}
        for bad in ([1.0], [-1.0, 2.0], [0.0, 0.0], [np.nan, 1.0]):
            with pytest.raises(ValueError, match="scene weights"):
                env.set_scene_weights(bad)
    finally:
        env.close()


def _two_scenes(registry) -> list[str]:
    from vid2sim.registry import Registry
    return sorted(r.scene_id for r in Registry(registry).list())[:2]


def test_prioritised_scenes_are_sent_counted_and_resumed(street_registry, tmp_path):
    config = tiny_config(street_registry, tmp_path / "run", 180)
    config.n_envs, config.scene_ids = 1, _two_scenes(street_registry)  # one env holds both scenes
    config.distill.scene_priority = 0.5
    result = train_distill(config)
    ckpt = torch.load(tmp_path / "run" / "checkpoints" / "last.pt", map_location="cpu", weights_only=False)
    state = ckpt["scene_priority"]
    assert state["scene_ids"] == config.scene_ids and sum(state["episodes"]) > 0  # the student's episodes counted
    assert all(0.5 <= row["scene_weight_max"] <= 0.75 for row in result.history)  # half uniform over 2 scenes
    config.total_steps = 240
    train_distill(config, resume=True)
    resumed = torch.load(tmp_path / "run" / "checkpoints" / "last.pt", map_location="cpu", weights_only=False)
    assert sum(resumed["scene_priority"]["episodes"]) >= 0.9 * sum(state["episodes"])  # carried over, faded once
