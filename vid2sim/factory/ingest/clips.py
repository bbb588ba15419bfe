"""Clip planning: a manifest row -> one or more clips (time windows of one source).

A row with a window gives one clip. Without one, a video is cut into consecutive
clips of `clip_seconds` (default 15 s, as in the paper); a tail shorter than
`min_seconds` is merged into the previous clip (or kept alone when it is the only one).
An image folder is always one clip (no window).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Optional

from pathlib import Path

from vid2sim.factory.ingest.clip_list import ManifestRow, load_manifest
from vid2sim.factory.ingest.sources import Source, resolve_source
from vid2sim.factory.runtime.stage_cache import StageError
from vid2sim.factory.ingest.video_io import probe_video
from vid2sim.ranges import checked

DEFAULT_CLIP_SECONDS = 15.0


@checked
@dataclass(frozen=True)
class ClipsConfig:
    clip_seconds: float = DEFAULT_CLIP_SECONDS  # s, length of the windows a long source is cut into
    min_seconds: float = 4.0  # s, a shorter remainder joins the last window instead of making its own


@dataclass(frozen=True)
class ClipSpec:
    """One clip to process: a source, a window (None = the whole source) and the row's facts."""

    clip_id: str
    source: Source
    window: Optional[tuple[float, float]]
    group: str
    capture_height: float = 1.5
    tags: dict = field(default_factory=dict)


def split_windows(duration: float, clip_seconds: float = DEFAULT_CLIP_SECONDS,
                  min_seconds: float = 4.0) -> list[tuple[float, float]]:
    """Cut [0, duration) into consecutive windows of `clip_seconds`."""
    if duration <= 0:
        return []
    n = max(1, int(duration // clip_seconds))
    edges = [i * clip_seconds for i in range(n)] + [duration]
    if duration - n * clip_seconds >= min_seconds:
        edges = [i * clip_seconds for i in range(n + 1)] + [duration]
    return [(round(a, 6), round(b, 6)) for a, b in zip(edges[:-1], edges[1:])]


def clip_id(source: Source, window: Optional[tuple[float, float]]) -> str:
    """Stable id from the source content hash and the window."""
    w = "all" if window is None else f"{window[0]:.3f}-{window[1]:.3f}"
    return f"{source.sha256[:12]}-{hashlib.sha256(w.encode()).hexdigest()[:6]}"


def plan_clips(row: ManifestRow, source: Source, conf: ClipsConfig = ClipsConfig()) -> list[ClipSpec]:
    """Clips of one manifest row (its window, or N-second pieces of the whole video)."""
    if source.kind == "images":
        windows: list = [None]
    elif row.window is not None:
        windows = [row.window]
    else:
        windows = split_windows(probe_video(source.path).duration, conf.clip_seconds, conf.min_seconds)
        windows = windows or [None]
    return [ClipSpec(clip_id(source, w), source, w, row.group, row.capture_height, dict(row.tags))
            for w in windows]


def plan_manifest(path: Path, conf: ClipsConfig = ClipsConfig(), cache_dir: Optional[Path] = None,
                  ) -> tuple[list[ClipSpec], list[tuple[ManifestRow, StageError]]]:
    """All clips of a manifest, and the rows whose source failed (a bad source does not
    stop the others; a malformed manifest row raises, since the manifest itself is wrong)."""
    clips, failed = [], []
    for row in load_manifest(path):
        try:
            src = resolve_source(row.source, cache_dir, row.sha256)
            clips.extend(plan_clips(row, src, conf))
        except StageError as e:
            failed.append((row, e))
    return clips, failed
