"""Env mesh rasteriser speed: frames/s at 128x72 for a 162k-triangle street mesh, vs pybullet's
TinyRenderer drawing the same mesh from the same cameras.

Usage: .venv/bin/python benchmarks/raster.py [--frames 200] [--no-pybullet] [--quick]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from common import Run, add_run_args
from vid2sim.envs.raster import rasterize

W, H = 128, 72
K = np.array([[64.0, 0.0, 64.0], [0.0, 64.0, 36.0], [0.0, 0.0, 1.0]])  # 90 deg horizontal FOV


def street_mesh(n: int = 285, size: float = 40.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Height-field street, z up: flat road, kerbs, 'facades' rising at |y| > 6 m. 2(n-1)^2 faces."""
    xs = np.linspace(-size / 2, size / 2, n)
    X, Y = np.meshgrid(xs, xs)  # [n, n]
    Z = np.where(np.abs(Y) > 6.0, 8.0 + np.sin(X) * 2, np.where(np.abs(Y) > 4.0, 0.15, 0.0))
    v = np.stack([X, Y, Z], -1).reshape(-1, 3).astype(np.float32)  # [n*n, 3]
    r, c = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (r * n + c).ravel()
    f = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    rng = np.random.default_rng(0)
    col = rng.integers(40, 220, size=(len(f), 3), dtype=np.uint8)
    return v, f.astype(np.int32), col


def robot_cameras(count: int) -> list[np.ndarray]:
    """World->camera 4x4 for a 0.6 m high camera driving along +x, yawing a little."""
    out = []
    for k in range(count):
        yaw = 0.3 * np.sin(k * 0.1)
        fwd = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        right = np.array([np.sin(yaw), -np.cos(yaw), 0.0])
        down = np.array([0.0, 0.0, -1.0])
        R = np.stack([right, down, fwd])  # rows: camera x, y, z axes in world
        eye = np.array([-15.0 + 0.1 * k % 20, 0.5 * np.sin(k * 0.05), 0.6])
        w2c = np.eye(4)
        w2c[:3, :3] = R
        w2c[:3, 3] = -R @ eye
        out.append(w2c)
    return out


def bench_ours(mesh, cams) -> tuple[float, float]:
    """(frames/s wall, frames/s of process CPU time: the figure when other jobs share the core)."""
    rasterize(*mesh, K, cams[0], W, H)  # compile / load cache
    t, c = time.perf_counter(), time.process_time()
    for w2c in cams:
        rasterize(*mesh, K, w2c, W, H)
    return len(cams) / (time.perf_counter() - t), len(cams) / (time.process_time() - c)


def bench_pybullet(mesh, cams) -> tuple[float, float]:
    import pybullet as pb

    cid = pb.connect(pb.DIRECT)
    v, f, _ = mesh
    vis = pb.createVisualShape(pb.GEOM_MESH, vertices=v.tolist(), indices=f.ravel().tolist(),
                               physicsClientId=cid)
    pb.createMultiBody(0, baseVisualShapeIndex=vis, physicsClientId=cid)
    proj = pb.computeProjectionMatrixFOV(fov=2 * np.degrees(np.arctan(36 / 64)), aspect=W / H,
                                         nearVal=0.05, farVal=100.0)
    views = []
    for w2c in cams:
        gl = np.diag([1.0, -1.0, -1.0, 1.0]) @ w2c  # OpenCV -> OpenGL camera
        views.append(gl.T.ravel().tolist())
    t, c = time.perf_counter(), time.process_time()
    for view in views:
        pb.getCameraImage(W, H, view, proj, renderer=pb.ER_TINY_RENDERER, physicsClientId=cid)
    fps = len(views) / (time.perf_counter() - t), len(views) / (time.process_time() - c)
    pb.disconnect(cid)
    return fps


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--no-pybullet", action="store_true")
    ap.add_argument("--quick", action="store_true", help="60 frames (smoke run)")
    add_run_args(ap)
    args = ap.parse_args()
    frames = 60 if args.quick and args.frames == 200 else args.frames
    with Run("raster", args) as run:
        mesh = street_mesh()
        cams = robot_cameras(frames)
        conf = {"triangles": len(mesh[1]), "vertices": len(mesh[0]), "image": f"{W}x{H}", "threads": 1}
        print(f"mesh: {len(mesh[1])} triangles, {len(mesh[0])} vertices; image {W}x{H}; 1 thread")
        wall, cpu = bench_ours(mesh, cams)
        run.record_all("vid2sim.envs.raster.rasterize", {"fps_wall": wall, "fps_per_cpu_s": cpu},
                       {"fps_wall": "frames/s", "fps_per_cpu_s": "frames/CPU-s"}, {**conf, "frames": frames})
        print(f"vid2sim.envs.raster.rasterize: {wall:.1f} frames/s wall, {cpu:.1f} per CPU-second")
        if not args.no_pybullet:
            n = max(frames // 10, 5)
            wall, cpu = bench_pybullet(mesh, cams[:n])
            run.record_all("pybullet ER_TINY_RENDERER", {"fps_wall": wall, "fps_per_cpu_s": cpu},
                           {"fps_wall": "frames/s", "fps_per_cpu_s": "frames/CPU-s"}, {**conf, "frames": n})
            print(f"pybullet ER_TINY_RENDERER (same mesh, same cameras): {wall:.1f} frames/s wall, "
                  f"{cpu:.1f} per CPU-second")

if __name__ == "__main__":
    main()
