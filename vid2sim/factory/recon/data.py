"""Read a PosedClip's frames into memory at the training resolution.

Reads: images (images_dir), dynamic masks (masks_dir, `<image>.png`, 0 = dynamic),
intrinsics and poses. Writes nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import cv2
import numpy as np

from vid2sim.factory.sfm.posed import PosedClip, PosedFrame
from vid2sim.factory.runtime.stage_cache import StageError

STAGE = "recon"
STAGE_VERSION = 2  # bump when this stage's outputs change for the same inputs


@dataclass(frozen=True)
class ReconOutputs:
    """Files of a finished recon folder, relative to it."""

    splats: str = "splats.ply"
    metrics: str = "metrics.json"


OUTPUTS = ReconOutputs()


@dataclass
class View:
    """One frame at the training resolution."""

    index: int
    name: str
    split: str
    image: np.ndarray  # [H, W, 3] float32 in [0, 1]
    mask: np.ndarray  # [H, W] bool, True = static (used by the losses)
    K: np.ndarray  # [3, 3] scaled to the training resolution
    cam_to_world: np.ndarray  # [4, 4] OpenCV axes

    @property
    def height(self) -> int:
        return int(self.image.shape[0])

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    @property
    def world_to_cam(self) -> np.ndarray:
        return np.linalg.inv(self.cam_to_world)


def target_size(width: int, height: int, max_width: int) -> tuple[int, int, float]:
    """(w, h, scale) so that w <= max_width (no upscaling)."""
    s = min(1.0, max_width / float(width)) if max_width > 0 else 1.0
    return max(1, int(round(width * s))), max(1, int(round(height * s))), s


def scale_K(K: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """Intrinsics for an image resized by (sx, sy); pixel centres at j + 0.5 (COLMAP)."""
    out = np.array(K, np.float64).copy()
    out[0, 0] *= sx
    out[0, 2] *= sx
    out[1, 1] *= sy
    out[1, 2] *= sy
    return out


def load_view(clip: PosedClip, frame: PosedFrame, max_width: int) -> View:
    path = clip.image_path(frame)
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise StageError(STAGE, "unreadable_image", f"{path} could not be read")
    h0, w0 = img.shape[:2]
    if (w0, h0) != (frame.width, frame.height):
        raise StageError(STAGE, "image_size_mismatch",
                         f"{path} is {w0}x{h0}, cameras.parquet says {frame.width}x{frame.height}")
    w, h, _ = target_size(w0, h0, max_width)
    img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA) if (w, h) != (w0, h0) else img
    mask = np.ones((h, w), bool)
    mpath: Optional[Path] = clip.mask_path(frame)
    if mpath is not None:
        m = cv2.imread(str(mpath), cv2.IMREAD_GRAYSCALE)
        if m is None:
            raise StageError(STAGE, "unreadable_mask", f"{mpath} could not be read")
        mask = cv2.resize(m, (w, h), interpolation=cv2.INTER_NEAREST) > 127
    rgb = cv2.cvtColor(img, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
    K = scale_K(frame.K, w / w0, h / h0)
    return View(frame.index, frame.image, frame.split, rgb, mask, K, np.asarray(frame.cam_to_world, np.float64))


def load_views(clip: PosedClip, max_width: int) -> list[View]:
    """Every frame of the clip (train and test) as a View."""
    if not clip.frames:
        raise StageError(STAGE, "empty_clip", "the PosedClip has no frames")
    return [load_view(clip, f, max_width) for f in clip.frames]


def scene_extent(views: list[View]) -> float:
    """3DGS 'cameras_extent': 1.1 x the largest camera distance from the mean centre."""
    centres = np.stack([v.cam_to_world[:3, 3] for v in views])
    radius = float(np.linalg.norm(centres - centres.mean(0), axis=1).max())
    return 1.1 * max(radius, 1e-3)


def downscale_view(view: View, scale: float) -> View:
    """The view at `scale` x its size (image INTER_AREA, mask nearest, K rescaled)."""
    h0, w0 = view.height, view.width
    w, h = max(1, int(round(w0 * scale))), max(1, int(round(h0 * scale)))
    if (w, h) == (w0, h0):
        return view
    img = cv2.resize(view.image, (w, h), interpolation=cv2.INTER_AREA)  # [h, w, 3]
    mask = cv2.resize(view.mask.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0  # [h, w]
    return View(view.index, view.name, view.split, img, mask, scale_K(view.K, w / w0, h / h0), view.cam_to_world)

