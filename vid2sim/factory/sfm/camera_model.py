"""Lens -> COLMAP camera model choice (and an initial focal length).

Reads: the first image of a clip (size, EXIF make/model/focal) and optional user hints.
Writes nothing. Wide action cameras (GoPro, DJI Osmo Action, Insta360, ...; or any lens
with a known horizontal FOV above ~100 degrees) get OPENCV_FISHEYE / OPENCV; ordinary
phone and camera lenses get OPENCV (or SIMPLE_RADIAL for short, low-texture clips).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from vid2sim.factory.ingest import lens_tags

MODELS = ("OPENCV", "OPENCV_FISHEYE", "SIMPLE_RADIAL", "RADIAL", "PINHOLE", "SIMPLE_PINHOLE")
WIDE_MAKERS = ("gopro", "insta360", "dji", "akaso", "sjcam", "yi ", "garmin virb")
WIDE_FOV_DEG = 100.0
FISHEYE_FOV_DEG = 140.0


@dataclass
class LensHint:
    """What is known about the lens; every field optional."""

    make: str = ""  # EXIF / container make, e.g. "GoPro"
    model: str = ""  # e.g. "GoPro Max"
    hfov_deg: Optional[float] = None  # known horizontal field of view
    focal_px: Optional[float] = None  # known focal length in pixels (at the image size)
    wide: Optional[bool] = None  # user hint: wide action-camera lens


@dataclass
class CameraChoice:
    model: str  # COLMAP model name
    params: list[float] = field(default_factory=list)  # initial params ([] = COLMAP default)
    reason: str = ""


def is_wide(hint: LensHint) -> bool:
    """A wide action-camera lens: user hint, maker, or known FOV > ~100 degrees."""
    if hint.wide is not None:
        return hint.wide
    name = f"{hint.make} {hint.model}".lower()
    if any(m.strip() in name for m in WIDE_MAKERS if m.strip()):
        return True
    return hint.hfov_deg is not None and hint.hfov_deg > WIDE_FOV_DEG


def focal_from_fov(width: int, hfov_deg: float) -> float:
    """Pinhole focal in pixels giving `hfov_deg` over `width` pixels."""
    return 0.5 * width / math.tan(math.radians(min(hfov_deg, 170.0)) / 2)


def exif_hint(image: Path) -> LensHint:
    """Make, model and a pixel focal from an image's EXIF (35 mm equivalent), when present: the
    tags the decode stage keeps in its frames (ingest/lens_tags.py)."""
    tags = lens_tags.from_image(image)
    hint = LensHint(make=tags.make, model=tags.model)
    if tags.focal_35mm:
        from PIL import Image

        with Image.open(image) as im:
            width = im.size[0]
        hint.focal_px = tags.focal_35mm / 36.0 * width  # 36 mm = full-frame width
        hint.hfov_deg = math.degrees(2 * math.atan(18.0 / tags.focal_35mm))
    return hint


def initial_params(model: str, width: int, height: int, focal: float) -> list[float]:
    """COLMAP params with the given focal, centred principal point, zero distortion."""
    cx, cy = width / 2.0, height / 2.0
    return {
        "SIMPLE_PINHOLE": [focal, cx, cy],
        "PINHOLE": [focal, focal, cx, cy],
        "SIMPLE_RADIAL": [focal, cx, cy, 0.0],
        "RADIAL": [focal, cx, cy, 0.0, 0.0],
        "OPENCV": [focal, focal, cx, cy, 0.0, 0.0, 0.0, 0.0],
        "OPENCV_FISHEYE": [focal, focal, cx, cy, 0.0, 0.0, 0.0, 0.0],
    }[model]


def choose_camera_model(width: int, height: int, hint: Optional[LensHint] = None,
                        requested: str = "auto") -> CameraChoice:
    """Camera model for a clip of `width` x `height` frames.

    `requested` other than "auto" is honoured as is (with a focal prior when one is known).
    Wide lenses: FOV >= ~140 degrees -> OPENCV_FISHEYE, else OPENCV (its k1..p2 absorb the
    barrel distortion of a GoPro-style linearised/hero mode well). Normal lenses -> OPENCV.
    """
    hint = hint or LensHint()
    focal = hint.focal_px
    if focal is None and hint.hfov_deg is not None:
        focal = focal_from_fov(width, hint.hfov_deg)
    if requested != "auto":
        if requested not in MODELS:
            raise ValueError(f"camera model {requested!r} is not one of {MODELS}")
        params = initial_params(requested, width, height, focal) if focal else []
        return CameraChoice(requested, params, "requested")
    if is_wide(hint):
        fov = hint.hfov_deg or 0.0
        model = "OPENCV_FISHEYE" if fov >= FISHEYE_FOV_DEG else "OPENCV"
        if focal is None:
            focal = 0.5 * width  # ~ 90-120 deg after distortion: a sane start for action cams
        return CameraChoice(model, initial_params(model, width, height, focal),
                            f"wide lens ({hint.make} {hint.model} fov={hint.hfov_deg})".strip())
    params = initial_params("OPENCV", width, height, focal) if focal else []
    return CameraChoice("OPENCV", params, "normal lens" + (" (EXIF focal)" if focal else ""))
