"""LocalStorage: relative artifact paths only, named errors, folder copies, atomic markers."""

from __future__ import annotations

import pytest

from vid2sim.factory.runtime.storage import LocalStorage, StorageError


def test_bytes_and_markers_round_trip(tmp_path):
    s = LocalStorage(tmp_path / "root")
    assert not s.exists("clip/decode/clip.json")
    s.write_bytes("clip/decode/clip.json", b"{}")
    assert s.exists("clip/decode/clip.json") and s.read_bytes("clip/decode/clip.json") == b"{}"
    s.write_marker("clip/decode/stage.json", b"one")
    s.write_marker("clip/decode/stage.json", b"two")
    assert s.read_bytes("clip/decode/stage.json") == b"two"
    assert sorted(p.name for p in (tmp_path / "root/clip/decode").iterdir()) == ["clip.json", "stage.json"]


@pytest.mark.parametrize("bad", ["", "/etc/passwd", "clip/../../x", "a\\b"])
def test_paths_outside_the_root_are_refused(tmp_path, bad):
    with pytest.raises(StorageError, match="invalid artifact path"):
        LocalStorage(tmp_path).exists(bad)


def test_missing_artifacts_are_named(tmp_path):
    s = LocalStorage(tmp_path)
    with pytest.raises(StorageError, match="clip/recon/splats.ply"):
        s.read_bytes("clip/recon/splats.ply")
    with pytest.raises(StorageError, match="clip/meshing"):
        s.get_dir("clip/meshing", tmp_path / "out")


def test_folders_go_in_and_out(tmp_path):
    src = tmp_path / "local"
    (src / "images").mkdir(parents=True)
    (src / "images" / "a.jpg").write_bytes(b"jpg")
    s = LocalStorage(tmp_path / "root")
    s.put_dir(src, "clip/decode")
    assert s.read_bytes("clip/decode/images/a.jpg") == b"jpg"
    back = s.get_dir("clip/decode", tmp_path / "copy")
    assert (back / "images" / "a.jpg").read_bytes() == b"jpg"
    assert s.get_dir("clip/decode", s.path("clip/decode")) == s.path("clip/decode")
