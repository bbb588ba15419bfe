"""`masks` stage: dynamic-object masks (moving people, vehicles) without downloaded weights.

Reads: a finished `decode` output (`images/*.jpg`, `stage.json`).
Writes into `out_dir`:
  masks/<image name>.png  uint8, 0 = dynamic/ignored, 255 = static (COLMAP's mask
                          convention: SfM passes this folder as its mask path; the mask of
                          `000001.jpg` is `000001.jpg.png`)
  masks.parquet           per frame: image, dynamic_fraction, model (F | H), components,
                          people_boxes, segments, reliable
  stage.json              done-marker with a summary, written by the runner (runtime/runner.py)

Method (per frame t, on a grey copy `analysis_width` wide):
 1. dense DIS optical flow to t-1 and t+1 and back (forward-backward check: flow that does
    not round-trip within `fb_px`, or lies on untextured pixels, is ignored, not "dynamic");
 2. RANSAC fundamental matrix and homography on the reliable flow; the homography is used
    when it explains the flow as well as F (rotation / little parallax: F is degenerate),
    otherwise F. Pixels whose flow disagrees with that geometry (Sampson / transfer error
    above max(residual_px, residual_rel x the frame median)) move on their own;
 3. temporal consistency: the evidence of t-1 and t+1 is warped into t along the flow and
    a pixel is dynamic when the majority of the (up to 3) votes says so; then an opening,
    removal of blobs smaller than `min_area`, and a dilation by `dilate_px`;
 4. optional object detectors that only ADD objects that also move: OpenCV's HOG people
    detector when the OpenCV build has it (OpenCV 5's main wheel does not: recorded as
    "off"), and a learned segmenter plug-in (`Segmenter`, e.g. a TorchScript file from a
    local path): a segment is masked when >= `segment_min_motion` of it moves.
A frame whose dynamic fraction exceeds `max_dynamic` is treated as a geometry failure: its
motion mask is discarded (only detector masks remain) and it is marked unreliable.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Protocol, Sequence

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from vid2sim.factory.ingest.decode import kept_images
from vid2sim.factory.runtime.stage_cache import StageError, StageWork, finished_key
from vid2sim.ranges import checked

STAGE = "masks"
STAGE_VERSION = 1  # bump when this stage's outputs change for the same inputs

@dataclass(frozen=True)
class MasksOutputs:
    """This stage's output artifacts, as paths relative to its stage folder (the stage contract)."""

    masks: str = "masks"  # <image>.png, 0 = dynamic (COLMAP)
    table: str = "masks.parquet"


OUTPUTS = MasksOutputs()



@checked
@dataclass(frozen=True)
class MasksConfig:
    analysis_width: int = 424  # flow resolution (px); masks are upsampled to the image size
    residual_px: float = 1.0  # epipolar / transfer error (analysis px) that counts as motion
    residual_rel: float = 4.0  # ... and at least this multiple of the frame's median error
    fb_px: float = 1.0  # forward-backward round-trip tolerance (analysis px)
    min_texture: float = 1e-4  # min eigenvalue of the structure tensor (grey in [0, 1])
    min_area: float = 0.001  # drop dynamic blobs smaller than this fraction of the image
    dilate_px: int = 7  # grow masks by this many output pixels
    max_dynamic: float = 0.5  # above this fraction the motion mask is discarded (unreliable)
    people: str = "auto"  # "auto" (HOG if the OpenCV build has it) | "hog" | "off"
    people_min_motion: float = 0.05  # a HOG box is masked when this fraction of it moves
    segmenter_path: Optional[str] = None  # TorchScript learned segmenter (local file)
    segmenter_classes: tuple[int, ...] = (1,)  # output classes that are people / vehicles
    segment_min_motion: float = 0.1  # a segment is masked when this fraction of it moves


class Segmenter(Protocol):
    """Plug-in: BGR image [H, W, 3] uint8 -> bool [H, W], True on people / vehicles."""

    def __call__(self, bgr: np.ndarray) -> np.ndarray: ...


class TorchScriptSegmenter:
    """A learned segmenter from a local TorchScript file.

    The module takes a float tensor [1, 3, H, W] (RGB in [0, 1]) and returns either logits
    [1, C, H, W] (argmax is taken) or labels [1, H, W]; pixels whose class is in `classes`
    are people / vehicles.
    """

    def __init__(self, path: str, classes: Sequence[int]) -> None:
        import torch

        if not Path(path).is_file():
            raise StageError(STAGE, "missing_segmenter", f"{path}: no such model file")
        self._torch, self.classes = torch, list(classes)
        self.model = torch.jit.load(str(path), map_location="cpu").eval()

    def __call__(self, bgr: np.ndarray) -> np.ndarray:
        torch = self._torch
        x = torch.from_numpy(np.ascontiguousarray(bgr[:, :, ::-1])).permute(2, 0, 1)[None].float() / 255.0
        with torch.no_grad():
            y = self.model(x)
        labels = y.argmax(1)[0] if y.dim() == 4 else y[0]
        return np.isin(labels.cpu().numpy(), self.classes)


class HogPeople:
    """OpenCV's default HOG people detector (only in builds that still ship it)."""

    def __init__(self) -> None:
        self.hog = cv2.HOGDescriptor()
        self.hog.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())

    def __call__(self, bgr: np.ndarray) -> np.ndarray:  # [K, 4] x0, y0, x1, y1
        boxes, _ = self.hog.detectMultiScale(bgr, winStride=(8, 8), padding=(8, 8), scale=1.05)
        b = np.asarray(boxes, np.float64).reshape(-1, 4)
        return np.c_[b[:, :2], b[:, :2] + b[:, 2:]]


def hog_available() -> bool:
    return hasattr(cv2, "HOGDescriptor") and hasattr(cv2, "HOGDescriptor_getDefaultPeopleDetector")


# --------------------------------------------------------------------------- motion evidence
def _grey(img: np.ndarray, width: int) -> np.ndarray:
    g = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    h, w = g.shape
    if w > width:
        g = cv2.resize(g, (width, int(round(h * width / w))), interpolation=cv2.INTER_AREA)
    return g


def _warp(img: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Sample `img` (frame j) at x + flow(x) (flow from frame i to j) -> image in frame i."""
    h, w = flow.shape[:2]
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return cv2.remap(img, gx + flow[..., 0], gy + flow[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _apply(M: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows of M applied to homogeneous pixel grids (x, y, 1): three arrays like x."""
    M = M.astype(np.float32)
    return tuple(M[r, 0] * x + M[r, 1] * y + M[r, 2] for r in range(3))


def sampson(F: np.ndarray, x: np.ndarray, y: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Sampson distance (px) of correspondences (x, y) -> (u, v) to the fundamental matrix F."""
    a, b, c = _apply(F, x, y)  # epipolar line in image 2
    at, bt, _ = _apply(F.T, u, v)  # epipolar line in image 1
    num = (a * u + b * v + c) ** 2
    return np.sqrt(num / np.maximum(a * a + b * b + at * at + bt * bt, 1e-12))


def transfer(H: np.ndarray, x: np.ndarray, y: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Distance (px) between H (x, y) and (u, v)."""
    p, q, r = _apply(H, x, y)
    r = np.where(np.abs(r) < 1e-6, 1e-6, r)
    return np.hypot(p / r - u, q / r - v)


def pair_residual(flow: np.ndarray, reliable: np.ndarray, conf: MasksConfig) -> tuple[np.ndarray, str]:
    """Per-pixel disagreement [h, w] of `flow` with the dominant camera geometry, and the model."""
    h, w = flow.shape[:2]
    x, y = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))  # [h, w]
    u, v = x + flow[..., 0], y + flow[..., 1]
    sub = reliable[::6, ::6]
    if sub.sum() < 30:
        return np.zeros((h, w), np.float32), "none"
    a = np.stack([x[::6, ::6][sub], y[::6, ::6][sub]], 1)  # [N, 2]
    b = np.stack([u[::6, ::6][sub], v[::6, ::6][sub]], 1)  # [N, 2]
    H, h_in = cv2.findHomography(a, b, cv2.RANSAC, 1.0)
    F, f_in = cv2.findFundamentalMat(a, b, cv2.FM_RANSAC, 0.5, 0.999)
    f_ok = F is not None and F.shape == (3, 3)
    if H is not None and (not f_ok or h_in.sum() >= 0.95 * f_in.sum()):
        return transfer(H, x, y, u, v), "H"
    if not f_ok:
        return np.zeros((h, w), np.float32), "none"
    return sampson(F, x, y, u, v), "F"


def _texture(grey: np.ndarray, conf: MasksConfig) -> np.ndarray:
    return cv2.cornerMinEigenVal(grey.astype(np.float32) / 255.0, 5, 3) > conf.min_texture


def motion_evidence(greys: list[np.ndarray], conf: MasksConfig) -> tuple[list[np.ndarray], list[dict], list[str]]:
    """Per frame: evidence in [0, 1] [h, w] (fraction of neighbour pairs that flag a pixel),
    flows to the neighbours {-1: flow, +1: flow} and the geometry model used."""
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    n = len(greys)
    flows: list[dict] = [{} for _ in range(n)]
    for i in range(n - 1):
        flows[i][+1] = dis.calc(greys[i], greys[i + 1], None)
        flows[i + 1][-1] = dis.calc(greys[i + 1], greys[i], None)
    textured = [_texture(g, conf) for g in greys]
    evidence, models = [], []
    for i in range(n):
        votes, used = [], []
        for d, f in flows[i].items():
            back = _warp(flows[i + d][-d], f)  # flow j->i sampled at x + f(x)
            reliable = (np.linalg.norm(f + back, axis=2) < conf.fb_px) & textured[i]
            res, model = pair_residual(f, reliable, conf)
            med = float(np.median(res[reliable])) if reliable.any() else 0.0
            votes.append(reliable & (res > max(conf.residual_px, conf.residual_rel * med)))
            used.append(model)
        evidence.append(np.mean(votes, axis=0) if votes else np.zeros(greys[i].shape))
        models.append("/".join(used))
    return evidence, flows, models


def temporal_majority(evidence: list[np.ndarray], flows: list[dict]) -> list[np.ndarray]:
    """Dynamic where most of {t-1, t, t+1} (warped into t along the flow) agree."""
    out = []
    for i, e in enumerate(evidence):
        votes = [e] + [_warp(evidence[i + d].astype(np.float32), f) for d, f in flows[i].items()]
        out.append(np.mean(votes, axis=0) > 0.5 - 1e-6 if len(votes) > 1 else e >= 0.5)
    return out


def clean(mask: np.ndarray, conf: MasksConfig) -> np.ndarray:
    """Opening + removal of blobs smaller than `min_area` (bool [h, w])."""
    m = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    keep = np.zeros(n, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= conf.min_area * m.size
    return keep[labels]


# --------------------------------------------------------------------------- detectors
def moving_segments(seg: np.ndarray, moving: np.ndarray, min_motion: float) -> np.ndarray:
    """Connected segments of `seg` (bool [H, W]) of which >= min_motion is `moving`."""
    n, labels = cv2.connectedComponents(seg.astype(np.uint8), connectivity=8)
    if n <= 1:
        return np.zeros_like(seg, bool)
    area = np.bincount(labels.ravel(), minlength=n)
    hit = np.bincount(labels.ravel(), weights=moving.ravel().astype(np.float64), minlength=n)
    keep = hit / np.maximum(area, 1) >= min_motion
    keep[0] = False
    return keep[labels]


def moving_boxes(boxes: np.ndarray, moving: np.ndarray, min_motion: float) -> np.ndarray:
    """Union of boxes [K, 4] of which >= min_motion is `moving` (bool [H, W])."""
    out = np.zeros_like(moving, bool)
    h, w = moving.shape
    for x0, y0, x1, y1 in np.asarray(boxes).reshape(-1, 4).astype(int):
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
        if x1 > x0 and y1 > y0 and moving[y0:y1, x0:x1].mean() >= min_motion:
            out[y0:y1, x0:x1] = True
    return out


def _people_detector(conf: MasksConfig) -> Optional[HogPeople]:
    if conf.people == "off" or (conf.people == "auto" and not hog_available()):
        return None
    if not hog_available():
        raise StageError(STAGE, "no_people_detector", f"OpenCV {cv2.__version__} has no HOGDescriptor")
    return HogPeople()


# --------------------------------------------------------------------------- stage
def compute_masks(images: list[np.ndarray], conf: MasksConfig, segmenter: Optional[Segmenter] = None,
                  ) -> tuple[list[np.ndarray], list[dict]]:
    """BGR images -> dynamic masks (bool [H, W], True = dynamic) and per-frame facts."""
    H, W = images[0].shape[:2]
    greys = [_grey(im, conf.analysis_width) for im in images]
    evidence, flows, models = motion_evidence(greys, conf)
    motion = temporal_majority(evidence, flows)
    people = _people_detector(conf)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * conf.dilate_px + 1,) * 2)
    masks, facts = [], []
    for img, m, model in zip(images, motion, models):
        m = clean(m, conf)
        reliable = m.mean() <= conf.max_dynamic
        moving = cv2.resize(m.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST).astype(bool)
        dyn = moving.copy() if reliable else np.zeros((H, W), bool)
        n_boxes = n_seg = 0
        if people is not None:
            boxes = people(img)
            add = moving_boxes(boxes, moving, conf.people_min_motion)
            dyn |= add
            n_boxes = len(boxes)
        if segmenter is not None:
            seg = moving_segments(np.asarray(segmenter(img), bool), moving, conf.segment_min_motion)
            dyn |= seg
            n_seg = int(cv2.connectedComponents(seg.astype(np.uint8))[0] - 1)
        if conf.dilate_px > 0 and dyn.any():
            dyn = cv2.dilate(dyn.astype(np.uint8), kernel).astype(bool)
        n_comp = int(cv2.connectedComponents(dyn.astype(np.uint8))[0] - 1)
        masks.append(dyn)
        facts.append({"dynamic_fraction": float(dyn.mean()), "model": model, "components": n_comp,
                      "people_boxes": n_boxes, "segments": n_seg, "reliable": bool(reliable)})
    return masks, facts


def load_segmenter(conf: MasksConfig) -> Optional[Segmenter]:
    return TorchScriptSegmenter(conf.segmenter_path, conf.segmenter_classes) if conf.segmenter_path else None


def work(conf: MasksConfig, decode_dir: Path, segmenter: Optional[Segmenter] = None) -> StageWork:
    """Masks of every frame of a finished decode output: keyed by the config, the decode key
    and the segmenter."""
    decode_dir = Path(decode_dir)
    decode_key = finished_key(decode_dir, STAGE, f"{decode_dir}: no finished decode output (stage.json)")
    files = kept_images(decode_dir)
    if len(files) < 2:
        raise StageError(STAGE, "too_few_frames", f"{decode_dir}: {len(files)} images")
    seg_id = conf.segmenter_path or (type(segmenter).__name__ if segmenter is not None else None)
    return StageWork(STAGE, STAGE_VERSION, conf, (decode_key, seg_id),
                     lambda out_dir: build(conf, files, out_dir, segmenter, seg_id))


def build(conf: MasksConfig, files: list[Path], out_dir: Path, segmenter: Optional[Segmenter],
          seg_id: Optional[str]) -> dict:
    """Write `masks/<image>.png` and `masks.parquet` for `files` into the empty `out_dir`;
    returns the summary."""
    segmenter = segmenter or load_segmenter(conf)
    images = [cv2.imread(str(p), cv2.IMREAD_COLOR) for p in files]
    masks, facts = compute_masks(images, conf, segmenter)
    (out_dir / OUTPUTS.masks).mkdir()
    for p, m in zip(files, masks):
        cv2.imwrite(str(out_dir / OUTPUTS.masks / f"{p.name}.png"), np.where(m, 0, 255).astype(np.uint8))
    table = pa.Table.from_pylist([{"image": p.name, **f} for p, f in zip(files, facts)])
    pq.write_table(table, out_dir / OUTPUTS.table)
    frac = np.array([f["dynamic_fraction"] for f in facts])
    return {"frames": len(files), "mean_dynamic": float(frac.mean()), "max_dynamic": float(frac.max()),
            "frames_with_dynamic": int((frac > 0).sum()),
            "unreliable": int(sum(not f["reliable"] for f in facts)),
            "people_detector": "hog" if _people_detector(conf) else "off", "segmenter": seg_id}
