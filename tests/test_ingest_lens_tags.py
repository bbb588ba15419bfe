"""The decode stage keeps the camera's make, model and 35 mm focal length (and nothing else of a
photo's EXIF) in the frames it writes, and the sfm stage's camera choice reads them back."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from ingest_media import panning_frames
from vid2sim.factory.ingest import decode, lens_tags
from vid2sim.factory.ingest.lens_tags import LensTags
from vid2sim.factory.runtime.runner import run_stage
from vid2sim.factory.sfm.camera_model import choose_camera_model, exif_hint

GPS_IFD = 0x8825


def _video_with_tags(path: Path, container: dict, handler: str = "") -> Path:
    import av

    frames = panning_frames(30, speed=3.0)
    with av.open(str(path), "w", options={"movflags": "use_metadata_tags"}) as out:
        out.metadata.update(container)
        stream = out.add_stream("libx264", rate=30)
        stream.width, stream.height, stream.pix_fmt = 160, 120, "yuv420p"
        if handler:
            stream.metadata["handler_name"] = handler
        for f in frames:
            for pkt in stream.encode(av.VideoFrame.from_ndarray(f, format="bgr24")):
                out.mux(pkt)
        for pkt in stream.encode():
            out.mux(pkt)
    return path


def _decode(src: Path, out: Path) -> Path:
    return run_stage(decode.work(decode.DecodeConfig(fps=10.0, workers=1), src), out)


def test_video_container_tags_reach_the_frames_and_the_camera_choice(tmp_path: Path) -> None:
    video = _video_with_tags(tmp_path / "clip.mp4", {"make": "GoPro", "model": "HERO9 Black"})
    out = _decode(video, tmp_path / "decode")
    first = sorted((out / "images").glob("*.jpg"))[0]
    hint = exif_hint(first)
    assert (hint.make, hint.model) == ("GoPro", "HERO9 Black")
    choice = choose_camera_model(160, 120, hint)
    assert "wide lens" in choice.reason and choice.params[0] == 80.0  # 0.5 x width, not COLMAP's 192
    assert json.loads((out / "clip.json").read_text())["lens"]["make"] == "GoPro"


def test_action_camera_named_by_the_track_handler(tmp_path: Path) -> None:
    video = _video_with_tags(tmp_path / "clip.mp4", {}, handler="GoPro AVC")
    assert lens_tags.from_video(video) == LensTags(make="GoPro")
    plain = _video_with_tags(tmp_path / "plain.mp4", {})
    assert lens_tags.from_video(plain).empty
    assert lens_tags.from_video(tmp_path / "missing.mp4").empty


def test_photo_exif_keeps_lens_facts_and_drops_the_rest(tmp_path: Path) -> None:
    folder = tmp_path / "photos"
    folder.mkdir()
    for i, frame in enumerate(panning_frames(12, speed=4.0)):
        exif = Image.Exif()
        exif[lens_tags.EXIF_MAKE], exif[lens_tags.EXIF_MODEL] = "Apple", "iPhone 4S"
        exif.get_ifd(lens_tags.EXIF_IFD)[lens_tags.EXIF_FOCAL_35MM] = 35
        exif.get_ifd(GPS_IFD)[2] = (55.0, 42.0, 0.0)  # latitude: must not survive
        Image.fromarray(frame[:, :, ::-1]).save(folder / f"{i:03d}.jpg", exif=exif)
    out = _decode(folder, tmp_path / "decode")
    written = sorted((out / "images").glob("*.jpg"))[0]
    assert lens_tags.from_image(written) == LensTags("Apple", "iPhone 4S", 35.0)
    with Image.open(written) as im:
        exif = im.getexif()
        assert not exif.get_ifd(GPS_IFD) and GPS_IFD not in exif
        assert set(exif) <= {lens_tags.EXIF_MAKE, lens_tags.EXIF_MODEL, lens_tags.EXIF_IFD}
    hint = exif_hint(written)
    assert hint.focal_px == 35.0 / 36.0 * 160


def test_the_exif_segment_leaves_the_pixels_and_an_empty_one_the_bytes() -> None:
    img = panning_frames(1)[0]
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 95])
    plain = buf.tobytes()
    tagged = lens_tags.with_exif(plain, LensTags("DJI", "Osmo").exif_segment())
    assert tagged != plain and tagged[:2] == b"\xff\xd8"
    a = cv2.imdecode(np.frombuffer(plain, np.uint8), cv2.IMREAD_COLOR)
    b = cv2.imdecode(np.frombuffer(tagged, np.uint8), cv2.IMREAD_COLOR)
    assert np.array_equal(a, b)
    assert lens_tags.with_exif(plain, LensTags().exif_segment()) == plain
