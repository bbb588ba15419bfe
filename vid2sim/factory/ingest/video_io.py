"""Video reading with PyAV: probe a file and stream its frames, with named failures.

Failure reasons (StageError, stage "decode"):
  not_a_video     the file has no known container signature and cannot be opened
  truncated       a container signature is there but opening/decoding breaks, or far fewer
                  frames decode than the container declares (a cut-off file)
  zero_frames     the container holds no video frame (no video track, as muxers write
                  for an empty recording, or a track that decodes to nothing)
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Iterator, Optional

import numpy as np

from vid2sim.factory.runtime.stage_cache import StageError

STAGE = "decode"


@dataclass(frozen=True)
class VideoInfo:
    path: Path
    fps: float
    width: int
    height: int
    duration: float  # seconds (container or stream metadata; 0 when unknown)
    n_frames: int  # declared frame count (0 when unknown)
    codec: str


def has_container_signature(path: Path) -> bool:
    """True when the first bytes look like MP4/MOV, AVI, Matroska/WebM, MPEG-TS or MPEG-PS."""
    with open(path, "rb") as f:
        head = f.read(16)
    return (head[4:8] in (b"ftyp", b"moov", b"mdat", b"free", b"wide", b"skip")
            or head[:4] == b"RIFF" or head[:4] == b"\x1aE\xdf\xa3"
            or head[:1] == b"\x47" or head[:4] == b"\x00\x00\x01\xba")


def _open(path: Path):
    import av

    try:
        container = av.open(str(path))
    except (av.error.FFmpegError, OSError, ValueError) as e:
        reason = "truncated" if has_container_signature(path) else "not_a_video"
        raise StageError(STAGE, reason, f"{path}: {type(e).__name__}: {e}") from None
    if not container.streams.video:
        container.close()
        raise StageError(STAGE, "zero_frames", f"{path}: the container has no video track (no frame)")
    return container


def probe_video(path: Path) -> VideoInfo:
    """Read container metadata (no decoding)."""
    container = _open(Path(path))
    try:
        s = container.streams.video[0]
        rate = s.average_rate or s.guessed_rate or Fraction(30)
        duration = 0.0
        if s.duration is not None and s.time_base is not None:
            duration = float(s.duration * s.time_base)
        elif container.duration:
            duration = container.duration / 1e6
        n = int(s.frames or 0) or int(round(duration * float(rate)))
        return VideoInfo(Path(path), float(rate), s.codec_context.width, s.codec_context.height,
                         duration, n, s.codec_context.name)
    finally:
        container.close()


def iter_frames(path: Path, start: float = 0.0, end: Optional[float] = None) -> Iterator[tuple[int, float, np.ndarray]]:
    """Yield (source frame index, timestamp s, BGR uint8 [H, W, 3]) in [start, end).

    Decodes sequentially from the beginning (exact frame indices); raises `truncated`
    when decoding breaks part-way and `zero_frames` when nothing decodes.
    """
    import av

    container = _open(Path(path))
    n = 0
    try:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        rate = float(stream.average_rate or stream.guessed_rate or 30)
        try:
            for i, frame in enumerate(container.decode(stream)):
                n += 1
                t = float(frame.time) if frame.time is not None else i / rate
                if t < start - 1e-6:
                    continue
                if end is not None and t >= end - 1e-6:
                    break
                yield i, t, frame.to_ndarray(format="bgr24")
        except (av.error.FFmpegError, ValueError) as e:
            raise StageError(STAGE, "truncated", f"{path}: decoding failed after {n} frames: {e}") from None
    finally:
        container.close()
    if n == 0:
        raise StageError(STAGE, "zero_frames", f"{path}: the video track decodes to no frame")


def check_complete(path: Path, info: VideoInfo, decoded: int, min_ratio: float = 0.9) -> None:
    """Raise `truncated` when far fewer frames decoded than the container declares."""
    if info.n_frames >= 10 and decoded < min_ratio * info.n_frames:
        raise StageError(STAGE, "truncated",
                         f"{path}: decoded {decoded} of {info.n_frames} declared frames")
