"""`vid2sim ingest` end to end: a clip list with one good and one bad clip, through the real
CLI, real Ray and every stage; the good clip is registered, the bad one reported by name."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from vid2sim.factory.recon.config import preset as recon_preset
from vid2sim.factory.runtime.pipeline import STEP_NAMES, preset
from vid2sim.factory.runtime.stage_cache import MARKER
from vid2sim.factory.synthetic import generate_street, render_video
from vid2sim.factory.synthetic import preset as street_preset
from vid2sim.registry import Registry

pytestmark = pytest.mark.slow  # SfM + splat training of a 4 s clip through Ray (minutes)


def _tiny_config(path: Path) -> Path:
    conf = preset("fast")
    recon = recon_preset("fast", iterations=150, checkpoint_every=1000)
    recon.densify = replace(recon.densify, start_iter=50, stop_iter=120, every=25)
    recon.loss = replace(recon.loss, geometry_from_iter=50)
    return replace(conf, recon=recon).save(path)


def test_ingest_registers_the_good_clip_and_names_the_bad_one(tmp_path):
    street = street_preset("demo", seed=1, duration_s=4.0, write_depth=False)
    clip = render_video(generate_street(street), street, tmp_path / "street")
    (tmp_path / "broken.mp4").write_bytes(b"this is not a video" * 100)
    clip_list = tmp_path / "clips.yaml"
    clip_list.write_text(yaml.safe_dump([{"source": str(clip.video), "licence": "CC0", "group": "street-1"},
                                         {"source": "broken.mp4", "licence": "CC0"}]))
    cmd = [sys.executable, "-m", "vid2sim.cli", "ingest", str(clip_list), "--registry", str(tmp_path / "reg"),
           "--workdir", str(tmp_path / "work"), "--config", str(_tiny_config(tmp_path / "conf.json")),
           "--num-cpus", "2", "--json"]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=1800, env={**os.environ})
    assert run.returncode == 1, run.stderr[-3000:]  # one clip failed
    clips = {c["clip"]: c for c in json.loads(run.stdout)["clips"]}
    good = [c for c in clips.values() if c["ok"]]
    bad = [c for c in clips.values() if not c["ok"]]
    assert len(good) == 1 and len(bad) == 1, clips
    assert bad[0]["reason"] == "not_a_video" and "broken" in bad[0]["clip"]
    assert good[0]["version"] == 1
    scenes = Registry(str(tmp_path / "reg")).list()
    assert [s.scene_id for s in scenes] == [good[0]["scene_id"]]
    stage_dirs = tmp_path / "work" / good[0]["clip"]
    assert sorted(p.parent.name for p in stage_dirs.glob("*/" + MARKER)) == sorted(STEP_NAMES)
