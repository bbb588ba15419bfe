"""Small test media for the ingest tests, written with PyAV (no downloaded data)."""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Optional

import cv2
import numpy as np


def texture(h: int, w: int, seed: int = 0) -> np.ndarray:
    """Multi-scale random texture, BGR uint8 [h, w, 3] (good for flow and sharpness)."""
    rng = np.random.default_rng(seed)
    img = np.zeros((h, w, 3), np.float32)
    for s in (4, 16, 64):
        noise = rng.random((max(2, h // s), max(2, w // s), 3)).astype(np.float32)
        img += cv2.resize(noise, (w, h), interpolation=cv2.INTER_CUBIC)
    img = (img - img.min()) / (img.max() - img.min())
    return (img * 255).astype(np.uint8)


def panning_frames(n: int, h: int = 120, w: int = 160, speed: float = 2.0, seed: int = 0,
                   obj: Optional[dict] = None) -> list[np.ndarray]:
    """A camera panning over a textured wall at `speed` px/frame; `obj` = {size, vx, vy, x, y}
    adds a textured square moving on its own (ground truth boxes via `object_box`)."""
    wall = texture(h + 40, w + int(speed * n) + 40, seed)
    sprite = texture(obj["size"], obj["size"], seed + 1)[:, :, ::-1].copy() if obj else None
    frames = []
    for i in range(n):
        x0 = int(round(20 + speed * i))
        f = wall[20:20 + h, x0:x0 + w].copy()
        if obj:
            x, y = object_box(obj, i)[:2]
            f[y:y + obj["size"], x:x + obj["size"]] = sprite
        frames.append(f)
    return frames


def object_box(obj: dict, i: int) -> tuple[int, int, int, int]:
    x, y = int(round(obj["x"] + obj["vx"] * i)), int(round(obj["y"] + obj["vy"] * i))
    return x, y, x + obj["size"], y + obj["size"]


def write_video(path: Path, frames: list[np.ndarray], fps: int = 30, codec: str = "libx264") -> Path:
    """Write BGR frames as an mp4 (PyAV). An empty list gives what a recorder writes for an
    empty recording (OpenCV's VideoWriter: an mp4 container without a video frame)."""
    import av

    if not frames:
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (160, 120))
        writer.release()
        return Path(path)
    h, w = (frames[0].shape[:2] if frames else (120, 160))
    with av.open(str(path), "w") as out:
        stream = out.add_stream(codec, rate=fps)
        stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
        stream.options = {"crf": "18", "preset": "ultrafast"} if codec == "libx264" else {}
        for f in frames:
            for pkt in stream.encode(av.VideoFrame.from_ndarray(f, format="bgr24")):
                out.mux(pkt)
        for pkt in stream.encode():
            out.mux(pkt)
    return Path(path)


def make_video(path: Path, n: int = 60, fps: int = 30, transform: Optional[Callable] = None, **kw) -> Path:
    frames = panning_frames(n, **kw)
    if transform:
        frames = [transform(i, f) for i, f in enumerate(frames)]
    return write_video(path, frames, fps)
