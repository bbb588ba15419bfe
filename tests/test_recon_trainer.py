"""Reconstruction stage end to end on the tiny ray-cast toy clip (cpu/torch splat backend)."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from vid2sim.factory.sfm.posed import PosedClip
from vid2sim.factory.recon import config as C
from vid2sim.factory.recon.data import load_views
from vid2sim.factory.recon.evaluate import _lpips_fn
from recon_toy import make_toy_clip
from vid2sim.factory.recon.trainer import train, work
from vid2sim.factory.runtime.runner import run_stage
from vid2sim.factory.runtime.stage_cache import StageError
from vid2sim.splats.ply import read_ply


def tiny_conf(**kw) -> C.ReconConfig:
    conf = C.preset("fast", iterations=40, max_width=40, checkpoint_every=20, max_init_points=600, **kw)
    conf.densify = dataclasses.replace(conf.densify, start_iter=10, stop_iter=35, every=10,
                                       opacity_reset_every=1000, max_gaussians=2000)
    conf.loss = dataclasses.replace(conf.loss, geometry_from_iter=5)
    conf.prior = dataclasses.replace(conf.prior, num_planes=32)
    return conf


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    return make_toy_clip(tmp_path_factory.mktemp("toy"), n_frames=17, width=48, height=36, n_points=1500)


def test_presets_and_config_round_trip(tmp_path):
    fast, paper = C.preset("fast"), C.preset("paper")
    assert paper.iterations == 30_000 and paper.loss.geometry_from_iter == 500
    assert paper.loss.lambda_dssim == 0.2 and paper.densify.absgrad_threshold > paper.densify.grad_threshold
    assert fast.iterations <= 3000 and fast.max_width <= 320 and fast.densify.max_gaussians <= 200_000
    base = C.baseline(fast)
    assert base.prior.kind == "none" and not base.loss.geometry and base.iterations == fast.iterations
    path = fast.save(tmp_path / "c.json")
    assert C.ReconConfig.load(path) == fast
    with pytest.raises(ValueError, match="unknown reconstruction preset"):
        C.preset("huge")


def test_stage_writes_outputs_evaluates_and_skips_rerun(toy, tmp_path):
    conf = tiny_conf()
    out = run_stage(work(conf, toy), tmp_path / "run")
    for name in ("splats.ply", "metrics.json", "config.json", "stage.json", "prior.npz"):
        assert (out / name).is_file(), name
    assert not (out / "checkpoint.pt").exists()
    m = json.loads((out / "metrics.json").read_text())
    assert m["n_test_frames"] == 3 and 10.0 < m["psnr"] < 60.0 and 0.0 < m["ssim"] <= 1.0
    lpips_fn, _ = _lpips_fn()  # LPIPS runs only when its weights are local
    assert (m["lpips"] is None) if lpips_fn is None else (0.0 < m["lpips"] < 1.0)
    # random normals average 90 deg (sign-sensitive); 40 iterations on the toy reach ~45 deg
    assert 0.0 < m["depth_median_abs_rel"] < 0.5 and 0.0 < m["normal_err_deg"] < 70.0
    assert read_ply(out / "splats.ply").num == m["n_gaussians"] > 0
    assert C.ReconConfig.load(out / "config.json") == conf
    log = json.loads((out / "train_log.json").read_text())["log"]
    assert any(e.get("split", 0) + e.get("cloned", 0) > 0 for e in log)  # densification ran
    mtime = (out / "metrics.json").stat().st_mtime_ns
    run_stage(work(conf, toy), tmp_path / "run")  # finished: skipped
    assert (out / "metrics.json").stat().st_mtime_ns == mtime


def test_training_lowers_the_photometric_loss_and_resumes(toy, tmp_path):
    clip = PosedClip.load(toy)
    conf = tiny_conf()
    conf = dataclasses.replace(conf, iterations=30, checkpoint_every=15)
    views = load_views(clip, conf.max_width)
    (tmp_path / "r").mkdir()
    _, s1 = train(conf, clip, views, {}, tmp_path / "r", key="k", log_every=5)
    rgb = [e["rgb"] for e in s1["log"] if "rgb" in e]
    assert np.mean(rgb[-2:]) < 0.8 * rgb[0]
    assert (tmp_path / "r" / "checkpoint.pt").is_file()
    _, s2 = train(conf, clip, views, {}, tmp_path / "r", key="k", log_every=5)
    assert s2["resumed_from"] == 15
    _, s3 = train(conf, clip, views, {}, tmp_path / "r", key="other", log_every=5)
    assert s3["resumed_from"] == 0  # a checkpoint of another config is not reused


def test_bad_inputs_are_named(toy, tmp_path):
    with pytest.raises(StageError, match="bad_posed_clip"):
        run_stage(work(tiny_conf(), tmp_path / "nowhere"), tmp_path / "out")
    clip = PosedClip.load(toy)
    clip.points_xyz, clip.points_rgb = np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    bad = clip.save(tmp_path / "nopoints")
    with pytest.raises(StageError, match="no_sparse_points"):
        run_stage(work(tiny_conf(), bad), tmp_path / "out2")
    assert not (tmp_path / "out2" / "stage.json").exists()


def test_cli_recon_run(toy, tmp_path):
    from typer.testing import CliRunner

    from vid2sim.cli.app import app

    res = CliRunner().invoke(app, ["recon", "run", str(toy), str(tmp_path / "cli"), "--baseline",
                                   "--iterations", "8", "--json"])
    assert res.exit_code == 0, res.output
    m = json.loads(res.output[res.output.index("{"):])
    assert m["prior"] == "none" and m["geometry"] is False and m["iterations"] == 8
    assert math.isfinite(m["psnr"])
