"""Face anonymisation applied in memory, before any frame is written to disk.

Detectors (all without downloading anything at run time):
  "dlib_hog"  dlib's built-in HOG + linear SVM frontal face detector (compiled into the
              `dlib-bin` pip wheel; no model file). The default.
  "cascade"   an OpenCV Haar/LBP cascade XML. OpenCV 5's main wheel has neither
              `cv2.CascadeClassifier` nor bundled XMLs (`cv2.data.haarcascades` is an
              empty folder), so this works only with OpenCV 4.x / contrib builds, or with a
              local `model_path` to a cascade XML.
  "yunet"     OpenCV's `cv2.FaceDetectorYN` with a local YuNet .onnx file (`model_path`):
              the plug-in for a stronger, learned detector.
  "none"      explicit opt-out (recorded in clip.json); never chosen silently.

`FaceBlurrer(conf)(img)` detects faces, blurs each padded box with a heavy Gaussian
blur over a pixelated copy, and returns (blurred image, boxes [K, 4] x0, y0, x1, y1).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Protocol

import cv2
import numpy as np

from vid2sim.factory.runtime.stage_cache import StageError


@dataclass(frozen=True)
class FaceConfig:
    detector: str = "dlib_hog"  # dlib_hog | cascade | yunet | none
    model_path: Optional[str] = None  # cascade XML or YuNet .onnx (local file)
    upsample: int = 1  # dlib: image pyramid up-sampling (1 finds faces >= ~40 px)
    score_threshold: float = 0.0  # dlib SVM margin; yunet confidence is 0.6 when left at 0
    pad: float = 0.3  # grow each box by this fraction on every side before blurring
    max_side: int = 960  # detect on a copy whose long side is at most this


class FaceDetector(Protocol):
    name: str

    def detect(self, bgr: np.ndarray) -> np.ndarray:  # [K, 4] float x0, y0, x1, y1
        ...


class DlibHogFaces:
    name = "dlib_hog"

    def __init__(self, conf: FaceConfig) -> None:
        try:
            import dlib
        except ImportError as e:
            raise StageError("privacy", "no_face_detector", "dlib is not installed (pip install dlib-bin)") from e
        self._det, self.conf = dlib.get_frontal_face_detector(), conf

    def detect(self, bgr: np.ndarray) -> np.ndarray:
        rgb = np.ascontiguousarray(bgr[:, :, ::-1])
        rects, scores, _ = self._det.run(rgb, self.conf.upsample, self.conf.score_threshold)
        return np.array([[r.left(), r.top(), r.right(), r.bottom()] for r in rects], np.float64).reshape(-1, 4)


class CascadeFaces:
    name = "cascade"

    def __init__(self, conf: FaceConfig) -> None:
        if not hasattr(cv2, "CascadeClassifier"):
            raise StageError("privacy", "no_face_detector",
                             f"OpenCV {cv2.__version__} has no CascadeClassifier (moved out of OpenCV 5 main)")
        cascades = Path(getattr(cv2.data, "haarcascades", ""))
        path = conf.model_path or str(cascades / "haarcascade_frontalface_default.xml")
        self._clf = cv2.CascadeClassifier(path)
        if self._clf.empty():
            raise StageError("privacy", "no_face_detector", f"cannot load cascade {path}")

    def detect(self, bgr: np.ndarray) -> np.ndarray:
        gray = cv2.equalizeHist(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))
        boxes = self._clf.detectMultiScale(gray, 1.1, 4, minSize=(16, 16))
        b = np.asarray(boxes, np.float64).reshape(-1, 4)
        return np.c_[b[:, :2], b[:, :2] + b[:, 2:]]


class YuNetFaces:
    name = "yunet"

    def __init__(self, conf: FaceConfig) -> None:
        if not conf.model_path or not Path(conf.model_path).is_file():
            raise StageError("privacy", "no_face_detector",
                             f"yunet needs a local .onnx model_path, got {conf.model_path!r}")
        thr = conf.score_threshold or 0.6
        self._det = cv2.FaceDetectorYN.create(str(conf.model_path), "", (320, 320), thr, 0.3, 5000)

    def detect(self, bgr: np.ndarray) -> np.ndarray:
        h, w = bgr.shape[:2]
        self._det.setInputSize((w, h))
        _, faces = self._det.detect(bgr)
        if faces is None:
            return np.zeros((0, 4))
        b = faces[:, :4].astype(np.float64)
        return np.c_[b[:, :2], b[:, :2] + b[:, 2:]]


DETECTORS = {"dlib_hog": DlibHogFaces, "cascade": CascadeFaces, "yunet": YuNetFaces}


def make_detector(conf: FaceConfig) -> Optional[FaceDetector]:
    """The configured detector, or None for the explicit "none" opt-out."""
    if conf.detector == "none":
        return None
    if conf.detector not in DETECTORS:
        raise StageError("privacy", "no_face_detector", f"unknown detector {conf.detector!r}; one of {list(DETECTORS)}")
    return DETECTORS[conf.detector](conf)


def blur_boxes(bgr: np.ndarray, boxes: np.ndarray, pad: float = 0.3) -> np.ndarray:
    """Irreversibly blur padded boxes [K, 4] (pixelate, then Gaussian) in a copy of `bgr`."""
    out = bgr.copy()
    h, w = out.shape[:2]
    for x0, y0, x1, y1 in np.asarray(boxes, np.float64).reshape(-1, 4):
        px, py = pad * (x1 - x0), pad * (y1 - y0)
        a, b = int(max(0, x0 - px)), int(max(0, y0 - py))
        c, d = int(min(w, x1 + px)), int(min(h, y1 + py))
        if c - a < 2 or d - b < 2:
            continue
        roi = out[b:d, a:c]
        small = cv2.resize(roi, (max(1, (c - a) // 8), max(1, (d - b) // 8)), interpolation=cv2.INTER_AREA)
        roi = cv2.resize(small, (c - a, d - b), interpolation=cv2.INTER_LINEAR)
        k = max(3, ((min(c - a, d - b) // 2) | 1))
        out[b:d, a:c] = cv2.GaussianBlur(roi, (k, k), 0)
    return out


class FaceBlurrer:
    """Detect + blur; call on every frame before it is written."""

    def __init__(self, conf: FaceConfig = FaceConfig()) -> None:
        self.conf, self.detector = conf, make_detector(conf)
        self.name = "none" if self.detector is None else self.detector.name

    def __call__(self, bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.detector is None:
            return bgr, np.zeros((0, 4))
        h, w = bgr.shape[:2]
        s = min(1.0, self.conf.max_side / max(h, w))
        small = bgr if s == 1.0 else cv2.resize(bgr, (int(round(w * s)), int(round(h * s))),
                                                interpolation=cv2.INTER_AREA)
        boxes = self.detector.detect(small) / s  # [K, 4] full-resolution pixels
        return (blur_boxes(bgr, boxes, self.conf.pad) if len(boxes) else bgr), boxes
