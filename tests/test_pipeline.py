"""The factory pipeline's back half on a real Ray runtime: a ground-truth posed synthetic
clip -> splat training -> TSDF mesh + walkable map -> bundle -> registry commit; then a
re-run resumes from the cache and commits nothing new."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
import ray

from vid2sim.factory.ingest.clips import ClipSpec
from vid2sim.factory.runtime.orchestrator import ensure_ray, run_clips
from vid2sim.factory.runtime.stage_cache import MARKER
from vid2sim.factory.runtime.pipeline import ClipJob, PipelineConfig, bundle_path, clip_work, stage_specs
from vid2sim.factory.runtime.steps import metric
from vid2sim.factory.recon.config import preset as recon_preset
from vid2sim.factory.ingest.sources import resolve_source
from vid2sim.factory.synthetic.config import preset as street_preset
from vid2sim.factory.synthetic.make_street import main as make_street
from vid2sim.registry import Registry
from vid2sim.formats.bundle import validate_bundle

pytestmark = pytest.mark.slow  # splat training + meshing through Ray (about a minute)

BACK_HALF = ("recon", "meshing", "walkable", "bundle")


@pytest.fixture(scope="module")
def street(tmp_path_factory) -> Path:
    conf = street_preset("test", seed=1, duration_s=2.0, width=192, height=108, write_frames=True)
    return make_street(conf, tmp_path_factory.mktemp("street"))


@pytest.fixture(scope="module", autouse=True)
def local_ray():
    ensure_ray(num_cpus=2)
    yield
    ray.shutdown()


def _run(street: Path, work: Path, registry: Registry):
    conf = PipelineConfig(recon=recon_preset("fast", iterations=120, max_width=192, checkpoint_every=1000))
    conf.recon.densify = replace(conf.recon.densify, start_iter=40, stop_iter=100, every=20)
    conf.recon.loss = replace(conf.recon.loss, geometry_from_iter=40)
    source = resolve_source(street / "video.mp4")
    job = ClipJob(ClipSpec("clip0", source, None, "street-1", 1.5, {"city": "synthetic"}), "synthetic-street-1",
                  "CC0")
    start = clip_work(job, conf, work, 2, metric=metric.Outputs(street))  # enters posed, past metric
    stages = [s for s in stage_specs(2) if s.name in BACK_HALF]
    versions = []
    results = run_clips([("clip0", start)], stages,
                        on_clip_done=lambda s: versions.append(registry.add(bundle_path(s.work)).version))
    return results[0], versions


def _markers(clip_dir: Path) -> dict[str, tuple[str, int]]:
    """{stage: (marker key, marker mtime_ns)} of the finished stage folders."""
    return {p.parent.name: (json.loads(p.read_text())["key"], p.stat().st_mtime_ns)
            for p in sorted(clip_dir.glob("*/" + MARKER))}


def test_back_half_commits_a_valid_scene_and_resumes(street, tmp_path):
    registry = Registry(str(tmp_path / "registry"))
    result, versions = _run(street, tmp_path / "work", registry)
    assert result.ok, f"{result.failed_stage}: {result.reason}: {result.detail}"
    info = validate_bundle(bundle_path(result.work))
    assert info.scene_id == "synthetic-street-1"
    assert info.num_splats > 100
    scenes = registry.list()
    assert [s.scene_id for s in scenes] == ["synthetic-street-1"]
    assert scenes[0].walkable_area_m2 > 1.0
    assert "recon.psnr" in scenes[0].metrics and scenes[0].metrics["recon.psnr"] > 12.0
    assert registry.verify() == []
    markers = _markers(tmp_path / "work" / "clip0")
    assert set(markers) == set(BACK_HALF)

    again, versions2 = _run(street, tmp_path / "work", registry)
    assert again.ok
    assert _markers(tmp_path / "work" / "clip0") == markers  # every stage cached: no marker rewritten
    assert versions2 == versions  # identical content: no new registry version
