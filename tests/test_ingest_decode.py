"""`decode` stage: sampling, blur / duplicate filters, face blurring, outputs, input errors."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import matplotlib.cbook as cbook
import numpy as np
import pyarrow.parquet as pq
import pytest

from ingest_media import make_video, panning_frames, texture, write_video
from vid2sim.factory.ingest import decode
from vid2sim.factory.ingest.privacy import Anonymiser, FaceConfig
from vid2sim.factory.runtime.stage_cache import StageError, load_record
from vid2sim.factory.runtime.runner import run_stage

CONF = decode.DecodeConfig(workers=1)


def _decode_error(tmp_path: Path, source, conf=CONF) -> StageError:
    out = tmp_path / "out"
    with pytest.raises(StageError) as e:
        run_stage(decode.work(conf, source), out)
    assert e.value.stage == "decode"
    assert not out.exists()  # nothing written
    return e.value


def test_decode_samples_filters_and_writes(tmp_path: Path) -> None:
    frames = panning_frames(40, speed=3.0)
    frames[12] = cv2.GaussianBlur(frames[12], (0, 0), 4)  # badly blurred
    frames[19:24] = [frames[18]] * 5  # the camera stopped
    video = write_video(tmp_path / "walk.mp4", frames, fps=20)
    out = run_stage(decode.work(replace(CONF, fps=10.0), video), tmp_path / "out")  # every 2nd frame
    table = pq.read_table(out / "frames.parquet").to_pylist()
    assert [r["source_frame"] for r in table] == list(range(0, 40, 2))
    reasons = {r["source_frame"]: r["reason"] for r in table if not r["kept"]}
    assert reasons == {12: "blur", 20: "duplicate", 22: "duplicate"}
    kept = [r for r in table if r["kept"]]
    assert [r["index"] for r in kept] == list(range(17))
    assert sorted(p.name for p in (out / "images").iterdir()) == [r["image"] for r in kept]
    assert all(r["motion"] >= CONF.dup_flow_px for r in kept[1:])
    clip = json.loads((out / "clip.json").read_text())
    assert clip["counts"]["sampled"] == 20 and clip["counts"]["kept"] == 17
    assert clip["counts"]["dropped_blur"] == 1 and clip["counts"]["dropped_duplicate"] == 2
    assert clip["size"] == [160, 120] and clip["source_fps"] == pytest.approx(20.0)
    assert clip["sha256"] and clip["face_detector"] == "centerface"
    assert load_record(out).summary["kept"] == 17


def test_window_resize_and_skip(tmp_path: Path) -> None:
    video = make_video(tmp_path / "walk.mp4", n=90, fps=30, h=240, w=320)
    conf = replace(CONF, fps=15.0, max_side=160)
    out = run_stage(decode.work(conf, video, window=(1.0, 2.0)), tmp_path / "out")
    table = pq.read_table(out / "frames.parquet")
    ts = table.column("timestamp").to_pylist()
    assert len(ts) == 15 and 1.0 - 1e-6 <= min(ts) and max(ts) < 2.0
    assert cv2.imread(str(out / "images" / "000000.jpg")).shape == (120, 160, 3)
    stamp = (out / "stage.json").stat().st_mtime_ns
    run_stage(decode.work(conf, video, window=(1.0, 2.0)), tmp_path / "out")  # same key: skipped
    assert (out / "stage.json").stat().st_mtime_ns == stamp
    with pytest.raises(StageError) as e:
        run_stage(decode.work(conf, video, window=(10.0, 12.0)), tmp_path / "out2")
    assert e.value.reason == "empty_window"


def _face_scene(i: int) -> np.ndarray:
    """A textured, panning background with a person's face (matplotlib's sample photo)."""
    face = cv2.imread(cbook.get_sample_data("grace_hopper.jpg", asfileobj=False))  # [600, 512, 3]
    face = cv2.resize(face, (128, 150), interpolation=cv2.INTER_AREA)
    bg = texture(300, 500 + 8 * 12, seed=3)[:, 8 * i: 8 * i + 400].copy()
    bg[60:210, 140:268] = face
    return bg


def test_faces_blurred_before_writing(tmp_path: Path) -> None:
    folder = tmp_path / "photos"
    folder.mkdir()
    for i in range(12):
        cv2.imwrite(str(folder / f"{i + 1}.png"), _face_scene(i))
    out = run_stage(decode.work(CONF, folder), tmp_path / "out")
    table = pq.read_table(out / "frames.parquet").to_pylist()
    assert len(table) == 12 and all(r["kept"] and r["faces"] >= 1 for r in table)
    raw = _face_scene(0)[85:155, 170:245]  # the face (eyes, nose, mouth)
    written = cv2.imread(str(out / "images" / "000000.jpg"))[85:155, 170:245]
    lap = lambda im: cv2.Laplacian(cv2.cvtColor(im, cv2.COLOR_BGR2GRAY), cv2.CV_32F).var()  # noqa: E731
    assert lap(written) < 0.1 * lap(raw)  # the face is unrecognisably smoothed
    clip = json.loads((out / "clip.json").read_text())
    assert clip["kind"] == "images" and clip["counts"]["frames_with_faces"] == 12


def test_anonymiser_leaves_faceless_frames(tmp_path: Path) -> None:
    img = texture(120, 160)
    out, faces, plates = Anonymiser(FaceConfig())(img)
    assert len(faces) == 0 and len(plates) == 0 and np.array_equal(out, img)
    with pytest.raises(StageError) as e:
        Anonymiser(FaceConfig(detector="yunet", model_path=str(tmp_path / "missing.onnx")))
    assert e.value.reason == "no_face_detector"


# ---------------------------------------------------------------------------- bad input
def test_not_a_video(tmp_path: Path) -> None:
    fake = tmp_path / "clip.mp4"
    fake.write_text("this is a text file renamed .mp4\n" * 20)
    assert _decode_error(tmp_path, fake).reason == "not_a_video"


def test_truncated(tmp_path: Path) -> None:
    data = make_video(tmp_path / "full.mp4", n=60).read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: len(data) // 2])
    assert _decode_error(tmp_path, cut).reason == "truncated"


def test_zero_frames(tmp_path: Path) -> None:
    assert _decode_error(tmp_path, write_video(tmp_path / "empty.mp4", [])).reason == "zero_frames"


def test_fewer_than_10_frames(tmp_path: Path) -> None:
    video = make_video(tmp_path / "short.mp4", n=9, fps=10)
    err = _decode_error(tmp_path, video, replace(CONF, fps=30.0))
    assert err.reason == "too_few_frames" and "9 frames" in err.detail


def test_all_black(tmp_path: Path) -> None:
    video = write_video(tmp_path / "black.mp4", [np.zeros((120, 160, 3), np.uint8)] * 30)
    assert _decode_error(tmp_path, video).reason == "all_black"


def test_static_camera(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    still = texture(120, 160)
    frames = [np.clip(still + rng.normal(0, 1.0, still.shape), 0, 255).astype(np.uint8) for _ in range(60)]
    assert _decode_error(tmp_path, write_video(tmp_path / "tripod.mp4", frames)).reason == "static_camera"


def test_unreadable_image_in_folder(tmp_path: Path) -> None:
    folder = tmp_path / "photos"
    folder.mkdir()
    for i in range(10):
        cv2.imwrite(str(folder / f"{i}.jpg"), texture(60, 80, seed=i))
    (folder / "5.jpg").write_text("not an image")
    assert _decode_error(tmp_path, folder).reason == "not_an_image"
