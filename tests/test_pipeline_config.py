"""PipelineConfig round-trips through scene.json; the presets set what docs/factory.md says."""

from __future__ import annotations

import json

import pytest

from vid2sim.factory.runtime.pipeline import PipelineConfig, preset, stage_specs
from vid2sim.formats.scene import make_scene_json
from vid2sim.versioning import config_hash


@pytest.mark.parametrize("name", ["fast", "paper"])
def test_pipeline_config_round_trips_through_scene_json(name):
    conf = preset(name)
    scene = make_scene_json("s", source_uri="file:///v.mp4", source_sha256="0" * 64, clip_start_s=0.0,
                            clip_end_s=1.0, scale_source="capture_height", config=conf)
    back = PipelineConfig.from_dict(json.loads(json.dumps(scene))["pipeline"]["config"])
    assert back == conf
    assert config_hash(back) == scene["pipeline"]["config_hash"]


def test_presets_sample_at_the_documented_rates():
    assert preset("fast").decode.fps == 10.0
    assert preset("paper").decode.fps == 30.0  # the paper's 30 fps
    assert preset("paper").recon.iterations == 30_000
    with pytest.raises(ValueError, match="unknown preset"):
        preset("slow")


def test_unknown_config_field_is_named():
    scene = make_scene_json("s", source_uri="u", source_sha256="0" * 64, clip_start_s=0.0, clip_end_s=1.0,
                            scale_source="x", config=preset("fast"))
    data = json.loads(json.dumps(scene["pipeline"]["config"]))
    data["decode"]["fsp"] = 12.0
    with pytest.raises(TypeError, match="DecodeConfig.*fsp"):
        PipelineConfig.from_dict(data)


def test_sfm_stage_reserves_one_cpu_when_colmap_runs_on_one_thread():
    """Deterministic SfM (the default) uses one COLMAP thread, so its stage reserves one CPU and
    another clip's stage can run beside it; every other stage reserves the clip's share."""
    assert preset("fast").resolved().sfm.deterministic
    specs = {s.name: s for s in stage_specs(2.0, 0.0, 1.0)}
    assert specs["sfm"].num_cpus == 1.0
    assert all(s.num_cpus == 2.0 for name, s in specs.items() if name != "sfm")
    assert all(s.num_cpus == 2.0 for s in stage_specs(2.0))
