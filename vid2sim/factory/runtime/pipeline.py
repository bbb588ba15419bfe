"""The factory pipeline: clips -> stages (Ray tasks) -> scene bundles -> registry.

Per clip, in `workdir/<clip_id>/` (a local folder, or an object-store URI: then each stage runs
in its node's scratch and syncs with the store, see runtime/staging.py):
  decode/  masks/  sfm/  metric/  recon/  meshing/  walkable/  bundle/  (one stage each)
Each folder is a stage output with its `stage.json` marker (config + input hash), so a
re-run resumes after the last finished stage. The finished bundle is committed to the
registry by the driver (`Registry.add` is atomic). A clip that fails reports its stage
and reason; the others go on.
"""

from __future__ import annotations

import json
import os
import re
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Optional, Sequence, Union

import numba
import numpy as np
import ray
import torch
import trimesh

from vid2sim.factory.geometry import meshing, walkable
from vid2sim.factory.geometry.meshing import MeshingConfig
from vid2sim.factory.geometry.splat_views import SplatViewConfig, render_views
from vid2sim.factory.geometry.walkable import WalkableConfig
from vid2sim.factory.ingest import decode, masks
from vid2sim.factory.ingest.clip_list import ManifestRow, load_manifest, parse_row
from vid2sim.factory.ingest.clips import ClipsConfig, ClipSpec, plan_clips
from vid2sim.factory.ingest.decode import DecodeConfig
from vid2sim.factory.ingest.decode import preset as decode_preset
from vid2sim.factory.ingest.masks import MasksConfig
from vid2sim.factory.evaluation.corridor import CorridorConfig, corridor_check, gate_reasons
from vid2sim.factory.runtime.object_store import is_remote
from vid2sim.factory.runtime.staging import OnStore, fetch_from_store
from vid2sim.factory.ingest.sources import redact_uri, resolve_source
from vid2sim.factory.recon import trainer
from vid2sim.factory.recon.config import ReconConfig
from vid2sim.factory.recon.config import preset as recon_preset
from vid2sim.factory.runtime.bundle_assembly import assemble_bundle
from vid2sim.factory.runtime.orchestrator import ClipResult, ClipState, StageSpec, init_ray, run_clips
from vid2sim.factory.runtime.stage_cache import StageError, input_key
from vid2sim.factory.sfm import metric, sfm
from vid2sim.factory.sfm.metric import MetricConfig
from vid2sim.factory.sfm.posed import PosedClip
from vid2sim.factory.sfm.sfm import SfMConfig
from vid2sim.factory.sfm.sfm import preset as sfm_preset
from vid2sim.formats.walkable import load_walkable
from vid2sim.registry import Registry
from vid2sim.splats.ply import read_ply
from vid2sim.versioning import config_hash, from_jsonable, to_jsonable

MANIFEST_SUFFIXES = {".yaml", ".yml", ".csv", ".parquet"}
CORRIDOR_REPORT = "corridor.json"  # in the walkable stage folder, written before its marker


def _sfm_config(preset: str) -> SfMConfig:
    return sfm_preset("fast" if preset == "fast" else "accurate")


@dataclass
class PipelineConfig:
    """Every stage's config; saved with each scene (pipeline hash = hash of this)."""

    preset: str = "fast"  # name of the preset this config started from ("fast" | "paper"); a label, read by `resolved`
    clips: ClipsConfig = field(default_factory=ClipsConfig)  # cutting long sources into clips
    decode: DecodeConfig = field(default_factory=DecodeConfig)  # frame sampling, quality filters, face blurring
    masks: MasksConfig = field(default_factory=MasksConfig)  # dynamic-object masks (people, vehicles)
    sfm: Optional[SfMConfig] = None  # camera poses (COLMAP / GLOMAP); None: from the preset (see resolved)
    metric: Optional[MetricConfig] = None  # metric scale and ground plane; None: the defaults
    recon: ReconConfig = field(default_factory=lambda: recon_preset("fast"))  # Gaussian-splat training
    views: SplatViewConfig = field(default_factory=SplatViewConfig)  # splat depth views rendered for meshing
    meshing: MeshingConfig = field(default_factory=MeshingConfig)  # TSDF fusion into collision / visual meshes
    walkable: WalkableConfig = field(default_factory=WalkableConfig)  # walkable map and the physical collision mesh
    corridor: CorridorConfig = field(default_factory=CorridorConfig)  # walked-corridor check and quality gate

    def resolved(self) -> "PipelineConfig":
        """Fill the SfM/metric configs from the preset when left unset."""
        return replace(self, sfm=self.sfm or _sfm_config(self.preset),
                       metric=self.metric or MetricConfig())

    @classmethod
    def from_dict(cls, data: dict) -> "PipelineConfig":
        """Rebuild from `to_jsonable(conf)`, e.g. scene.json's pipeline.config."""
        return from_jsonable(cls, data)

    def save(self, path: Path) -> Path:
        """Write the config as JSON (the same object scene.json keeps under pipeline.config)."""
        Path(path).write_text(json.dumps(to_jsonable(self), indent=2))
        return Path(path)

    @classmethod
    def load(cls, path: Path) -> "PipelineConfig":
        """Read a config JSON written by `save` (or copied from a scene.json)."""
        return cls.from_dict(json.loads(Path(path).read_text()))


def preset(name: str) -> PipelineConfig:
    """Named pipeline presets: `fast` (minutes on 2 CPU cores, 10 fps) and `paper` (30 fps, 30k iterations)."""
    if name not in ("fast", "paper"):
        raise ValueError(f"unknown preset {name!r} (fast | paper)")
    views = SplatViewConfig() if name == "fast" else SplatViewConfig(scale=1.0, every=1)
    sampling = decode_preset("default" if name == "fast" else "paper")
    return PipelineConfig(preset=name, decode=sampling, recon=recon_preset(name), views=views).resolved()


# ----------------------------------------------------------------------------- clips

@dataclass(frozen=True)
class ClipJob:
    spec: ClipSpec
    scene_id: str
    licence: str


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
            failed.append(ClipResult(redact_uri(row.source), False, e.stage, e.reason, e.detail, {}, {}))
            continue
        stem = Path(row.source.split("?")[0].rstrip("/")).name.rsplit(".", 1)[0]
        jobs.extend(ClipJob(s, scene_id_for(s, stem), row.licence) for s in specs)
    return jobs, failed


# ----------------------------------------------------------------------------- stages

def _threads(ctx: dict) -> int:
    """Limit torch/numba threads to the CPUs Ray assigned to this task."""
    n = int(ray.get_runtime_context().get_assigned_resources().get("CPU", ctx.get("cpus", 1)) or 1)
    n = max(1, n)
    torch.set_num_threads(n)
    try:
        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    except ValueError:
        pass
    os.environ["OMP_NUM_THREADS"] = str(n)
    return n


def _dir(ctx: dict, stage: str) -> Path:
    return Path(ctx["clip_dir"]) / stage


def stage_decode(ctx: dict) -> dict:
    job: ClipJob = ctx["job"]
    conf: PipelineConfig = ctx["conf"]
    workers = _threads(ctx)
    out = decode.main(replace(conf.decode, workers=workers), job.spec.source, _dir(ctx, "decode"),
                      job.spec.window)
    return {"decode_dir": str(out)}


def stage_masks(ctx: dict) -> dict:
    _threads(ctx)
    out = masks.main(ctx["conf"].masks, Path(ctx["decode_dir"]), _dir(ctx, "masks"))
    return {"masks_dir": str(out)}


def stage_sfm(ctx: dict) -> dict:
    _threads(ctx)
    out = sfm.main(ctx["conf"].resolved().sfm, Path(ctx["decode_dir"]) / decode.OUTPUTS.images,
                   Path(ctx["masks_dir"]) / masks.OUTPUTS.masks,
                   _dir(ctx, "sfm"))
    return {"sfm_dir": str(out)}


def stage_metric(ctx: dict) -> dict:
    _threads(ctx)
    conf = replace(ctx["conf"].resolved().metric, capture_height_m=ctx["job"].spec.capture_height)
    out = metric.main(conf, Path(ctx["sfm_dir"]), _dir(ctx, "metric"),
                      Path(ctx["decode_dir"]) / decode.OUTPUTS.images)
    return {"posed_dir": str(out)}


def stage_recon(ctx: dict) -> dict:
    _threads(ctx)
    out = trainer.main(ctx["conf"].recon, Path(ctx["posed_dir"]), _dir(ctx, "recon"))
    return {"recon_dir": str(out)}


def stage_meshing(ctx: dict) -> dict:
    """Splat depth views -> collision + visual mesh and ground points (meshing/)."""
    _threads(ctx)
    conf: PipelineConfig = ctx["conf"]
    recon_dir = Path(ctx["recon_dir"])
    clip = PosedClip.load(Path(ctx["posed_dir"]))
    views_key = config_hash(input_key(recon_dir), conf.views)
    model = read_ply(recon_dir / "splats.ply")
    mesh_dir = meshing.main(conf.meshing, render_views(model, clip, conf.views), _dir(ctx, "meshing"),
                            input_key=views_key)
    return {"meshing_dir": str(mesh_dir)}


def stage_walkable(ctx: dict) -> dict:
    """Ground points + carved points + fused collision mesh + camera path -> the physical layer
    (walkable/): walkable grid and the collision mesh that agrees with it, and the corridor
    report on them (corridor.json, written before the stage marker: the marker is the last file
    of the folder); then the corridor gate, which writes nothing."""
    _threads(ctx)
    conf: PipelineConfig = ctx["conf"]
    mesh_dir = Path(ctx["meshing_dir"])
    clip = PosedClip.load(Path(ctx["posed_dir"]))
    path = np.array([f.cam_to_world[:3, 3] for f in clip.frames])  # [T, 3]
    carved = mesh_dir / meshing.OUTPUTS.carved_points
    ground = walkable.load_points(mesh_dir / meshing.OUTPUTS.ground_points, "bad_ground_points")
    # the corridor config decides corridor.json, a file of this stage: it is part of the key
    key = config_hash(input_key(mesh_dir), input_key(Path(ctx["posed_dir"])), conf.corridor)
    walk_dir = walkable.main(conf.walkable, ground, mesh_dir / meshing.OUTPUTS.collision, path,
                             _dir(ctx, "walkable"), input_key=key,
                             carved_points=walkable.load_points(carved, "bad_carved_points")
                             if carved.is_file() else None,
                             before_marker=lambda d: corridor_report(conf.corridor, d, path))
    corridor_gate(_read_corridor_report(walk_dir))
    return {"walkable_dir": str(walk_dir)}


def corridor_report(conf: CorridorConfig, walk_dir: Path, path: np.ndarray) -> dict:
    """Corridor check (vid2sim.factory.evaluation.corridor) of the physical layer in walk_dir
    (walkable.npz + the collision.ply the bundle ships) and its quality-gate verdict, written to
    walk_dir/corridor.json; returns the record."""
    mesh = trimesh.load(walk_dir / walkable.OUTPUTS.collision, force="mesh", process=False)
    report = corridor_check(load_walkable(walk_dir / walkable.OUTPUTS.grid), mesh, path, conf)
    reasons = gate_reasons(report, conf)
    out = {**report.to_dict(), "passed": not reasons, "reasons": ",".join(reasons)}
    (walk_dir / CORRIDOR_REPORT).write_text(json.dumps(out, indent=2))
    return out


def _read_corridor_report(walk_dir: Path) -> dict:
    try:
        return json.loads((walk_dir / CORRIDOR_REPORT).read_text())
    except (OSError, ValueError) as e:
        raise StageError("walkable", "bad_corridor_report", f"{walk_dir / CORRIDOR_REPORT}: {e}") from None


def corridor_gate(report: dict) -> None:
    """The quality gate on a corridor report (`corridor_report`): raises
    StageError('walkable', reason) when the walked corridor is blocked; writes nothing."""
    reasons = [r for r in str(report.get("reasons", "")).split(",") if r]
    if reasons:
        raise StageError("walkable", reasons[0], f"walked corridor check failed ({', '.join(reasons)}): "
                         f"{report['walkable_fraction']:.1%} of the path walkable, "
                         f"{report['path_components']} components, "
                         f"{report['corridor_area_m2']:.3f} m^2 of collision surface in the corridor")


def check_corridor(conf: CorridorConfig, walk_dir: Path, path: np.ndarray) -> dict:
    """`corridor_report` then `corridor_gate`: the report written to walk_dir/corridor.json,
    StageError('walkable', reason) when the walked corridor is blocked."""
    out = corridor_report(conf, walk_dir, path)
    corridor_gate(out)
    return out


def stage_bundle(ctx: dict) -> dict:
    _threads(ctx)
    out = assemble_bundle(ctx, _dir(ctx, "bundle"))
    return {"bundle_dir": str(out)}


STAGES: list[tuple[str, Callable[[dict], dict]]] = [
    ("decode", stage_decode), ("masks", stage_masks), ("sfm", stage_sfm), ("metric", stage_metric),
    ("recon", stage_recon), ("meshing", stage_meshing), ("walkable", stage_walkable), ("bundle", stage_bundle),
]


def stage_specs(cpus_per_clip: float, gpus_for_recon: float = 0.0,
                cpus_for_sfm: Optional[float] = None) -> list[StageSpec]:
    """The chain; each stage runs against the work store when the context names one.
    cpus_for_sfm: what the sfm stage reserves (default cpus_per_clip; 1 when COLMAP runs on
    one thread, `sfm.colmap_threads`, so another clip's stage can use the other cores)."""
    def cpus(name: str) -> float:
        return cpus_for_sfm if name == "sfm" and cpus_for_sfm is not None else cpus_per_clip

    return [StageSpec(name, OnStore(fn), num_cpus=cpus(name),
                      num_gpus=gpus_for_recon if name == "recon" else 0.0) for name, fn in STAGES]


# ----------------------------------------------------------------------------- run

@dataclass
class IngestReport:
    results: list[ClipResult]
    committed: dict[str, int]  # scene_id -> registry version
    seconds: float

    def to_json(self) -> dict:
        return {
            "seconds": round(self.seconds, 2),
            "clips": [{"clip": r.clip_id, "ok": r.ok, "scene_id": r.context.get("scene_id"),
                       "version": self.committed.get(r.context.get("scene_id", "")),
                       "failed_stage": r.failed_stage or None, "reason": r.reason or None,
                       "detail": (r.detail or "")[:500] or None,
                       "stage_seconds": {k: round(v, 2) for k, v in r.seconds.items()}}
                      for r in self.results],
        }


def clip_context(job: ClipJob, conf: PipelineConfig, cpus: float, workdir: Union[str, Path]) -> dict:
    """A clip's starting context: a local work folder, or a work store (object-store URI) that
    every node reads and writes through its own scratch (see runtime/staging.py)."""
    ctx = {"job": job, "conf": conf, "scene_id": job.scene_id, "cpus": cpus, "clip_id": job.spec.clip_id}
    if is_remote(str(workdir)):
        return {**ctx, "work_uri": str(workdir).rstrip("/")}
    return {**ctx, "clip_dir": str(Path(workdir).resolve() / job.spec.clip_id)}


def bundle_path(ctx: dict) -> Path:
    """The finished bundle as a local folder (fetched from the work store when there is one)."""
    if ctx.get("work_uri"):
        return fetch_from_store(ctx["work_uri"], ctx["clip_id"], ctx["bundle_dir"])
    return Path(ctx["bundle_dir"])


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
    clips = [(j.spec.clip_id, clip_context(j, conf, cpus, workdir)) for j in jobs]
    committed: dict[str, int] = {}

    def commit(state: ClipState) -> None:
        try:
            rec = reg.add(bundle_path(state.context))
        except Exception as e:  # BundleError or storage error: the clip fails, the registry is intact
            raise StageError("commit", "commit_failed", str(e)) from e
        committed[rec.scene_id] = rec.version

    sfm_cpus = min(1.0, cpus) if sfm.colmap_threads(conf.sfm) == 1 else cpus
    results = run_clips(clips, stage_specs(cpus, gpus, sfm_cpus), max_retries=max_retries, on_update=on_update,
                        on_clip_done=commit) if clips else []
    return IngestReport(failed + results, committed, time.perf_counter() - t0)
