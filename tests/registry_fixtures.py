"""Small real scene bundles for registry tests (a few hundred Gaussians, a trimesh box).

Importable from spawned processes (no pytest dependency).
"""

from __future__ import annotations

import hashlib
import struct
import zlib
from pathlib import Path
from typing import Optional

import numpy as np

from vid2sim.factory.sfm.posed import PosedClip, PosedFrame
from vid2sim.formats.bundle import write_bundle
from vid2sim.formats.scene import make_scene_json


def write_splats_ply(path: Path, n: int = 300, seed: int = 0, sh_rest: int = 0) -> Path:
    """Standard 3DGS binary PLY with `n` random Gaussians."""
    from plyfile import PlyData, PlyElement

    rng = np.random.default_rng(seed)
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(sh_rest)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    data = np.zeros(n, dtype=[(k, "f4") for k in names])
    for k in names:
        data[k] = rng.normal(size=n).astype(np.float32)
    data["nx"] = data["ny"] = data["nz"] = 0
    PlyData([PlyElement.describe(data, "vertex")]).write(str(path))
    return path


def write_box_ply(path: Path, extents=(4.0, 3.0, 2.0)) -> Path:
    import trimesh

    trimesh.creation.box(extents=extents).export(str(path))
    return path


def write_png(path: Path, w: int = 8, h: int = 6, seed: int = 0) -> Path:
    """A tiny RGB PNG written by hand (no image library needed)."""
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 255, size=(h, w, 3), dtype=np.uint8)
    raw = b"".join(b"\x00" + img[y].tobytes() for y in range(h))

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw))
                     + chunk(b"IEND", b""))
    return path


def cameras_table(n: int = 16):
    frames = []
    for i in range(n):
        T = np.eye(4)
        T[0, 3] = 0.1 * i
        K = np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]])
        frames.append(PosedFrame(i, f"{i:05d}.jpg", i / 10.0, 64, 48, K, T, "test" if i % 8 == 0 else "train"))
    return PosedClip(frames=frames, images_dir=Path(".")).cameras_table()


def make_bundle(
    out_dir: Path,
    scene_id: str = "scene-a",
    *,
    group: Optional[str] = None,
    seed: int = 0,
    n_splats: int = 300,
    tags: tuple[str, ...] = (),
    metrics: Optional[dict] = None,
    extras: bool = False,
) -> Path:
    """Write a valid bundle for `scene_id` into `out_dir`; `seed` changes the content."""
    out_dir = Path(out_dir)
    work = out_dir.parent / f".{out_dir.name}.inputs"
    work.mkdir(parents=True, exist_ok=True)
    sha = hashlib.sha256(f"video:{group or scene_id}".encode()).hexdigest()
    scene = make_scene_json(
        scene_id, source_uri=f"file:///videos/{group or scene_id}.mp4", source_sha256=sha,
        clip_start_s=0.0, clip_end_s=10.0 + seed, group=group, scale_source="test-fixture",
        metrics=metrics if metrics is not None else {"psnr": 25.0 + seed % 5}, config={"seed": seed},
        code_version="test", tags=tags)
    grid = np.zeros((10, 12), np.uint8)
    grid[2:8, 3:9] = 1
    ex = {}
    if extras:
        (work / "colmap").mkdir(exist_ok=True)
        (work / "colmap" / "points3D.txt").write_text(f"# points {seed}\n")
        ex = {"visual.ply": write_box_ply(work / "visual.ply", (1, 1, 1)), "colmap": work / "colmap"}
    write_bundle(
        out_dir, scene_json=scene,
        splats_ply=write_splats_ply(work / "s.ply", n_splats, seed),
        collision_ply=write_box_ply(work / "c.ply"),
        walkable=(grid, (-1.0, -2.0), 0.5), cameras=cameras_table(),
        preview_png=write_png(work / "p.png", seed=seed), extras=ex, overwrite=True)
    import shutil

    shutil.rmtree(work, ignore_errors=True)
    return out_dir


def concurrent_worker(root: str, wid: int, bundles: list[str], common: str, shared: str,
                      auto_compact_files: int = 50) -> list[str]:
    """Run in a spawned process: add own bundles, the common bundle, and tag the shared scene."""
    from vid2sim.registry.store import Registry, RegistryConfig

    reg = Registry(root, config=RegistryConfig(auto_compact_files=auto_compact_files))
    refs = []
    for i, b in enumerate(bundles):
        refs.append(reg.add(b).ref)
        refs.append(reg.tag(shared, f"w{wid}-{i}").ref)
        if i == 0:
            reg.add(common)
    return refs


KILL_LOOP = """
import sys
from vid2sim.registry.store import Registry, RegistryConfig
reg = Registry(sys.argv[1], config=RegistryConfig(auto_compact_files=int(sys.argv[2])))
reg.version  # open the table before announcing readiness
print("ready", flush=True)
for b in sys.argv[3:]:
    reg.add(b)
    print("added", b, flush=True)
"""


def synthetic_record(scene_id: str, group: str, *, psnr: float = 25.0, tags: tuple[str, ...] = (),
                     status: str = "active", version: int = 1):
    """A manifest record without files (for split logic and bulk benchmarks)."""
    from datetime import datetime, timezone

    from vid2sim.registry.records import Artifact, SceneRecord

    h = hashlib.sha256(scene_id.encode()).hexdigest()
    return SceneRecord(
        scene_id=scene_id, version=version, status=status, event="add", message=None,
        created_at=datetime.now(timezone.utc), source_uri=f"file:///videos/{group}.mp4",
        source_sha256=hashlib.sha256(group.encode()).hexdigest(), clip_start_s=0.0, clip_end_s=10.0,
        source_group=group, num_frames=100, num_train_frames=87, num_test_frames=13, num_splats=100000,
        metrics={"psnr": psnr}, bounds=(0, 0, 0, 1, 1, 1), mesh_bounds=(0, 0, 0, 1, 1, 1),
        walkable_area_m2=10.0, tags=tuple(tags), pipeline_hash="p", code_version="test", content_hash=h,
        artifacts=(Artifact("scene.json", h, 10),))


def cli_add_worker(root: str, bundle: str, barrier) -> dict:
    """Run in a spawned process: wait for the others, then `vid2sim registry add --json`."""
    import json

    from typer.testing import CliRunner

    from vid2sim.cli.registry import app  # the registry sub-app alone: quick to spawn

    barrier.wait()
    r = CliRunner().invoke(app, ["add", bundle, "-r", root, "--json"])
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout)


def checkout_worker(root: str, scene_id: str, dest: str, barrier) -> str:
    """Run in a spawned process: wait for the others, then check `scene_id` out into `dest`."""
    from vid2sim.registry.store import Registry

    reg = Registry(root)
    barrier.wait()
    return str(reg.checkout(scene_id, dest=dest))
