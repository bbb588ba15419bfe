"""Anonymisation applied in memory, before any frame is written to disk: faces and plates.

`Anonymiser(faces, plates)(img)` detects faces (see `face_detectors`: CenterFace by default)
and licence plates (see `plates`: rows of character-like blobs), blurs each padded box with a
heavy Gaussian blur over a pixelated copy, and returns (blurred image, face boxes [K, 4],
plate boxes [M, 4]), boxes as x0, y0, x1, y1 in full-resolution pixels. `record()` is what the
decode stage writes to clip.json; the configs themselves reach scene.json through the pipeline
config (`pipeline.config.decode.faces` / `.plates`).

Measured recall and cost per frame: benchmarks/privacy.py (docs/benchmarks/privacy.md).
"""

from __future__ import annotations

import cv2
import numpy as np

from vid2sim.factory.ingest.face_detectors import FaceConfig, make_detector
from vid2sim.factory.ingest.plates import PlateConfig, detect_plates
from vid2sim.factory.runtime.stage_cache import StageError

__all__ = ["Anonymiser", "FaceConfig", "PlateConfig", "blur_boxes", "blur_mask"]


def _padded(boxes: np.ndarray, pad: float, w: int, h: int) -> np.ndarray:
    """Boxes [K, 4] grown by `pad` of their size on every side, clipped, as ints."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    d = pad * np.c_[b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]]
    out = np.c_[b[:, :2] - d, b[:, 2:] + d]
    return np.clip(out, 0, [w, h, w, h]).astype(int)


def blur_mask(shape: tuple[int, int], boxes: np.ndarray, pad: float = 0.3) -> np.ndarray:
    """bool [H, W]: the pixels `blur_boxes` replaces."""
    h, w = shape
    m = np.zeros((h, w), bool)
    for a, b, c, d in _padded(boxes, pad, w, h):
        if c - a >= 2 and d - b >= 2:
            m[b:d, a:c] = True
    return m


def blur_boxes(bgr: np.ndarray, boxes: np.ndarray, pad: float = 0.3) -> np.ndarray:
    """Irreversibly blur padded boxes [K, 4] (pixelate, then Gaussian) in a copy of `bgr`."""
    out = bgr.copy()
    h, w = out.shape[:2]
    for a, b, c, d in _padded(boxes, pad, w, h):
        if c - a < 2 or d - b < 2:
            continue
        roi = out[b:d, a:c]
        small = cv2.resize(roi, (max(1, (c - a) // 8), max(1, (d - b) // 8)), interpolation=cv2.INTER_AREA)
        roi = cv2.resize(small, (c - a, d - b), interpolation=cv2.INTER_LINEAR)
        k = max(3, ((min(c - a, d - b) // 2) | 1))
        out[b:d, a:c] = cv2.GaussianBlur(roi, (k, k), 0)
    return out


class Anonymiser:
    """Detect faces and plates, blur them; call on every frame before it is written."""

    def __init__(self, faces: FaceConfig = FaceConfig(), plates: PlateConfig = PlateConfig()) -> None:
        if plates.detector not in ("text_rows", "none"):
            raise StageError("privacy", "no_plate_detector", f"unknown plate detector {plates.detector!r}")
        self.faces, self.plates, self.detector = faces, plates, make_detector(faces)
        self.name = "none" if self.detector is None else self.detector.name

    def record(self) -> dict:
        """The detectors and their settings, for clip.json."""
        return {"face_detector": self.name, "plate_detector": self.plates.detector,
                "faces": vars(self.faces), "plates": vars(self.plates)}

    def detect_faces(self, bgr: np.ndarray) -> np.ndarray:
        if self.detector is None:
            return np.zeros((0, 4))
        h, w = bgr.shape[:2]
        s = min(1.0, self.faces.max_side / max(h, w))
        small = bgr if s == 1.0 else cv2.resize(bgr, (int(round(w * s)), int(round(h * s))),
                                                interpolation=cv2.INTER_AREA)
        return self.detector.detect(small) / s

    def detect_plates(self, bgr: np.ndarray) -> np.ndarray:
        return np.zeros((0, 4)) if self.plates.detector == "none" else detect_plates(bgr, self.plates)

    def __call__(self, bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        faces, plates = self.detect_faces(bgr), self.detect_plates(bgr)
        out = blur_boxes(bgr, faces, self.faces.pad) if len(faces) else bgr
        out = blur_boxes(out, plates, self.plates.pad) if len(plates) else out
        return out, faces, plates
