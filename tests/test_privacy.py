"""Anonymiser on composited real faces (scikit-image's LFW subset) and rendered plates.

Every stored image downstream of the factory (splat training images, previews, episode videos)
is made from the decode stage's `images/`; these tests check that those are anonymised, that
no other module reads source pixels, and that the detectors and settings reach scene.json.
"""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

from conftest import shared_data_path
from ingest_media import texture
from vid2sim.factory.ingest import decode
from vid2sim.factory.ingest.privacy import Anonymiser, FaceConfig, PlateConfig, blur_mask
from vid2sim.factory.ingest.privacy_probe import FacePose, composite, coverage, false_positives
from vid2sim.factory.runtime.stage_cache import StageError
from vid2sim.factory.runtime.runner import run_stage

POSES = [FacePose(14), FacePose(20, roll_deg=10), FacePose(28, yaw=0.3), FacePose(36, mirror=True, motion_px=2),
         FacePose(48, roll_deg=-20), FacePose(64, yaw=0.15)]


def detail(img: np.ndarray, box: np.ndarray) -> float:
    """Laplacian variance (fine detail) inside a box."""
    x0, y0, x1, y1 = np.asarray(box).astype(int)
    return float(cv2.Laplacian(cv2.cvtColor(img[y0:y1, x0:x1], cv2.COLOR_BGR2GRAY), cv2.CV_32F).var())


def inner(box: np.ndarray) -> np.ndarray:
    """The middle of a plate box (its characters, without the plate's outline)."""
    x0, y0, x1, y1 = box
    return np.array([x0 + 0.1 * (x1 - x0), y0 + 0.3 * (y1 - y0), x1 - 0.1 * (x1 - x0), y1 - 0.2 * (y1 - y0)])


@pytest.fixture(scope="module")
def street() -> np.ndarray:
    """A synthetic street render (BGR, 640 x 360)."""
    from vid2sim.factory.synthetic import StreetRenderer, generate_street, preset
    from vid2sim.factory.synthetic.trajectory import walking_poses

    conf = preset("demo", duration_s=1.0, width=640, height=360)
    return StreetRenderer(generate_street(conf), conf).render(walking_poses(conf)[1][5])["rgb"][:, :, ::-1].copy()


def check_anonymised(frame: np.ndarray, seed: int) -> None:
    c = composite(frame, POSES, [110, 140], np.random.default_rng(seed))
    assert len(c.faces) == len(POSES) and len(c.plates) == 2
    out, faces, plates = Anonymiser()(c.image)
    cov = coverage(blur_mask(out.shape[:2], faces, 0.3), c.faces)
    assert (cov >= 0.8).all(), f"faces not covered: {cov}"
    assert (coverage(blur_mask(out.shape[:2], plates, 0.25), c.plates) >= 0.6).all()
    assert false_positives(faces, c.people) == 0
    for box in [*c.faces, *map(inner, c.plates)]:
        assert detail(out, box) < 0.3 * detail(c.image, box)  # detail is gone, not just boxed


def test_faces_and_plates_found_and_blurred_on_texture() -> None:
    check_anonymised(texture(360, 640, seed=4), seed=0)


@pytest.mark.slow
def test_faces_and_plates_found_and_blurred_on_a_synthetic_street(street: np.ndarray) -> None:
    check_anonymised(street, seed=0)


def test_turned_pass_maps_its_boxes_back_to_the_upright_frame() -> None:
    c = composite(texture(360, 640, seed=2), [FacePose(90)], [], np.random.default_rng(3))
    anon = Anonymiser(FaceConfig(), PlateConfig(detector="none"))
    for degrees in (20.0, -20.0):
        boxes, _ = anon.detector._run_turned(c.image, degrees)  # [K, 4] in the upright frame
        cov = coverage(blur_mask(c.image.shape[:2], boxes, 0.3), c.faces)
        assert cov[0] >= 0.8, (degrees, boxes, c.faces)
        x0, y0, x1, y1 = c.faces[0]
        best = boxes[np.argmax([min(b[2], x1) - max(b[0], x0) for b in boxes])]
        assert (best[2] - best[0]) * (best[3] - best[1]) < 3 * (x1 - x0) * (y1 - y0)  # the face, not the frame


@pytest.mark.shared_data
def test_faces_and_plates_found_and_blurred_on_a_real_street() -> None:
    frame = cv2.imread(str(sorted((shared_data_path("opensfm_lund_street") / "images").glob("*.jpg"))[3]))
    check_anonymised(cv2.resize(frame, (640, 480), interpolation=cv2.INTER_AREA), seed=1)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="known false positive: the plate finder takes a row of windows seen at a "
                   "grazing angle for characters (3.7 % of this frame blurred); a thin-bar rule that drops it "
                   "changed the GoPro clip's blurred patches and walked-corridor figure, so it is not applied")
def test_empty_street_is_left_alone(street: np.ndarray) -> None:
    out, faces, plates = Anonymiser()(street)
    assert len(faces) == 0 and blur_mask(street.shape[:2], plates).mean() < 0.02


def test_missing_models_are_named_errors(tmp_path: Path) -> None:
    missing = str(tmp_path / "missing.onnx")
    for conf, named in ((FaceConfig(model_path=missing), missing),
                        (FaceConfig(detector="yunet", model_path=missing), missing),
                        (FaceConfig(detector="no_such_detector"), "no_such_detector")):
        with pytest.raises(StageError) as e:
            Anonymiser(conf)
        assert e.value.reason == "no_face_detector" and named in str(e.value)
    with pytest.raises(StageError) as e:
        Anonymiser(FaceConfig(), PlateConfig(detector="no_such_detector"))
    assert e.value.reason == "no_plate_detector"


def test_decode_writes_no_unblurred_face_or_plate(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    bg = texture(360, 480 + 8 * 6, seed=5)
    c = composite(bg[:, :480], [FacePose(30), FacePose(44, yaw=0.3), FacePose(60, roll_deg=15)], [120], rng)
    folder = tmp_path / "photos"
    folder.mkdir()
    raws = []
    for i in range(6):  # the camera pans; the people and the plate stay in the picture
        frame = bg[:, 8 * i: 8 * i + 480].copy()
        objects = c.image[:, :480] != bg[:, :480]
        frame[objects] = c.image[objects]
        raws.append(frame)
        cv2.imwrite(str(folder / f"{i + 1}.png"), frame)
    out = run_stage(decode.work(replace(decode.DecodeConfig(workers=1), min_frames=4), folder), tmp_path / "out")
    table = pq.read_table(out / "frames.parquet").to_pylist()
    kept = [r for r in table if r["kept"]]
    assert len(kept) >= 4 and all(r["faces"] == 3 and r["plates"] >= 1 for r in kept)
    for r in kept:
        written, raw = cv2.imread(str(out / "images" / r["image"])), raws[r["source_frame"]]
        for box in [*c.faces, *map(inner, c.plates)]:
            assert detail(written, box) < 0.3 * detail(raw, box)
    clip = json.loads((out / "clip.json").read_text())
    assert clip["face_detector"] == "centerface" and clip["plate_detector"] == "text_rows"
    assert clip["faces"]["upscale"] == 2.0 and clip["counts"]["plates_blurred"] >= len(kept)


def test_only_decode_reads_source_pixels() -> None:
    """Source video frames are decoded, and sampled frames taken, in the decode stage alone, so
    every later artifact is made from anonymised images."""
    pkg = Path(decode.__file__).resolve().parents[2]
    readers = {p.relative_to(pkg).as_posix() for p in pkg.rglob("*.py")
               if re.search(r"\b(iter_frames|sample_video|sample_images)\(", p.read_text())}
    assert readers <= {"factory/ingest/decode.py", "factory/ingest/video_io.py"}, readers


def test_scene_json_records_the_anonymiser() -> None:
    from vid2sim.factory.runtime.pipeline import PipelineConfig
    from vid2sim.formats.scene import make_scene_json

    scene = make_scene_json("s0", source_uri="file:///v.mp4", source_sha256="0" * 64, clip_start_s=0.0,
                            clip_end_s=1.0, scale_source="capture_height", config=PipelineConfig())
    dec = scene["pipeline"]["config"]["decode"]
    assert dec["faces"]["detector"] == "centerface" and dec["faces"]["score_threshold"] == 0.0
    assert dec["plates"]["detector"] == "text_rows" and dec["plates"]["min_char_px"] == 4


def chain_roots_reference(c: np.ndarray, conf: PlateConfig) -> np.ndarray:
    """The plain-Python union-find `plates._chain_roots` compiles (characters sorted by x0)."""
    h, parent = c[:, 3] - c[:, 1], list(range(len(c)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(len(c)):
        for j in range(i + 1, len(c)):
            gap = c[j, 0] - c[i, 2]
            if gap > conf.max_gap * h[i]:
                break
            tol = conf.align * max(h[i], h[j])
            if (gap > -0.2 * h[i] and abs(c[i, 1] - c[j, 1]) < tol and abs(c[i, 3] - c[j, 3]) < tol
                    and 1 / conf.height_ratio < h[j] / h[i] < conf.height_ratio):
                parent[root(j)] = root(i)
    return np.array([root(i) for i in range(len(c))])


def test_plate_components_are_the_default_labellings(street: np.ndarray) -> None:
    """The plate finder's faster labelling gives OpenCV's default components, in the same
    order, on the enlarged thresholded frames it reads (a street with plates and faces)."""
    from vid2sim.factory.ingest.plates import component_stats

    c = composite(street, POSES, [110, 140], np.random.default_rng(3))
    grey = cv2.resize(cv2.cvtColor(c.image, cv2.COLOR_BGR2GRAY), None, fx=3, fy=3, interpolation=cv2.INTER_LINEAR)
    for mode, delta in ((cv2.THRESH_BINARY_INV, 12), (cv2.THRESH_BINARY, -12)):
        binary = cv2.adaptiveThreshold(grey, 255, cv2.ADAPTIVE_THRESH_MEAN_C, mode, 15, delta)
        want = cv2.connectedComponentsWithStats(binary, connectivity=8)[2]
        assert len(want) > 100 and np.array_equal(component_stats(binary), want)


def test_plate_character_chains_equal_the_plain_reference() -> None:
    """The compiled chaining of character boxes gives the reference's roots, on rows of text and clutter."""
    from vid2sim.factory.ingest.plates import _chain_roots

    rng = np.random.default_rng(0)
    conf = PlateConfig()
    rows = [np.c_[x0 + 14 * np.arange(6), np.full(6, y), x0 + 14 * np.arange(6) + 9, np.full(6, y + 16)]
            for x0, y in rng.uniform(0, 800, (20, 2))]  # [6, 4] each: 6 characters in a line
    xy, wh = rng.uniform(0, 900, (600, 2)), rng.uniform(3, 40, (600, 2))
    boxes = np.concatenate([*rows, np.c_[xy, xy + wh]]) + rng.normal(0, 0.5, (720, 4))
    boxes = boxes[np.argsort(boxes[:, 0])]
    roots = _chain_roots(boxes, conf.max_gap, conf.align, conf.height_ratio)
    assert np.array_equal(roots, chain_roots_reference(boxes, conf))
    assert len(np.unique(roots)) < len(boxes) - 20 * 5 + 1  # the 20 rows at least were chained
