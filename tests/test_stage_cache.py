"""The one cache rule: key = stage name + STAGE_VERSION + config + input keys.

Checked on real stages (decode -> masks on a small panning clip) by their `stage.json`
markers: an unchanged re-run rewrites no marker; a changed config or a bumped stage version
reruns exactly that stage and the stages downstream of it.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import pytest

from ingest_media import panning_frames
from vid2sim.factory.ingest import decode, masks
from vid2sim.factory.runtime.runner import run_stage
from vid2sim.factory.runtime.stage_cache import MARKER, StageError, content_key, input_key, load_record, stage_key


def _frames_folder(tmp_path: Path, n: int = 12) -> Path:
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, f in enumerate(panning_frames(n, h=120, w=160, speed=3.0)):
        cv2.imwrite(str(folder / f"{i:03d}.png"), f)
    return folder


def _chain(tmp_path: Path, frames: Path, dconf: decode.DecodeConfig, mconf: masks.MasksConfig) -> dict[str, tuple]:
    """Run decode -> masks; return {stage: (marker key, marker mtime_ns)}."""
    d = run_stage(decode.work(dconf, frames), tmp_path / "decode")
    m = run_stage(masks.work(mconf, d), tmp_path / "masks")
    return {name: (load_record(out).key, (out / MARKER).stat().st_mtime_ns) for name, out in
            (("decode", d), ("masks", m))}


def _rerun(before: dict, after: dict) -> set[str]:
    return {s for s in before if before[s] != after[s]}


def test_changed_config_or_version_reruns_exactly_the_downstream_stages(tmp_path, monkeypatch):
    frames = _frames_folder(tmp_path)
    dconf, mconf = decode.DecodeConfig(workers=1, dup_flow_px=0.0), masks.MasksConfig()
    first = _chain(tmp_path, frames, dconf, mconf)
    same = _chain(tmp_path, frames, dconf, mconf)
    assert _rerun(first, same) == set()
    new_masks = _chain(tmp_path, frames, dconf, replace(mconf, dilate_px=mconf.dilate_px + 2))
    assert _rerun(same, new_masks) == {"masks"}
    monkeypatch.setattr(masks, "STAGE_VERSION", masks.STAGE_VERSION + 1)
    bumped_masks = _chain(tmp_path, frames, dconf, replace(mconf, dilate_px=mconf.dilate_px + 2))
    assert _rerun(new_masks, bumped_masks) == {"masks"}
    monkeypatch.setattr(decode, "STAGE_VERSION", decode.STAGE_VERSION + 1)
    bumped_decode = _chain(tmp_path, frames, dconf, replace(mconf, dilate_px=mconf.dilate_px + 2))
    assert _rerun(bumped_masks, bumped_decode) == {"decode", "masks"}


def test_stage_key_changes_with_each_part():
    base = stage_key("s", 1, {"a": 1}, "in")
    assert len({base, stage_key("t", 1, {"a": 1}, "in"), stage_key("s", 2, {"a": 1}, "in"),
                stage_key("s", 1, {"a": 2}, "in"), stage_key("s", 1, {"a": 1}, "other")}) == 5
    assert stage_key("s", 1, {"a": 1}, "in") == base


def test_input_key_is_the_marker_key_or_the_content(tmp_path):
    frames = _frames_folder(tmp_path)
    k = content_key(frames)
    assert input_key(frames) == k
    cv2.imwrite(str(frames / "000.png"), panning_frames(1, h=120, w=160, seed=5)[0])
    assert content_key(frames) != k  # image bytes count, not only names and sizes
    d = run_stage(decode.work(decode.DecodeConfig(workers=1, dup_flow_px=0.0), frames), tmp_path / "decode")
    assert input_key(d) == input_key(d / "images") == load_record(d).key
    with pytest.raises(StageError, match="missing_input"):
        input_key(tmp_path / "nowhere")
