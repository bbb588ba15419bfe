"""The `sfm` stage: masked SIFT, sequential matching, global (GLOMAP) or incremental mapping.

Reads:  `images_dir` (an ordered folder of frames) and optionally `masks_dir` (uint8, 0 = dynamic /
        ignored, 255 = static; named `<image>.png`, e.g. `000001.jpg.png`, or `<stem>.png`).
Writes into `out_dir`:
  database.db                 COLMAP features and verified matches
  sparse/0/                   COLMAP model (the lens model chosen by `camera_model.py`)
  undistorted/images/, undistorted/masks/<image>.png, undistorted/sparse/   pinhole images + model
  transforms.json             nerfstudio export of the undistorted model
  quality.json                registered fraction, reprojection error, track length, parallax,
                              timings (also written, with `failed`, when the quality gate fails)
  stage.json                  marker, only on success (written by the runner, runtime/runner.py).
Quality gate (StageError reasons): `too_few_frames`, `static_camera`, `too_few_registered`.
Loop detection needs a vocabulary-tree file (`vocab_tree_path`); none ships offline, so without
one the presets use quadratic sequential overlap (frames i +- 1, 2, 4, ... 2^k) instead.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import cv2
import numpy as np

from vid2sim.factory.sfm.camera_model import CameraChoice, LensHint, choose_camera_model, exif_hint
from vid2sim.factory.sfm.database import copy_in_name_order
from vid2sim.factory.sfm.export import write_colmap, write_transforms
from vid2sim.factory.sfm.undistort import undistort_project
from vid2sim.factory.runtime.stage_cache import StageError, StageWork, Timer, fresh_dir, input_key
from vid2sim.ranges import checked
from vid2sim.versioning import to_jsonable

STAGE = "sfm"
STAGE_VERSION = 2  # bump when this stage's outputs change for the same inputs


@dataclass(frozen=True)
class SfMOutputs:
    """Files of a finished sfm folder, relative to it."""

    quality: str = "quality.json"
    undistorted: str = "undistorted"  # the pinhole COLMAP project: images/, sparse/, masks/


OUTPUTS = SfMOutputs()

IMAGE_EXTS = (".jpg", ".jpeg", ".png")


@checked
@dataclass
class SfMConfig:
    """SfM options. `SfMConfig.preset("fast" | "accurate")` gives the named presets."""

    max_image_size: int = 848  # SIFT runs on frames downscaled to this longest side
    max_num_features: int = 4096  # SIFT features per frame, at most
    first_octave: int = -1  # -1: SIFT on a 2x upsampled image (more small features, ~3x slower)
    overlap: int = 10  # sequential matching window
    quadratic_overlap: bool = True  # also match i +- 2^k (a stand-in for loop closure)
    loop_detection: bool = False  # needs vocab_tree_path (a local file; never downloaded)
    vocab_tree_path: str = ""  # COLMAP vocabulary-tree file for loop_detection ("" = none)
    mapper: str = "global"  # "global" (GLOMAP) | "incremental"
    fallback_incremental: bool = True  # rerun incrementally if global registers too few
    retriangulate: bool = True  # global mapper's final retriangulation + refinement pass
    # global mapper: 0 solves on every track; N keeps tracks, longest first, until every frame has N
    # (GLOMAP's track selection), and the other points are triangulated from the solved poses
    # afterwards (poses and intrinsics fixed): a smaller problem for global positioning and BA
    tracks_per_view: int = 0
    camera_model: str = "auto"  # auto | OPENCV | OPENCV_FISHEYE | SIMPLE_RADIAL | PINHOLE ...
    camera_params: list[float] = field(default_factory=list)  # known intrinsics (COLMAP order)
    refine_intrinsics: Optional[bool] = None  # None: refine unless camera_params are given
    lens: LensHint = field(default_factory=LensHint)  # hints for camera_model="auto"
    # threads of feature extraction and undistortion (their output does not depend on it), and of
    # COLMAP's matching and mappers when deterministic is False
    num_threads: int = 2
    seed: int = 0  # COLMAP's random seed (RANSAC, mapper)
    # True: COLMAP's matching and mappers run on one thread, so the same frames give the same model
    # bit for bit (with 2, the descriptor matches differ between runs and bundle adjustment moves the
    # focal length by ~1e-4 px). Extraction keeps a one-thread run's image ids
    # (database.copy_in_name_order) and undistortion is per frame: both use num_threads either way.
    deterministic: bool = True
    undistort: bool = True  # also write pinhole images, masks and model in undistorted/ (recon reads them)
    min_frames: int = 10  # fewer input frames fails the stage (too_few_frames)
    min_registered_fraction: float = 0.8  # fewer frames registered fails the stage (too_few_registered)
    static_max_flow_px: float = 1.0  # median match displacement below this -> static camera
    static_min_tri_angle_deg: float = 0.25  # median triangulation angle below this -> static

    @classmethod
    def preset(cls, name: str, **overrides: Any) -> "SfMConfig":
        presets = {
            "fast": dict(max_image_size=848, max_num_features=4096, first_octave=0, overlap=10,
                         retriangulate=False),
            "accurate": dict(max_image_size=1600, max_num_features=8192, first_octave=-1,
                             overlap=20, retriangulate=True),
        }
        if name not in presets:
            raise ValueError(f"unknown SfM preset {name!r}; choose from {sorted(presets)}")
        return cls(**{**presets[name], **overrides})


def preset(name: str, **overrides: Any) -> SfMConfig:
    """Named SfM presets: "fast" (2-core budget) and "accurate"."""
    return SfMConfig.preset(name, **overrides)


@dataclass
class SfMQuality:
    num_frames: int = 0
    num_registered: int = 0
    registered_fraction: float = 0.0
    mean_reproj_error_px: Optional[float] = None
    mean_track_length: float = 0.0
    num_points: int = 0
    median_tri_angle_deg: float = 0.0
    median_flow_px: float = 0.0
    mapper: str = ""
    camera_model: str = ""
    camera_params: list[float] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    images_dir: str = ""  # the input frames, relative to the SfM folder (metric finds timestamps beside them)
    failed: str = ""


# ----------------------------------------------------------------------------- inputs

def list_images(images_dir: Path) -> list[str]:
    """Sorted image file names in `images_dir`."""
    images_dir = Path(images_dir)
    if not images_dir.is_dir():
        raise StageError(STAGE, "missing_input", f"images folder {images_dir} does not exist")
    return sorted(p.name for p in images_dir.iterdir() if p.suffix.lower() in IMAGE_EXTS)


def colmap_masks(masks_dir: Optional[Path], names: list[str], out_dir: Path) -> Optional[Path]:
    """A folder with COLMAP-named masks (`<image>.png`); links `<stem>.png` masks when needed."""
    if masks_dir is None or not Path(masks_dir).is_dir():
        return None
    masks_dir = Path(masks_dir)
    if all((masks_dir / f"{n}.png").exists() for n in names):
        return masks_dir
    linked = out_dir / "masks_colmap"
    linked.mkdir(exist_ok=True)
    found = 0
    for n in names:
        for cand in (masks_dir / f"{n}.png", masks_dir / f"{Path(n).stem}.png"):
            if cand.exists():
                os.symlink(cand.resolve(), linked / f"{n}.png")
                found += 1
                break
    return linked if found else None


def choose_camera(conf: SfMConfig, images_dir: Path, first: str) -> CameraChoice:
    img = cv2.imread(str(Path(images_dir) / first), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise StageError(STAGE, "unreadable_image", f"{Path(images_dir) / first} cannot be read")
    h, w = img.shape[:2]
    if conf.camera_params:
        return CameraChoice(conf.camera_model if conf.camera_model != "auto" else "PINHOLE",
                            list(conf.camera_params), "known intrinsics")
    hint = conf.lens if (conf.lens.make or conf.lens.hfov_deg or conf.lens.wide is not None
                         or conf.lens.focal_px) else exif_hint(Path(images_dir) / first)
    return choose_camera_model(w, h, hint, conf.camera_model)


# ----------------------------------------------------------------------------- COLMAP steps

def colmap_threads(conf: SfMConfig) -> int:
    """Threads of COLMAP's matching and mappers: 1 when the run must be reproducible (on 2 threads the
    descriptor matches differ between runs, and bundle adjustment moves the focal length by ~1e-4 px)."""
    return 1 if conf.deterministic else conf.num_threads


def extract(conf: SfMConfig, db: Path, images_dir: Path, names: list[str],
            masks: Optional[Path], cam: CameraChoice) -> None:
    """SIFT features of `names` into the new database `db`, on `conf.num_threads` threads whether or not
    the run is deterministic: each frame's features do not depend on the thread count, only the ids
    COLMAP hands out (completion order), so with more than one thread the features go to a scratch
    database first and `copy_in_name_order` writes `db` with a one-thread run's ids."""
    import pycolmap

    threads = max(1, conf.num_threads)
    target = db if threads == 1 else db.with_name(db.stem + "-unordered.db")
    target.unlink(missing_ok=True)
    ro = pycolmap.ImageReaderOptions()
    ro.camera_model = cam.model
    if cam.params:
        ro.camera_params = ",".join(f"{p:.10g}" for p in cam.params)
    if masks is not None:
        ro.mask_path = str(masks)
    eo = pycolmap.FeatureExtractionOptions()
    eo.max_image_size = conf.max_image_size
    eo.num_threads = threads
    eo.use_gpu = False
    eo.sift.max_num_features = conf.max_num_features
    eo.sift.first_octave = conf.first_octave
    pycolmap.extract_features(target, images_dir, image_names=names,
                              camera_mode=pycolmap.CameraMode.SINGLE, reader_options=ro,
                              extraction_options=eo, device=pycolmap.Device.cpu)
    if target != db:
        copy_in_name_order(target, db, names)
        target.unlink()


def match(conf: SfMConfig, db: Path) -> None:
    """Sequential matching and geometric verification into `db`, each pair's RANSAC seeded with
    `conf.seed`. On one thread when the run is deterministic: the descriptor matches themselves
    differ between runs on two threads (16 KITTI frames: one run of four differed)."""
    import pycolmap

    mo = pycolmap.FeatureMatchingOptions()
    mo.num_threads = colmap_threads(conf)
    mo.use_gpu = False
    po = pycolmap.SequentialPairingOptions()
    po.overlap = conf.overlap
    po.quadratic_overlap = conf.quadratic_overlap
    po.num_threads = colmap_threads(conf)
    if conf.loop_detection:
        if not conf.vocab_tree_path or not Path(conf.vocab_tree_path).is_file():
            raise StageError(STAGE, "missing_vocab_tree",
                             f"loop_detection needs a local vocab tree, got {conf.vocab_tree_path!r}")
        po.loop_detection = True
        po.vocab_tree_path = conf.vocab_tree_path
    vo = pycolmap.TwoViewGeometryOptions()
    vo.ransac.random_seed = conf.seed
    pycolmap.match_sequential(db, matching_options=mo, pairing_options=po, verification_options=vo,
                              device=pycolmap.Device.cpu)


def median_flow_px(db: Path) -> float:
    """Median (over verified pairs) of the median inlier-match displacement, in pixels."""
    import pycolmap

    database = pycolmap.Database.open(str(db))
    try:
        pair_ids, geoms = database.read_two_view_geometries()
        kps: dict[int, np.ndarray] = {}
        flows = []
        for pid, g in zip(pair_ids, geoms):
            m = np.asarray(g.inlier_matches)  # [K, 2]
            if len(m) < 8:
                continue
            i1, i2 = pycolmap.pair_id_to_image_pair(pid)
            for i in (i1, i2):
                if i not in kps:
                    kps[i] = np.asarray(database.read_keypoints(i))[:, :2]
            d = np.linalg.norm(kps[i1][m[:, 0]] - kps[i2][m[:, 1]], axis=1)
            flows.append(float(np.median(d)))
    finally:
        database.close()
    return float(np.median(flows)) if flows else 0.0


def intrinsics_refined(conf: SfMConfig) -> bool:
    return conf.refine_intrinsics if conf.refine_intrinsics is not None else not conf.camera_params


def map_global(conf: SfMConfig, db: Path, images_dir: Path, out: Path) -> dict:
    import pycolmap

    o = pycolmap.GlobalPipelineOptions()
    o.num_threads = colmap_threads(conf)
    o.random_seed = conf.seed
    ba = o.mapper.bundle_adjustment
    ba.refine_focal_length = ba.refine_extra_params = intrinsics_refined(conf)
    ba.ceres.use_gpu = False
    o.mapper.global_positioning.use_gpu = False
    o.mapper.skip_retriangulation = not conf.retriangulate
    if conf.tracks_per_view > 0:
        o.mapper.track_required_tracks_per_view = conf.tracks_per_view
    recs = pycolmap.global_mapping(db, images_dir, out, o)
    if conf.tracks_per_view > 0 and recs:
        recs = {0: triangulate_all(conf, largest(recs), db, images_dir, out / "triangulated")}
    return recs


def triangulate_all(conf: SfMConfig, rec: Any, db: Path, images_dir: Path, out: Path) -> Any:
    """Every track of the database triangulated into `rec` from its poses (poses, intrinsics and the
    points already there kept; COLMAP's point triangulator with bundle adjustment of the points)."""
    import pycolmap

    o = pycolmap.IncrementalPipelineOptions()
    o.num_threads = colmap_threads(conf)
    o.random_seed = conf.seed
    out.mkdir(parents=True, exist_ok=True)
    return pycolmap.triangulate_points(rec, db, images_dir, out, clear_points=False, options=o,
                                       refine_intrinsics=False)


def map_incremental(conf: SfMConfig, db: Path, images_dir: Path, out: Path) -> dict:
    import pycolmap

    o = pycolmap.IncrementalPipelineOptions()
    o.num_threads = colmap_threads(conf)
    o.random_seed = conf.seed
    o.multiple_models = False
    refine = intrinsics_refined(conf)
    o.ba_refine_focal_length = o.ba_refine_extra_params = refine
    o.mapper.abs_pose_refine_focal_length = o.mapper.abs_pose_refine_extra_params = refine
    return pycolmap.incremental_mapping(db, images_dir, out, o)


def largest(recs: dict) -> Any:
    return max(recs.values(), key=lambda r: r.num_reg_images()) if recs else None


def run_mapper(conf: SfMConfig, db: Path, images_dir: Path, work: Path, n: int) -> tuple[Any, str]:
    """Global mapper first; the incremental one when it registers < min_registered_fraction."""
    order = [conf.mapper] + (["incremental"] if conf.mapper == "global"
                             and conf.fallback_incremental else [])
    best, used = None, ""
    for name in order:
        out = fresh_dir(work / name)
        fn = map_global if name == "global" else map_incremental
        try:
            rec = largest(fn(conf, db, images_dir, out))
        except RuntimeError:
            rec = None
        if rec is not None and (best is None or rec.num_reg_images() > best.num_reg_images()):
            best, used = rec, name
        if best is not None and best.num_reg_images() >= conf.min_registered_fraction * n:
            break
    return best, used


# ----------------------------------------------------------------------------- quality

def median_tri_angle_deg(rec: Any, max_points: int = 3000, seed: int = 0) -> float:
    """Median over points of the largest angle between rays to the track's cameras (sampled)."""
    centers = {i: im.projection_center() for i, im in rec.images.items() if im.has_pose}
    ids = list(rec.point3D_ids())
    if not ids:
        return 0.0
    rng = np.random.default_rng(seed)
    ids = rng.choice(ids, size=min(max_points, len(ids)), replace=False)
    angles = []
    for pid in ids:
        p = rec.point3D(int(pid))
        c = np.array([centers[e.image_id] for e in p.track.elements if e.image_id in centers])
        if len(c) < 2:
            continue
        rays = c - p.xyz  # [T, 3]
        rays /= np.linalg.norm(rays, axis=1, keepdims=True) + 1e-12
        # widest pair: rays farthest from their mean direction on either side
        cos = np.clip(rays @ rays.T, -1.0, 1.0)
        angles.append(np.degrees(np.arccos(cos.min())))
    return float(np.median(angles)) if angles else 0.0


def measure(rec: Any, n: int) -> SfMQuality:
    rec.update_point_3d_errors()
    cam = next(iter(rec.cameras.values()))
    return SfMQuality(num_frames=n, num_registered=rec.num_reg_images(),
                      registered_fraction=rec.num_reg_images() / max(n, 1),
                      mean_reproj_error_px=float(rec.compute_mean_reprojection_error()),
                      mean_track_length=float(rec.compute_mean_track_length()),
                      num_points=rec.num_points3D(),
                      median_tri_angle_deg=median_tri_angle_deg(rec),
                      camera_model=cam.model.name, camera_params=[float(p) for p in cam.params])


def fail(out_dir: Path, q: SfMQuality, reason: str, detail: str) -> StageError:
    """Record the failure in quality.json (no marker) and build the error to raise."""
    q.failed = reason
    (out_dir / OUTPUTS.quality).write_text(json.dumps(to_jsonable(q), indent=2))
    return StageError(STAGE, reason, detail)


# ----------------------------------------------------------------------------- outputs

def write_outputs(out_dir: Path, images_dir: Path, masks: Optional[Path], rec: Any,
                  conf: SfMConfig) -> None:
    write_colmap(rec, out_dir / "sparse" / "0")
    if not conf.undistort:
        return
    und = out_dir / OUTPUTS.undistorted
    # each frame's remap is independent, so every thread may work even when deterministic
    und_rec = undistort_project(rec, images_dir, masks, und, threads=conf.num_threads)
    mask_names = ({p.name[:-4] for p in (und / "masks").iterdir()}
                  if (und / "masks").is_dir() else set())
    write_transforms(und_rec, out_dir / "transforms.json", "undistorted/images",
                     "undistorted/masks" if mask_names else None, mask_names)


# ----------------------------------------------------------------------------- stage

def work(conf: SfMConfig, images_dir: Path, masks_dir: Optional[Path]) -> StageWork:
    """SfM on an ordered frame folder: keyed by the config and the keys of the frames and masks."""
    images_dir = Path(images_dir)
    names = list_images(images_dir)
    keys = (input_key(images_dir), input_key(masks_dir) if masks_dir else None)
    return StageWork(STAGE, STAGE_VERSION, conf, keys,
                     lambda out_dir: build(conf, images_dir, names, masks_dir, out_dir))


def build(conf: SfMConfig, images_dir: Path, names: list[str], masks_dir: Optional[Path], out_dir: Path) -> dict:
    """Run SfM into the empty `out_dir` (see module doc for contents); returns quality.json's record."""
    q = SfMQuality(num_frames=len(names), images_dir=os.path.relpath(images_dir.resolve(), out_dir.resolve()))
    if len(names) < conf.min_frames:
        raise fail(out_dir, q, "too_few_frames",
                   f"{images_dir} has {len(names)} frames, need >= {conf.min_frames}")
    cam = choose_camera(conf, images_dir, names[0])
    masks = colmap_masks(masks_dir, names, out_dir)
    db = out_dir / "database.db"
    with Timer() as t:
        extract(conf, db, images_dir, names, masks, cam)
    q.seconds["extract"] = t.seconds
    with Timer() as t:
        match(conf, db)
    q.seconds["match"] = t.seconds
    q.median_flow_px = median_flow_px(db)
    if q.median_flow_px < conf.static_max_flow_px:
        raise fail(out_dir, q, "static_camera",
                   f"median feature motion {q.median_flow_px:.2f} px: the camera does not move")
    with Timer() as t:
        rec, used = run_mapper(conf, db, images_dir, out_dir / "mapping", len(names))
    q.seconds["map"] = t.seconds
    if rec is None:
        raise fail(out_dir, q, "too_few_registered", f"no model could be built from {images_dir}")
    q = dataclasses.replace(measure(rec, len(names)), seconds=q.seconds, mapper=used,
                            median_flow_px=q.median_flow_px, images_dir=q.images_dir)
    check_quality(conf, out_dir, q)
    with Timer() as t:
        write_outputs(out_dir, images_dir, masks, rec, conf)
    shutil.rmtree(out_dir / "mapping", ignore_errors=True)
    q.seconds["export"] = t.seconds
    (out_dir / OUTPUTS.quality).write_text(json.dumps(to_jsonable(q), indent=2))
    return to_jsonable(q)


def check_quality(conf: SfMConfig, out_dir: Path, q: SfMQuality) -> None:
    if q.registered_fraction < conf.min_registered_fraction:
        raise fail(out_dir, q, "too_few_registered",
                   f"{q.num_registered}/{q.num_frames} frames registered "
                   f"(< {conf.min_registered_fraction:.0%})")
    if q.median_tri_angle_deg < conf.static_min_tri_angle_deg:
        raise fail(out_dir, q, "static_camera",
                   f"median triangulation angle {q.median_tri_angle_deg:.3f} deg: no parallax")


def load_quality(sfm_dir: Path) -> dict:
    return json.loads((Path(sfm_dir) / OUTPUTS.quality).read_text())
