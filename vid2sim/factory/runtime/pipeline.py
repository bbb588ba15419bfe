"""The factory pipeline: clips -> steps (Ray tasks) -> scene bundles -> registry.

Per clip, in `workdir/<clip_id>/` (a local folder, or an object-store URI: then each step runs
in its node's scratch and syncs with the store, see runtime/runner.py):
  decode/  masks/  sfm/  metric/  recon/  meshing/  walkable/  bundle/  (one step each, `STEPS`)
Each folder is a step output with its `stage.json` marker (config + input hash), so a
re-run resumes after the last finished step. The finished bundle is committed to the
registry by the driver (`Registry.add` is atomic). A clip that fails reports its stage
and reason; the others go on.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Sequence, Union

import ray

from vid2sim.factory.ingest.clip_list import ManifestRow, load_manifest, parse_row
from vid2sim.factory.ingest.clips import ClipSpec, plan_clips
from vid2sim.factory.ingest.sources import redact_uri, resolve_source
from vid2sim.factory.runtime.config import ClipJob, PipelineConfig, preset
from vid2sim.factory.runtime.orchestrator import ClipResult, ClipState, StageSpec, init_ray, run_clips
from vid2sim.factory.runtime.runner import ClipWork, StepTask, clip_work, local_outputs
from vid2sim.factory.runtime.stage_cache import StageError
from vid2sim.factory.runtime.steps import STEP_NAMES, STEPS, bundle, recon
from vid2sim.factory.sfm import sfm
from vid2sim.registry import Registry

__all__ = ["STEPS", "STEP_NAMES", "ClipJob", "ClipWork", "PipelineConfig", "preset", "ingest", "stage_specs"]

MANIFEST_SUFFIXES = {".yaml", ".yml", ".csv", ".parquet"}


# ----------------------------------------------------------------------------- clips

def slug(text: str, limit: int = 40) -> str:
    s = re.sub(r"[^a-z0-9._-]+", "-", text.lower()).strip("-._")
    return (s or "clip")[:limit].strip("-._") or "clip"


def scene_id_for(spec: ClipSpec, stem: str) -> str:
    """Registry id naming the clip: <stem>-<sha8>[-<start>-<end>s], the window exact to 1 ms.

    Re-ingesting a clip gives the same id (a new version); any other window, another scene.
    """
    tail = f"-{spec.source.sha256[:8]}"
    if spec.window is not None:
        tail += "-" + "-".join(f"{t:.3f}".rstrip("0").rstrip(".") for t in spec.window) + "s"
    return slug(stem, limit=64 - len(tail)) + tail


def rows_from_inputs(inputs: Sequence[str], licence: str = "unknown",
                     capture_height: Optional[float] = None) -> list[ManifestRow]:
    """Manifest files are read; anything else is one source (video, image folder, URI)."""
    rows: list[ManifestRow] = []
    for i, item in enumerate(inputs):
        path = Path(item)
        if path.suffix.lower() in MANIFEST_SUFFIXES and path.is_file():
            rows.extend(load_manifest(path))
        else:
            rec = {"source": item, "licence": licence}
            if capture_height:
                rec["capture_height"] = capture_height
            rows.append(parse_row(rec, i, Path("."), "command line"))
    return rows


def plan_jobs(rows: Sequence[ManifestRow], conf: PipelineConfig, cache_dir: Optional[Path] = None
              ) -> tuple[list[ClipJob], list[ClipResult]]:
    """Resolve sources and cut clips; a source that cannot be read fails alone."""
    jobs, failed = [], []
    for row in rows:
        try:
            source = resolve_source(row.source, cache_dir, row.sha256) if cache_dir else \
                resolve_source(row.source, expected_sha256=row.sha256)
            specs = plan_clips(row, source, conf.clips)
        except StageError as e:
            failed.append(ClipResult(redact_uri(row.source), False, e.stage, e.reason, e.detail, None, {}))
            continue
        stem = Path(row.source.split("?")[0].rstrip("/")).name.rsplit(".", 1)[0]
        jobs.extend(ClipJob(s, scene_id_for(s, stem), row.licence) for s in specs)
    return jobs, failed


# ----------------------------------------------------------------------------- steps

def stage_specs(cpus_per_clip: float, gpus_for_recon: float = 0.0,
                cpus_for_sfm: Optional[float] = None) -> list[StageSpec]:
    """The chain of `STEPS` as Ray stages, each run by the one runner (`runner.StepTask`).
    cpus_for_sfm: what the sfm stage reserves (default cpus_per_clip; 1 when COLMAP runs on
    one thread, `sfm.colmap_threads`, so another clip's stage can use the other cores)."""
    def cpus(name: str) -> float:
        return cpus_for_sfm if name == sfm.STAGE and cpus_for_sfm is not None else cpus_per_clip

    return [StageSpec(step.name, StepTask(step), num_cpus=cpus(step.name),
                      num_gpus=gpus_for_recon if step.name == recon.NAME else 0.0) for step in STEPS]


# ----------------------------------------------------------------------------- run

@dataclass
class IngestReport:
    results: list[ClipResult]
    committed: dict[str, int]  # scene_id -> registry version
    seconds: float

    def to_json(self) -> dict:
        return {
            "seconds": round(self.seconds, 2),
            "clips": [{"clip": r.clip_id, "ok": r.ok, "scene_id": _scene_id(r),
                       "version": self.committed.get(_scene_id(r) or ""),
                       "failed_stage": r.failed_stage or None, "reason": r.reason or None,
                       "detail": (r.detail or "")[:500] or None,
                       "stage_seconds": {k: round(v, 2) for k, v in r.seconds.items()}}
                      for r in self.results],
        }


def _scene_id(result: ClipResult) -> Optional[str]:
    return result.work.job.scene_id if result.work is not None else None


def bundle_path(work: ClipWork) -> Path:
    """The finished bundle as a local folder (fetched from the work store when there is one)."""
    return bundle.Outputs(local_outputs(work, bundle.NAME).dir).scene


def ingest(inputs: Sequence[str], registry: Optional[str] = None, *,
           workdir: Union[str, Path] = Path("vid2sim-work"),
           conf: Optional[PipelineConfig] = None, ray_address: Optional[str] = None,
           num_cpus: Optional[int] = None, licence: str = "unknown",
           capture_height: Optional[float] = None, max_retries: int = 2,
           on_update: Optional[Callable[[ClipState], None]] = None,
           on_plan: Optional[Callable[[list[str]], None]] = None) -> IngestReport:
    """Run every clip of `inputs` through the pipeline and commit finished scenes."""
    t0 = time.perf_counter()
    conf = (conf or preset("fast")).resolved()
    reg = Registry(registry)
    jobs, failed = plan_jobs(rows_from_inputs(inputs, licence, capture_height), conf)
    if on_plan:
        on_plan([j.spec.clip_id for j in jobs] + [f.clip_id for f in failed])
    init_ray(ray_address, num_cpus)
    total_cpus = int(ray.cluster_resources().get("CPU", 1))
    cpus = float(max(1, total_cpus // max(1, len(jobs))))
    gpus = 1.0 if ray.cluster_resources().get("GPU", 0) >= 1 else 0.0
    clips = [(j.spec.clip_id, clip_work(j, conf, workdir, cpus)) for j in jobs]
    committed: dict[str, int] = {}

    def commit(state: ClipState) -> None:
        try:
            rec = reg.add(bundle_path(state.work))
        except Exception as e:  # BundleError or storage error: the clip fails, the registry is intact
            raise StageError("commit", "commit_failed", str(e)) from e
        committed[rec.scene_id] = rec.version

    sfm_cpus = min(1.0, cpus) if sfm.colmap_threads(conf.sfm) == 1 else cpus
    results = run_clips(clips, stage_specs(cpus, gpus, sfm_cpus), max_retries=max_retries, on_update=on_update,
                        on_clip_done=commit) if clips else []
    return IngestReport(failed + results, committed, time.perf_counter() - t0)
