"""`masks` stage: moving objects masked (COLMAP convention), static scene left alone, plug-ins."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest
import torch

from ingest_media import object_box, panning_frames
from vid2sim.factory.ingest import decode, masks
from vid2sim.factory.runtime.stage_cache import StageError
from vid2sim.factory.runtime.runner import run_stage

OBJ = dict(size=36, vx=-2, vy=1, x=150, y=40)  # moves against a camera panning at 3 px/frame


def _decoded(tmp_path: Path, frames: list[np.ndarray]) -> Path:
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(folder / f"{i:03d}.png"), f)
    return run_stage(decode.work(decode.DecodeConfig(workers=1, dup_flow_px=0.0), folder), tmp_path / "decode")


def _gt(i: int, shape: tuple) -> np.ndarray:
    x0, y0, x1, y1 = object_box(OBJ, i)
    gt = np.zeros(shape[:2], bool)
    gt[y0:y1, x0:x1] = True
    return gt


def test_moving_object_masked_static_background_kept(tmp_path: Path) -> None:
    frames = panning_frames(16, h=240, w=320, speed=3.0, obj=OBJ)
    out = run_stage(masks.work(masks.MasksConfig(), _decoded(tmp_path, frames)), tmp_path / "masks")
    files = sorted((out / "masks").iterdir())
    assert [p.name for p in files] == [f"{i:06d}.jpg.png" for i in range(16)]
    recalls, false_bg = [], []
    for i, p in enumerate(files):
        m = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        assert m.dtype == np.uint8 and m.shape == (240, 320) and set(np.unique(m)) <= {0, 255}
        dyn, gt = m == 0, _gt(i, m.shape)
        recalls.append((dyn & gt).sum() / gt.sum())
        ring = cv2.dilate(gt.astype(np.uint8), np.ones((25, 25), np.uint8)).astype(bool)
        false_bg.append((dyn & ~ring).mean())
    assert np.mean(recalls) > 0.9 and min(recalls) > 0.7
    assert max(false_bg) < 0.01
    table = pq.read_table(out / "masks.parquet").to_pylist()
    assert len(table) == 16 and all(r["reliable"] for r in table)


def test_static_scene_has_no_dynamic_pixels(tmp_path: Path) -> None:
    frames = panning_frames(12, h=240, w=320, speed=3.0)
    out = run_stage(masks.work(masks.MasksConfig(), _decoded(tmp_path, frames)), tmp_path / "masks")
    dyn = [np.mean(cv2.imread(str(p), 0) == 0) for p in sorted((out / "masks").iterdir())]
    assert max(dyn) < 0.005


class _RedSegmenter(torch.nn.Module):
    """A stand-in 'learned' model: class 1 where the image is strongly red."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # [1, 3, H, W] RGB -> [1, 2, H, W]
        red = x[:, 0] - 0.5 * (x[:, 1] + x[:, 2])
        return torch.stack([0.3 - red, red - 0.3], 1)


def test_learned_segmenter_plugin_keeps_only_moving_segments(tmp_path: Path) -> None:
    frames = panning_frames(12, h=240, w=320, speed=3.0, obj=OBJ)
    for i, f in enumerate(frames):
        x0, y0, x1, y1 = object_box(OBJ, i)
        f[y0 + 4:y1 - 4, x0 + 4:x1 - 4] = (0, 0, 255)  # a red (untextured) moving body
        sx = 100 - 3 * i  # a red sign painted on the wall: static in the world, pans with it
        f[150:200, sx:sx + 50] = (0, 0, 255)
    model = tmp_path / "seg.pt"
    torch.jit.script(_RedSegmenter()).save(str(model))
    conf = masks.MasksConfig(segmenter_path=str(model), segmenter_classes=(1,))
    out = run_stage(masks.work(conf, _decoded(tmp_path, frames)), tmp_path / "masks")
    body, sign = [], []
    for i, p in enumerate(sorted((out / "masks").iterdir())):
        dyn = cv2.imread(str(p), 0) == 0
        x0, y0, x1, y1 = object_box(OBJ, i)
        body.append(dyn[y0 + 4:y1 - 4, x0 + 4:x1 - 4].mean())
        sx = 100 - 3 * i
        sign.append(dyn[155:195, sx + 5:sx + 45].mean())
    assert min(body) > 0.95  # the whole moving body, not just its textured rim
    assert max(sign) < 0.05  # a static object of the same class stays usable
    table = pq.read_table(out / "masks.parquet").to_pylist()
    assert all(r["segments"] >= 1 for r in table)


def test_errors_and_skip(tmp_path: Path) -> None:
    with pytest.raises(StageError) as e:
        run_stage(masks.work(masks.MasksConfig(), tmp_path / "nowhere"), tmp_path / "masks")
    assert e.value.reason == "missing_input" and not (tmp_path / "masks").exists()
    dec = _decoded(tmp_path, panning_frames(10, speed=3.0))
    with pytest.raises(StageError) as e:
        conf = replace(masks.MasksConfig(), segmenter_path=str(tmp_path / "none.pt"))
        run_stage(masks.work(conf, dec), tmp_path / "m2")
    assert e.value.reason == "missing_segmenter" and not (tmp_path / "m2").exists()
    out = run_stage(masks.work(masks.MasksConfig(), dec), tmp_path / "masks")
    stamp = (out / "stage.json").stat().st_mtime_ns
    run_stage(masks.work(masks.MasksConfig(), dec), tmp_path / "masks")
    assert (out / "stage.json").stat().st_mtime_ns == stamp
