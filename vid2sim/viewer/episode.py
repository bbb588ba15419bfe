"""Which episode to replay: a trace file, an episode MP4 (its trace beside it) or an evaluation
report JSON (`eval policy --record N --out REPORT.json`: its recorded videos, trial `index`).

Reads those files; `VideoFrames` reads the camera-view panel of the episode MP4 frame by frame.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import cv2
import numpy as np

from vid2sim.formats.episode_trace import TRACE_SUFFIX, EpisodeTrace, read_trace, trace_path
from vid2sim.formats.errors import BundleError
from vid2sim.viewer.errors import EpisodeInputError


@dataclass
class EpisodeSource:
    trace: EpisodeTrace
    trace_file: Path
    video: Optional[Path]  # the episode MP4, None when it is gone
    registry: Optional[str]  # where its scene lives (the report's or the trace's registry)


def _from_report(path: Path, data: dict, index: int) -> tuple[Path, Optional[str]]:
    videos = data.get("videos") or []
    if not videos:
        raise EpisodeInputError(f"{path}: the evaluation report recorded no episodes (run `vid2sim eval policy "
                                "... --record 1 --out REPORT.json`)")
    if not 0 <= index < len(videos):
        raise EpisodeInputError(f"{path}: episode {index} asked for, the report recorded {len(videos)} "
                                f"(0..{len(videos) - 1})")
    video = Path(videos[index])
    video = video if video.is_absolute() or video.exists() else path.parent / video
    return trace_path(video), (data.get("config") or {}).get("registry")


def resolve_episode(path: Path, index: int = 0) -> EpisodeSource:
    """The episode at `path` (trace, MP4 or evaluation report); raise EpisodeInputError."""
    path = Path(path)
    if not path.is_file():
        raise EpisodeInputError(f"{path}: no such file")
    registry = None
    if path.suffix == ".mp4":
        tfile = trace_path(path)
    elif path.name.endswith(TRACE_SUFFIX):
        tfile = path
    else:
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError) as e:
            raise EpisodeInputError(f"{path}: not an MP4, trace or evaluation report ({e})") from None
        tfile, registry = _from_report(path, data, index) if "videos" in data else (path, None)
    try:
        trace = read_trace(tfile)
    except BundleError as e:
        raise EpisodeInputError(f"{e} (episodes recorded by `vid2sim envs record` or `vid2sim eval policy "
                                "--record N` have one beside each MP4)") from None
    video = tfile.with_name(trace.video) if trace.video else None
    return EpisodeSource(trace, tfile, video if video and video.is_file() else None, registry or trace.registry)


class VideoFrames:
    """Camera-view panel (left `view_width` px) of frame k of an episode MP4."""

    def __init__(self, path: Path, view_width: int) -> None:
        self.cap = cv2.VideoCapture(str(path))
        if not self.cap.isOpened():
            raise EpisodeInputError(f"{path}: OpenCV cannot open the episode video")
        self.view_width = view_width
        self.next_index = 0

    def frame(self, k: int) -> Optional[np.ndarray]:
        """RGB [H, view_width, 3] of frame k, None past the end."""
        if k != self.next_index:
            self.cap.set(cv2.CAP_PROP_POS_FRAMES, k)
        ok, bgr = self.cap.read()
        self.next_index = k + 1
        if not ok:
            return None
        width = self.view_width or bgr.shape[1]
        return np.ascontiguousarray(bgr[:, :width, ::-1])

    def close(self) -> None:
        self.cap.release()
