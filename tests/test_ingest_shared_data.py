"""Real footage: decode (+ masks) the GoPro sidewalk clip and the Lund photo folder."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from conftest import shared_data_path
from vid2sim.factory.ingest import decode, masks
from vid2sim.factory.ingest.sources import resolve_source
from vid2sim.factory.runtime.runner import run_stage

pytestmark = pytest.mark.shared_data


def test_gopro_sidewalk_decode_and_masks(tmp_path: Path) -> None:
    video = shared_data_path("gopro_max_sidewalk") / "max-heromode.mp4"
    t0 = time.perf_counter()
    out = run_stage(decode.work(decode.DecodeConfig(), video), tmp_path / "decode")
    t1 = time.perf_counter()
    clip = json.loads((out / "clip.json").read_text())
    counts = clip["counts"]
    assert clip["source_frames"] == 315 and clip["size"] == [848, 480]
    assert counts["sampled"] == 105  # 10.5 s at 10 fps
    assert counts["kept"] >= 95 and counts["kept"] + counts["dropped_blur"] + counts["dropped_duplicate"] \
        + counts["dropped_black"] == 105
    assert len(list((out / "images").glob("*.jpg"))) == counts["kept"]
    m = run_stage(masks.work(masks.MasksConfig(), out), tmp_path / "masks")
    t2 = time.perf_counter()
    table = pq.read_table(m / "masks.parquet").to_pylist()
    assert len(table) == counts["kept"]
    assert sum(r["dynamic_fraction"] for r in table) / len(table) < 0.05  # a mostly static street
    print(f"\ngopro decode {t1 - t0:.1f} s, masks {t2 - t1:.1f} s, counts {counts}")


def test_lund_image_folder(tmp_path: Path) -> None:
    folder = shared_data_path("opensfm_lund_street") / "images"
    src = resolve_source(folder)
    assert src.kind == "images" and len(src.images()) == 29
    out = run_stage(decode.work(decode.DecodeConfig(), src), tmp_path / "decode")
    table = pq.read_table(out / "frames.parquet").to_pylist()
    assert [r["source_frame"] for r in table] == list(range(29))
    clip = json.loads((out / "clip.json").read_text())
    assert clip["kind"] == "images" and clip["size"] == [1024, 768]
    assert clip["counts"]["kept"] >= 27  # photos metres apart: no duplicates, few if any blurred
