"""`decode` stage: a source (video window or image folder) -> anonymised, filtered frames.

Reads: a `Source` (see sources.py) and an optional window (start, end) in seconds.
Writes into `out_dir`:
  images/NNNNNN.jpg  kept frames, resized so the long side <= max_side, faces and plates blurred
                     IN MEMORY before the write (raw frames never touch the disk); EXIF with the
                     camera's make, model and 35 mm focal length only, where the source states
                     them (lens_tags.py: the sfm stage starts its camera from them)
  frames.parquet     one row per sampled frame: index (output index, null if dropped),
                     image, source_frame, timestamp, sharpness, motion, level, kept,
                     reason (null | black | blur | duplicate), faces, plates
  clip.json          source uri + sha256, window, source fps/size, sample fps, size,
                     counts, anonymiser (detectors and settings), lens tags, config
  stage.json         the done-marker, written by the runner (runtime/runner.py)

Filters (defaults, see DecodeConfig):
  sampling   10 fps (the paper uses 30 fps x 15 s = 450 frames; 10 fps keeps 1/3 of the
             frames, enough overlap for SfM at walking speed and 3x cheaper on CPU)
  blur       variance of the Laplacian below 0.35 x the clip median (relative, so it
             adapts to scene texture and resolution instead of an absolute number)
  duplicate  median optical-flow magnitude to the last KEPT frame below 0.6 px (at the
             output size): a frame that adds no motion. If >= 90 % of frames are duplicates
             the clip fails with `static_camera`.
Input errors (StageError "decode", nothing written): not_a_video, truncated, zero_frames,
not_an_image, empty_window, too_few_frames (< min_frames sampled or kept), all_black,
static_camera, plus the source reasons of sources.py.
"""

from __future__ import annotations

import json
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional, Union

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from vid2sim.factory.ingest import lens_tags
from vid2sim.factory.ingest.lens_tags import LensTags
from vid2sim.factory.ingest.privacy import Anonymiser, FaceConfig, PlateConfig
from vid2sim.factory.ingest.sources import Source, resolve_source
from vid2sim.factory.runtime.stage_cache import StageError, StageWork
from vid2sim.factory.ingest.video_io import check_complete, iter_frames, probe_video
from vid2sim.ranges import checked
from vid2sim.versioning import to_jsonable

STAGE = "decode"
STAGE_VERSION = 2  # bump when this stage's outputs change for the same inputs (2: lens EXIF)

@dataclass(frozen=True)
class DecodeOutputs:
    """This stage's output artifacts, as paths relative to its stage folder (the stage contract)."""

    images: str = "images"  # NNNNNN.jpg, faces and plates blurred
    frames: str = "frames.parquet"  # one row per sampled frame
    clip: str = "clip.json"


OUTPUTS = DecodeOutputs()



@checked
@dataclass(frozen=True)
class DecodeConfig:
    fps: float = 10.0  # target sampling rate; >= source fps keeps every frame
    max_side: int = 1024  # long side of written frames (never upscaled)
    blur_rel: float = 0.35  # drop if Laplacian variance < blur_rel * clip median
    dup_flow_px: float = 0.6  # drop if median flow to the last kept frame < this (output px)
    static_fraction: float = 0.9  # >= this fraction of duplicates -> static_camera
    min_frames: int = 10  # fewer frames sampled or kept fails the clip (too_few_frames)
    black_level: float = 10.0  # frame mean grey level (0..255) below which it is "black"
    black_fraction: float = 0.95  # >= this fraction of black frames -> all_black
    analysis_width: int = 320  # width of the grey copy used for optical flow
    jpeg_quality: int = 95  # JPEG quality (0-100) of the written frames
    image_fps: float = 1.0  # nominal rate for image-folder timestamps (index / image_fps)
    faces: FaceConfig = field(default_factory=FaceConfig)  # face detection and blurring (anonymisation)
    plates: PlateConfig = field(default_factory=PlateConfig)  # licence-plate detection and blurring
    workers: int = 2  # processes for anonymisation + JPEG writing (one detector thread each)


PRESETS = {
    "default": DecodeConfig(),  # the pipeline's `fast` preset
    "paper": DecodeConfig(fps=30.0, max_side=1920),  # 30 fps, as in the paper (pipeline `paper`)
}


def preset(name: str) -> DecodeConfig:
    """A named sampling preset (`default` 10 fps, `paper` 30 fps)."""
    if name not in PRESETS:
        raise ValueError(f"unknown decode preset {name!r}; choose one of {sorted(PRESETS)}")
    return PRESETS[name]


@dataclass
class Sample:
    source_frame: int
    timestamp: float
    image: np.ndarray  # [H, W, 3] uint8 BGR, resized
    sharpness: float = 0.0
    level: float = 0.0
    motion: float = float("nan")
    reason: Optional[str] = None  # None = kept
    lens: LensTags = LensTags()  # what the source says about its camera


# --------------------------------------------------------------------------- reading
def _resize(img: np.ndarray, max_side: int) -> np.ndarray:
    h, w = img.shape[:2]
    s = max_side / max(h, w)
    if s >= 1.0:
        return img
    return cv2.resize(img, (int(round(w * s)) // 2 * 2, int(round(h * s)) // 2 * 2), interpolation=cv2.INTER_AREA)


def sample_video(path: Path, conf: DecodeConfig, window: Optional[tuple[float, float]]) -> tuple[list[Sample], dict]:
    """Decode `path` and keep frames on a `conf.fps` time grid inside the window."""
    info = probe_video(path)
    start, end = (window or (0.0, None))
    step, half = 1.0 / conf.fps, 0.5 / max(info.fps, 1e-3)
    lens = lens_tags.from_video(path)
    samples, next_t, decoded = [], start, 0
    for idx, t, img in iter_frames(path, start, end):
        decoded += 1
        if t + half >= next_t:
            samples.append(Sample(idx, t, _resize(img, conf.max_side), lens=lens))
            while next_t <= t + half:
                next_t += step
    if not samples:
        raise StageError(STAGE, "empty_window", f"{path}: no frame in window {window} "
                         f"(duration {info.duration:.2f} s)")
    if end is None or (info.duration and end >= info.duration):
        check_complete(path, info, samples[-1].source_frame + 1)
    facts = {"source_fps": info.fps, "source_size": [info.width, info.height], "codec": info.codec,
             "source_frames": info.n_frames, "duration": info.duration, "decoded_in_window": decoded}
    return samples, facts


def sample_images(files: list[Path], conf: DecodeConfig) -> tuple[list[Sample], dict]:
    """Read an ordered image folder (every image is a sample; timestamps index / image_fps)."""
    samples, size = [], None
    for i, p in enumerate(files):
        img = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if img is None:
            raise StageError(STAGE, "not_an_image", f"{p}: cannot be read as an image")
        size = size or [img.shape[1], img.shape[0]]
        samples.append(Sample(i, i / conf.image_fps, _resize(img, conf.max_side),
                              lens=lens_tags.from_image(p)))
    return samples, {"source_fps": conf.image_fps, "source_size": size, "source_frames": len(files),
                     "timestamps": "nominal"}


# --------------------------------------------------------------------------- filtering
def _grey(img: np.ndarray, width: int) -> np.ndarray:
    g = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    h, w = g.shape
    return cv2.resize(g, (width, max(8, int(round(h * width / w)))), interpolation=cv2.INTER_AREA) if w > width else g


def sharpness(img: np.ndarray) -> float:
    """Variance of the Laplacian of the grey image (higher = sharper)."""
    return float(cv2.Laplacian(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), cv2.CV_32F).var())


def median_flow(a: np.ndarray, b: np.ndarray, dis: "cv2.DISOpticalFlow") -> float:
    """Median optical-flow magnitude between two grey images (pixels of `a`)."""
    flow = dis.calc(a, b, None)  # [h, w, 2]
    return float(np.median(np.linalg.norm(flow, axis=2)))


def filter_samples(samples: list[Sample], conf: DecodeConfig) -> dict:
    """Score every sample and set `reason` for dropped ones; raise on unusable clips."""
    n = len(samples)
    if n < conf.min_frames:
        raise StageError(STAGE, "too_few_frames", f"{n} frames sampled, need >= {conf.min_frames}")
    for s in samples:
        s.level = float(s.image.mean())
        s.sharpness = sharpness(s.image)
        s.reason = "black" if s.level < conf.black_level else None
    n_black = sum(s.reason == "black" for s in samples)
    if n_black >= conf.black_fraction * n:
        raise StageError(STAGE, "all_black", f"{n_black} of {n} frames have mean level < {conf.black_level}")
    med = float(np.median([s.sharpness for s in samples if s.reason is None]))
    for s in samples:
        if s.reason is None and s.sharpness < conf.blur_rel * med:
            s.reason = "blur"
    _mark_duplicates([s for s in samples if s.reason is None], conf)
    counts = {"sampled": n, "kept": sum(s.reason is None for s in samples), "dropped_black": n_black,
              "dropped_blur": sum(s.reason == "blur" for s in samples),
              "dropped_duplicate": sum(s.reason == "duplicate" for s in samples), "median_sharpness": med}
    candidates = counts["kept"] + counts["dropped_duplicate"]
    if counts["dropped_duplicate"] >= conf.static_fraction * max(candidates - 1, 1):
        raise StageError(STAGE, "static_camera",
                         f"{counts['dropped_duplicate']} of {candidates} frames show no motion "
                         f"(median flow < {conf.dup_flow_px} px)")
    if counts["kept"] < conf.min_frames:
        raise StageError(STAGE, "too_few_frames",
                         f"{counts['kept']} frames left after filtering {counts}, need >= {conf.min_frames}")
    return counts


def _mark_duplicates(sharp: list[Sample], conf: DecodeConfig) -> None:
    """Drop frames whose median flow to the last kept frame is below `dup_flow_px`."""
    if not sharp:
        return
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST)
    scale = sharp[0].image.shape[1] / min(conf.analysis_width, sharp[0].image.shape[1])
    last = _grey(sharp[0].image, conf.analysis_width)
    sharp[0].motion = 0.0
    for s in sharp[1:]:
        g = _grey(s.image, conf.analysis_width)
        s.motion = median_flow(last, g, dis) * scale
        if s.motion < conf.dup_flow_px:
            s.reason = "duplicate"
        else:
            last = g


# --------------------------------------------------------------------------- writing
def _frames_table(samples: list[Sample], found: dict[int, tuple[int, int]]) -> pa.Table:
    kept = [s.reason is None for s in samples]
    out_idx, k = [], 0
    for keep in kept:
        out_idx.append(k if keep else None)
        k += keep
    return pa.table({
        "index": pa.array(out_idx, pa.int32()),
        "image": pa.array([f"{i:06d}.jpg" if i is not None else None for i in out_idx], pa.string()),
        "source_frame": pa.array([s.source_frame for s in samples], pa.int64()),
        "timestamp": pa.array([s.timestamp for s in samples], pa.float64()),
        "sharpness": pa.array([s.sharpness for s in samples], pa.float64()),
        "motion": pa.array([None if np.isnan(s.motion) else s.motion for s in samples], pa.float64()),
        "level": pa.array([s.level for s in samples], pa.float64()),
        "kept": pa.array(kept, pa.bool_()),
        "reason": pa.array([s.reason for s in samples], pa.string()),
        "faces": pa.array([found.get(i, (0, 0))[0] for i in range(len(samples))], pa.int32()),
        "plates": pa.array([found.get(i, (0, 0))[1] for i in range(len(samples))], pa.int32()),
    })


_WORKER: dict = {}


def _init_worker(face_conf: FaceConfig, plate_conf: PlateConfig, quality: int) -> None:
    _WORKER["blur"], _WORKER["quality"] = Anonymiser(face_conf, plate_conf), quality


def _init_pool_worker(face_conf: FaceConfig, plate_conf: PlateConfig, quality: int) -> None:
    """A pool process: one OpenCV thread (the pool's processes are the parallelism), then the
    anonymiser."""
    cv2.setNumThreads(1)
    _init_worker(face_conf, plate_conf, quality)


def _blur_and_write(job: tuple[np.ndarray, str, bytes]) -> tuple[int, int]:
    """Worker: blur faces and plates in memory, then write the JPEG with the lens EXIF segment
    (b"": none); returns (faces, plates)."""
    img, path, exif = job
    img, faces, plates = _WORKER["blur"](img)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, _WORKER["quality"]])
    if not ok:
        raise OSError(f"cannot encode {path}")
    Path(path).write_bytes(lens_tags.with_exif(buf.tobytes(), exif))
    return len(faces), len(plates)


def _write(samples: list[Sample], conf: DecodeConfig, out_dir: Path) -> dict[int, tuple[int, int]]:
    """Anonymise in memory and write kept frames (in `conf.workers` processes); (faces, plates) per sample."""
    images = out_dir / OUTPUTS.images
    images.mkdir()
    kept = [i for i, s in enumerate(samples) if s.reason is None]
    segments: dict[LensTags, bytes] = {}
    jobs = [(samples[i].image, str(images / f"{k:06d}.jpg"),
             segments.setdefault(samples[i].lens, samples[i].lens.exif_segment()))
            for k, i in enumerate(kept)]
    if conf.workers <= 1 or len(jobs) < 32:  # a process pool costs ~1-2 s to start
        _init_worker(conf.faces, conf.plates, conf.jpeg_quality)
        counts = [_blur_and_write(j) for j in jobs]
    else:
        ctx = multiprocessing.get_context("spawn")
        init = (conf.faces, conf.plates, conf.jpeg_quality)
        with ProcessPoolExecutor(conf.workers, ctx, _init_pool_worker, init) as pool:
            counts = list(pool.map(_blur_and_write, jobs, chunksize=4))
    return dict(zip(kept, counts))


def work(conf: DecodeConfig, source: Union[Source, str, Path],
         window: Optional[tuple[float, float]] = None) -> StageWork:
    """Decoding one clip: keyed by the config (workers aside), the source's sha256 and the window."""
    src = source if isinstance(source, Source) else resolve_source(source)
    window = None if window is None else (float(window[0]), float(window[1]))
    return StageWork(STAGE, STAGE_VERSION, replace(conf, workers=1), (src.sha256, list(window) if window else None),
                     lambda out_dir: build(conf, src, window, out_dir))


def build(conf: DecodeConfig, src: Source, window: Optional[tuple[float, float]], out_dir: Path) -> dict:
    """Decode, filter, anonymise and write one clip into the empty `out_dir`; returns the summary."""
    blurrer = Anonymiser(conf.faces, conf.plates)  # fails early (nothing written) without a detector
    if src.kind == "video":
        samples, facts = sample_video(src.path, conf, window)
    else:
        samples, facts = sample_images(src.images(), conf)
    counts = filter_samples(samples, conf)
    found = _write(samples, conf, out_dir)
    pq.write_table(_frames_table(samples, found), out_dir / OUTPUTS.frames)
    kept = [s for s in samples if s.reason is None]
    h, w = kept[0].image.shape[:2]
    counts["faces_blurred"] = int(sum(f for f, _ in found.values()))
    counts["frames_with_faces"] = int(sum(f > 0 for f, _ in found.values()))
    counts["plates_blurred"] = int(sum(p for _, p in found.values()))
    clip = {"source": src.uri, "sha256": src.sha256, "kind": src.kind, "window": window,
            "sample_fps": conf.fps if src.kind == "video" else conf.image_fps, "size": [w, h],
            **facts, "counts": counts, **blurrer.record(), "lens": to_jsonable(kept[0].lens),
            "config": to_jsonable(conf)}
    (out_dir / OUTPUTS.clip).write_text(json.dumps(to_jsonable(clip), indent=2))
    summary = {k: counts[k] for k in ("sampled", "kept", "dropped_black", "dropped_blur", "dropped_duplicate",
                                      "faces_blurred", "plates_blurred")}
    return {**summary, "size": [w, h]}


def kept_images(out_dir: Path) -> list[Path]:
    """The written frames of a finished decode output, in order."""
    return sorted((Path(out_dir) / OUTPUTS.images).glob("*.jpg"))
