"""Feature extraction on several threads gives the database of a one-thread run, row for row."""

from __future__ import annotations

import hashlib
import sqlite3
from pathlib import Path

import cv2
import numpy as np
import pytest

from vid2sim.factory.sfm import sfm
from vid2sim.factory.sfm.database import copy_in_name_order


def frames(folder: Path, n: int = 8) -> list[str]:
    """`n` textured 320 x 180 frames of a scene panning sideways."""
    rng = np.random.default_rng(0)
    wide = cv2.resize(rng.integers(0, 256, (45, 160, 3), dtype=np.uint8), (1280, 180), interpolation=cv2.INTER_CUBIC)
    folder.mkdir()
    names = [f"{i:06d}.jpg" for i in range(n)]
    for i, name in enumerate(names):
        cv2.imwrite(str(folder / name), wide[:, 40 * i: 40 * i + 320], [cv2.IMWRITE_JPEG_QUALITY, 95])
    return names


def tables(db: Path) -> dict[str, str]:
    """Each table's rows, hashed (ids included)."""
    con = sqlite3.connect(str(db))
    try:
        names = [t for (t,) in con.execute("select name from sqlite_master where type='table'")]
        return {t: hashlib.sha1(repr(con.execute(f"select * from {t} order by 1").fetchall()).encode()).hexdigest()
                for t in names}
    finally:
        con.close()


def test_two_threads_extract_as_one(tmp_path):
    names = frames(tmp_path / "frames")
    dbs = {}
    for threads in (1, 2):
        conf = sfm.preset("fast", num_threads=threads, max_image_size=320)
        cam = sfm.choose_camera(conf, tmp_path / "frames", names[0])
        dbs[threads] = tmp_path / f"t{threads}.db"
        sfm.extract(conf, dbs[threads], tmp_path / "frames", names, None, cam)
    assert not (tmp_path / "t2-unordered.db").exists()
    one, two = tables(dbs[1]), tables(dbs[2])
    assert set(one) >= {"images", "frames", "frame_data", "keypoints", "descriptors", "cameras"}
    assert one == two
    con = sqlite3.connect(str(dbs[2]))
    assert [name for (name,) in con.execute("select name from images order by image_id")] == names
    assert min(rows for (rows,) in con.execute("select rows from keypoints")) > 50  # the frames have features
    con.close()


def test_copy_keeps_the_given_order_and_refuses_an_existing_target(tmp_path):
    names = frames(tmp_path / "frames", 4)
    conf = sfm.preset("fast", num_threads=1, max_image_size=320)
    sfm.extract(conf, tmp_path / "a.db", tmp_path / "frames", names, None,
                sfm.choose_camera(conf, tmp_path / "frames", names[0]))
    assert copy_in_name_order(tmp_path / "a.db", tmp_path / "b.db", names[::-1] + ["missing.jpg"]) == 4
    con = sqlite3.connect(str(tmp_path / "b.db"))
    assert [name for (name,) in con.execute("select name from images order by image_id")] == names[::-1]
    con.close()
    with pytest.raises(FileExistsError, match="b.db"):
        copy_in_name_order(tmp_path / "a.db", tmp_path / "b.db", names)
