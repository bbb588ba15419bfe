"""`vid2sim config show` and `--set`: every config field listed with its default, unit and
meaning; typed overrides on `ingest` and `eval policy`; bad overrides are one-line errors with
exit code 2 (typer CliRunner in-process, and the installed entry point for the banner)."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import typing
from pathlib import Path

import pytest
from typer.testing import CliRunner

from vid2sim.cli.app import app
from vid2sim.cli.settings import SettingError, apply_eval_overrides, apply_overrides, ingest_config
from vid2sim.envs.config import EnvConfig
from vid2sim.factory.runtime.pipeline import PipelineConfig
from vid2sim.training.config import TrainConfig
from vid2sim.training.evaluate import EvalConfig

runner = CliRunner()
ROOTS = {"ingest": PipelineConfig, "env": EnvConfig, "train": TrainConfig, "eval": EvalConfig}


def field_paths(cls: type, prefix: str = "") -> list[str]:
    """Dotted paths of every field, through nested (and Optional nested) dataclasses."""
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        out.append(prefix + f.name)
        inner = [a for a in typing.get_args(hints[f.name]) if a is not type(None)] or [hints[f.name]]
        if len(inner) == 1 and dataclasses.is_dataclass(inner[0]):
            out += field_paths(inner[0], f"{prefix}{f.name}.")
    return out


def show(*args: str) -> dict:
    r = runner.invoke(app, ["config", "show", *args, "--json"])
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout)


def rows(data: dict) -> dict[str, dict]:
    return {row["path"]: row for row in data["fields"]}


@pytest.mark.parametrize("section", list(ROOTS))
def test_show_lists_every_field(section):
    got = [row["path"] for row in show(section)["fields"]]
    want = field_paths(ROOTS[section])
    if section == "eval":  # then the env config it evaluates with, under env.
        want += ["env"] + field_paths(EnvConfig, "env.")
    assert got == want


def test_show_all_sections_in_text_and_json():
    data = show()
    assert set(data) == set(ROOTS)
    r = runner.invoke(app, ["config", "show"])
    assert r.exit_code == 0, r.output
    lines = r.stdout.splitlines()
    for section, cls in ROOTS.items():
        assert any(line.startswith(f"# {section}:") for line in lines)
    listed = {line.strip().split(":", 1)[0] for line in lines if line.strip() and not line.startswith("#")}
    assert set(field_paths(PipelineConfig)) | set(field_paths(EnvConfig)) <= listed


@pytest.mark.parametrize("section", ["ingest", "env"])
def test_every_field_has_a_meaning(section):
    missing = [row["path"] for row in show(section)["fields"] if not row["meaning"].strip()]
    assert missing == [], f"fields without a comment: {missing}"


def test_defaults_units_and_presets():
    fast, paper = rows(show("ingest")), rows(show("ingest", "--preset", "paper"))
    conf = ingest_config("paper")
    assert paper["recon.iterations"]["default"] == conf.recon.iterations != fast["recon.iterations"]["default"]
    assert paper["decode.fps"]["default"] == conf.decode.fps == 30.0
    assert fast["meshing.voxel_m"]["unit"] == "m" and fast["walkable.floater_max_area_m2"]["unit"] == "m^2"
    env = rows(show("env"))
    assert env["camera.jitter_freq"] == {**env["camera.jitter_freq"], "default": [2.0, 10.0], "unit": "Hz",
                                         "type": "tuple[float, float]"}
    assert env["robot"]["section"] and env["augment"]["default"] is None  # Optional section, unset
    train = rows(show("train"))
    assert train["run_dir"]["required"] and train["sac.batch_size"]["default"] == 256


def test_show_with_set_changes_the_value():
    data = rows(show("ingest", "--set", "recon.iterations=7", "--set", "walkable.kerb=null",
                     "--set", "recon.prior.near_far_percentiles=1,99"))
    assert data["recon.iterations"]["default"] == 7
    assert data["walkable.kerb"]["default"] is None
    assert data["recon.prior.near_far_percentiles"]["default"] == [1.0, 99.0]
    env = rows(show("eval", "--set", "trials=3", "--set", "env.camera.width=64"))
    assert env["trials"]["default"] == 3 and env["env.camera.width"]["default"] == 64


def test_apply_overrides_types_and_copies():
    conf = ingest_config("fast")
    new = apply_overrides(conf, ["decode.fps=5", "sfm.refine_intrinsics=none", "masks.segmenter_classes=[1, 3]",
                                 "views.cov_cull_alpha=null", "meshing.carve.body=false", "recon.background=1,1,1",
                                 "sfm.camera_params=[500, 500, 320, 240]", "decode.faces.detector=none",
                                 'meshing.carve={"rays": true}'])
    assert new.decode.fps == 5.0 and new.sfm.refine_intrinsics is None
    assert new.masks.segmenter_classes == (1, 3) and new.views.cov_cull_alpha is None
    assert new.meshing.carve.body is False and new.meshing.carve.rays is True  # the JSON object goes over it
    assert new.recon.background == (1.0, 1.0, 1.0) and new.sfm.camera_params == [500.0, 500.0, 320.0, 240.0]
    assert new.decode.faces.detector == "none"  # a plain str field keeps the word
    assert conf == ingest_config("fast")  # the input is not modified
    train = apply_overrides(TrainConfig(run_dir="r", total_steps=10),
                            ["sac.net_arch=64,64", "env_kwargs.variant=depth", "train_scenes=3", "sac.use_sde=no"])
    assert train.sac.net_arch == (64, 64) and train.env_kwargs == {"variant": "depth"}
    assert train.train_scenes == 3 and train.sac.use_sde is False


@pytest.mark.parametrize("item,names", [
    ("recon.iteratons=5", ["recon.iteratons", "unknown field", "iterations"]),
    ("recon.iterations=abc", ["recon.iterations", "expected int", "'abc'"]),
    ("decode.max_side=1.5", ["decode.max_side", "expected int"]),
    ("sfm.quadratic_overlap=maybe", ["sfm.quadratic_overlap", "expected bool"]),
    ("recon.prior.near_far_percentiles=1,2,3", ["recon.prior.near_far_percentiles", "expected 2 values"]),
    ("recon=5", ["recon", "section"]),
    ("recon.iterations", ["FIELD=VALUE"]),
    ("recon.iterations.x=1", ["recon.iterations", "not a section"]),
    ("decode.fps=none", ["decode.fps", "cannot be None"]),
])
def test_bad_override_is_a_one_line_error(item, names):
    with pytest.raises(SettingError) as e:
        apply_overrides(ingest_config("fast"), [item])
    assert "\n" not in str(e.value) and all(n in str(e.value) for n in names), str(e.value)


def _one_line_exit_2(result, *names: str) -> None:
    assert result.exit_code == 2, result.output
    err = result.stderr.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error: "), err
    assert all(n in err for n in names), err
    assert "Traceback" not in result.output


def test_ingest_rejects_bad_overrides_before_any_work(tmp_path):
    base = ["ingest", str(tmp_path / "missing.mp4"), "--registry", str(tmp_path / "reg"),
            "--workdir", str(tmp_path / "work")]
    _one_line_exit_2(runner.invoke(app, base + ["--set", "recon.iteratons=5"]), "recon.iteratons", "unknown field")
    _one_line_exit_2(runner.invoke(app, base + ["--set", "decode.fps=fast"]), "decode.fps", "expected float")
    assert not (tmp_path / "work").exists() and not (tmp_path / "reg").exists()


def test_eval_policy_rejects_bad_overrides(tmp_path):
    base = ["eval", "policy", "--policy", "random", "--registry", str(tmp_path / "reg")]
    _one_line_exit_2(runner.invoke(app, base + ["--set", "trails=3"]), "trails", "unknown field", "trials")
    _one_line_exit_2(runner.invoke(app, base + ["--set", "env.camera.width=wide"]), "env.camera.width", "expected int")
    _one_line_exit_2(runner.invoke(app, base + ["--set", "env.variant=thermal"]), "env.variant", "unknown variant")
    _one_line_exit_2(runner.invoke(app, base + ["--set", "obstacles=many"]), "obstacles")


def test_config_show_rejects_bad_arguments():
    _one_line_exit_2(runner.invoke(app, ["config", "show", "ingest", "--set", "recon.x=1"]), "recon.x")
    _one_line_exit_2(runner.invoke(app, ["config", "show", "nosuch"]), "nosuch")
    _one_line_exit_2(runner.invoke(app, ["config", "show", "env", "--preset", "paper"]), "--preset")
    _one_line_exit_2(runner.invoke(app, ["config", "show", "ingest", "--preset", "slow"]), "slow")


def test_eval_env_overrides_reach_the_env_config():
    conf = apply_eval_overrides(EvalConfig(registry="r", policy="random", obstacles="none"),
                                ["trials=2", "env.camera.width=64", "env.reward.c_time=0.2", "env.obstacles.lateral=1"])
    assert conf.trials == 2
    camera, reward, obstacles = (conf.env_kwargs[k] for k in ("camera", "reward", "obstacles"))
    assert camera.width == 64 and camera.height == EnvConfig().camera.height
    assert reward.c_time == 0.2 and obstacles.lateral == 1.0
    assert (obstacles.min_count, obstacles.max_count) == (0, 0)  # still the "none" mode's counts
    assert set(conf.env_kwargs) == {"camera", "reward", "obstacles"}  # only what changed


def test_no_pybullet_banner():
    out = subprocess.run([sys.executable, "-m", "vid2sim.cli", "version"], capture_output=True, text=True,
                         cwd=Path(__file__).resolve().parent.parent, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "pybullet" not in out.stdout + out.stderr
