"""Env render benchmark on real factory scenes: what the robot's 128x72 camera costs.

    .venv/bin/python benchmarks/env_render.py [--scenes demo gopro] [--poses 16] [--reps 3]
    .venv/bin/python benchmarks/env_render.py --scenes synthetic   # proxy, no factory scene
    .venv/bin/python benchmarks/env_render.py --quick   # the proxy, 8 poses, 1 rep, one fast setting
    .venv/bin/python benchmarks/env_render.py --scenes PATH/TO/BUNDLE   # any scene bundle folder

Scenes are built once by the factory and cached (benchmarks/env_scenes.py: the `make demo`
street; the shared GoPro MAX sidewalk clip when ../shared/data is there). Cameras: robot
poses along the walked path snapped to the walkable map, 0.6 m above the ground, heading
along the path +-25 deg, the envs' intrinsics (env_simready.robot_cameras: 60 deg vertical fov, 128x72).
Prints frames/s on 1 and 2 threads (and frames per CPU-second: per core), the per-phase
split, splats in view, blended splats per pixel, and PSNR/SSIM against the exact render for
every approximation. The sim-ready set is measured (and fitted) on 256 other robot views
(random walkable cells, random headings), never on the benchmark poses.
Exact: `StaticScene.render` and the frame kernel (`SceneBatch`), 8 separate calls of one
camera vs 8 cameras per call. Fast (`FastBatch`, approximate): per --keep-mass (with its
--fit-iterations), per --t-stop and --fill-alpha: PSNR/SSIM vs exact, the same two call
patterns, the phase split.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numba
import numpy as np
import pyarrow.parquet as pq
import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import Run, add_run_args  # noqa: E402
from env_scenes import build  # noqa: E402
from vid2sim.factory.recon.losses import ssim_map  # noqa: E402
from vid2sim.formats.walkable import WalkableGrid, load_walkable  # noqa: E402
from vid2sim.splats import RasterSettings, read_ply  # noqa: E402
from vid2sim.splats.cpu import StaticScene, StaticSceneConfig  # noqa: E402
from vid2sim.splats.cpu.env_batch import SceneBatch  # noqa: E402
from vid2sim.splats.cpu.env_fast_batch import TILE_SHIFT, FastBatch  # noqa: E402
from vid2sim.splats.cpu.env_fast_frame import (NPIX, NQ, composite_fast, cull_project,  # noqa: E402
                                          depth_order, sort_bin)
from vid2sim.splats.cpu.binning import _sort_and_bin_serial  # noqa: E402
from vid2sim.splats.cpu.env_frame import composite_frame, project_serial  # noqa: E402
from vid2sim.splats.cpu.project import camera_arrays  # noqa: E402
from vid2sim.splats.cpu.project import NF  # noqa: E402
from vid2sim.splats.cpu.env_simready import (SimReadyConfig, robot_cameras, sim_ready)  # noqa: E402
from vid2sim.splats.cpu.env_scene_kernels import cull_cells  # noqa: E402
from vid2sim.splats.cpu.synthetic import street_scene  # noqa: E402

W, H = 128, 72


def snap(grid: WalkableGrid, xy: np.ndarray) -> np.ndarray:
    """Nearest walkable cell centre of each point xy [P, 2]."""
    rows, cols = np.nonzero(grid.grid)
    cx, cy = grid.cell_center(rows, cols)
    cells = np.stack([cx, cy], 1)  # [C, 2]
    d = ((xy[:, None, :] - cells[None]) ** 2).sum(-1)
    return cells[d.argmin(1)]


def path_poses(bundle: Path, grid: WalkableGrid, n: int) -> tuple[np.ndarray, np.ndarray]:
    """n poses along the walked path (camera centres), snapped to the walkable map."""
    c2w = np.stack(pq.read_table(bundle / "cameras.parquet").column("cam_to_world").to_numpy(
        zero_copy_only=False)).reshape(-1, 4, 4)
    path = c2w[:, :2, 3]  # [F, 2]
    idx = np.linspace(0, len(path) - 2, n).astype(int)
    tangent = path[idx + 1] - path[idx]
    yaw = np.arctan2(tangent[:, 1], tangent[:, 0]) + np.deg2rad(np.resize([0.0, 25.0, -25.0], n))
    return snap(grid, path[idx]), yaw


def random_poses(grid: WalkableGrid, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    rows, cols = np.nonzero(grid.grid)
    pick = rng.integers(0, len(rows), n)
    x, y = grid.cell_center(rows[pick], cols[pick])
    return np.stack([x, y], 1), rng.uniform(-np.pi, np.pi, n)


def quality(img: torch.Tensor, ref: torch.Tensor) -> tuple[float, float]:
    """(PSNR dB, SSIM) of img vs ref, both [H, W, 3]."""
    a, b = img.clamp(0, 1), ref.clamp(0, 1)
    mse = float(((a - b) ** 2).mean())
    p = float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)
    return p, float(ssim_map(a, b).mean())


def timed(fn, reps: int) -> tuple[float, float]:
    """(wall s, process CPU s) of fn() run reps times, after one warm-up call."""
    fn()
    w0, c0 = time.perf_counter(), time.process_time()
    for _ in range(reps):
        fn()
    return time.perf_counter() - w0, time.process_time() - c0


def fps_line(run: Run, case: str, label: str, fn, frames: int, reps: int) -> float:
    """Print (and record under case) frames/s on 1 and 2 threads; returns frames/s per CPU-second
    on 1 thread."""
    numba.set_num_threads(1)
    w1, c1 = timed(fn, reps)
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    w2, _ = timed(fn, reps)
    numba.set_num_threads(1)
    n = frames * reps
    run.record_all(case, {"fps_1_thread": n / w1, "fps_per_cpu_s_1_thread": n / c1, "fps_2_threads": n / w2},
                   {"fps_1_thread": "frames/s", "fps_per_cpu_s_1_thread": "frames/CPU-s", "fps_2_threads": "frames/s"},
                   {"frames": frames, "reps": reps, "image": f"{W}x{H}"})
    print(f"  {label:<48} 1 thread {n / w1:7.1f} fps ({n / c1:7.1f} per CPU-s)   "
          f"2 threads {n / w2:7.1f} fps")
    return n / c1


def phases(scene: StaticScene, cams: list, st: RasterSettings, cap: int, tile: int,
           t_stop: float = 0.0) -> dict:
    """Per-phase CPU ms per frame (serial kernels, process CPU time: robust to other load)
    and splats in view / blends per covered pixel."""
    G = max(len(scene.means), 1)
    sel, fo = np.empty(G, np.int64), np.empty((G, NF), np.float32)
    box, radii = np.empty((G, 4), np.int32), np.empty(G, np.int32)
    color = np.empty((H, W, 3), np.float32)
    alpha, depth, bl = np.empty((H, W), np.float32), np.empty((H, W), np.float32), np.empty((H, W), np.int32)
    tx = (W + tile - 1) // tile
    nt = tx * ((H + tile - 1) // tile)
    t = {"cull": 0.0, "project": 0.0, "sort/bin": 0.0, "composite": 0.0}
    in_view, blends, covered = 0, 0, 0
    deg = min(st.active_sh_degree, scene.sh_degree)
    for cam in cams:
        view, campos, k = camera_arrays(cam)
        t0 = time.process_time()
        n = cull_cells(scene.centers, scene.r_means, scene.rho, scene.cell_start, view, k, W, H,
                       st.near, st.far, sel)
        t1 = time.process_time()
        project_serial(sel, n, scene.means, scene.cov, scene.opacity, scene.cut, scene.normal,
                       scene.rgb, scene.sh, deg, view, campos, k, W, H, st.near, st.far, -1.0,
                       fo, box, radii)
        t2 = time.process_time()
        off, inst, _, _ = _sort_and_bin_serial(fo, box, n, tile, tx, nt, False)
        t3 = time.process_time()
        blends += composite_frame(fo, box, off, inst, W, H, tile, cap, t_stop, color, alpha, depth, bl,
                                  np.zeros(0, np.float64))
        t4 = time.process_time()
        for key, dt in zip(t, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)):
            t[key] += dt
        in_view += int((box[:n, 2] >= box[:n, 0]).sum())
        covered += int((bl > 0).sum())
    f = len(cams)
    out = {k: 1e3 * v / f for k, v in t.items()}
    out.update(in_view=in_view / f, blends_px=blends / max(covered, 1))
    return out


def print_phases(label: str, p: dict, run: Run | None = None, case: str = "") -> None:
    split = ", ".join(f"{k} {v:.2f}" for k, v in p.items() if k not in ("in_view", "blends_px"))
    if run is not None:
        run.record_all(case, {f"{k} CPU ms/frame" if k not in ("in_view", "blends_px") else k: v
                              for k, v in p.items()},
                       {f"{k} CPU ms/frame": "ms" for k in p}, {"serial kernels": True})
    print(f"    {label} CPU ms per frame: {split}; splats in view {p['in_view']:,.0f}; "
          f"blended splats per covered pixel {p['blends_px']:.1f}")


def load_scene(name: str, args: argparse.Namespace) -> tuple | None:
    """(model, benchmark cameras, sim-ready cameras, title) of a factory scene, or of the
    synthetic street proxy ('synthetic': NOT a factory scene, for when none is built)."""
    if name == "synthetic":
        model = street_scene(args.synthetic_splats, seed=4)
        rng = np.random.default_rng(1)
        xs = np.linspace(-50.0, 50.0, args.poses)
        cams = robot_cameras(np.stack([xs, np.zeros_like(xs)], 1),
                             np.deg2rad(np.resize([0.0, 25.0, -25.0], args.poses)))
        train = robot_cameras(np.stack([rng.uniform(-55, 55, 256), rng.uniform(-2, 2, 256)], 1),
                              rng.uniform(-np.pi, np.pi, 256))
        return model, cams, train, f"synthetic street proxy (NOT a factory scene), {model.num:,} splats"
    bundle = Path(name) if (Path(name) / "scene.json").is_file() else build(name)
    if bundle is None:
        return None
    model = read_ply(bundle / "splats.ply")
    grid = load_walkable(bundle / "walkable.npz")
    cams = robot_cameras(*path_poses(bundle, grid, args.poses))
    train = robot_cameras(*random_poses(grid, 256, seed=1))
    return model, cams, train, f"{name}: {bundle}, walkable {grid.area_m2():.0f} m^2"


def bench_scene(run: Run, name: str, args: argparse.Namespace) -> None:
    loaded = load_scene(name, args)
    if loaded is None:
        run.note(f"skipped scene {name}: its data is absent")
        return
    tag = Path(name).name if name not in ("demo", "gopro", "synthetic") else name
    model, cams, train, title = loaded
    st = RasterSettings(W, H, active_sh_degree=model.sh_degree)
    print(f"\n## {title}\n  {model.num:,} splats (SH {model.sh_degree}), {len(cams)} robot "
          f"poses, 0.6 m, 128x72, 60 deg vertical fov")
    full = StaticScene(model)
    exact = [full.render(c, st).rgb for c in cams]
    print("  exact (frames/s; per CPU-s = per core):")
    run.record_all(f"{tag}: scene", {"splats": model.num, "sh_degree": model.sh_degree, "poses": len(cams)},
                   config={"title": title})
    fps_line(run, f"{tag}: exact, StaticScene.render", "before: StaticScene.render",
             lambda: [full.render(c, st) for c in cams], len(cams), args.reps)
    batch = SceneBatch([full])
    fps_line(run, f"{tag}: exact, frame kernel, 8 separate calls of 1 camera",
             "frame kernel, 8 separate calls of 1 camera", lambda: [batch.render([c], settings=st)
                                                                   for c in cams], len(cams), args.reps)
    fps_line(run, f"{tag}: exact, frame kernel, 8 cameras per call", "frame kernel, 8 cameras per call",
             lambda: [batch.render(cams[i:i + 8], settings=st) for i in range(0, len(cams), 8)],
             len(cams), args.reps)
    phases(full, cams[:1], st, 0, 16)  # compile the serial kernels outside the timing
    print_phases("exact", phases(full, cams, st, 0, 16), run, f"{tag}: exact, phases")
    fits = np.resize(args.fit_iterations, len(args.keep_mass))
    for mass, fit in zip(args.keep_mass, fits):
        t0 = time.perf_counter()
        conf = SimReadyConfig(keep_mass=mass, bake_colour=True, fit_iterations=int(fit))
        small, _ = sim_ready(model, train, conf, st)
        run.record_all(f"{tag}: sim-ready keep_mass {mass}, fit {fit}",
                       {"splats": small.num, "fraction_kept": small.num / model.num,
                        "made_s": time.perf_counter() - t0}, {"made_s": "s"},
                       {"train_views": len(train), "bake_colour": True})
        print(f"  sim-ready keep_mass {mass}, fit {fit} steps (colours baked, SH 0): "
              f"{small.num:,} splats ({small.num / model.num:.0%}), made in "
              f"{time.perf_counter() - t0:.1f} s from {len(train)} other robot views")
        scene = StaticScene(small, StaticSceneConfig(cell_size=args.cell_size))
        fb = FastBatch([scene])
        for ts in args.t_stop:
            for fill in args.fill_alpha:
                fast_lines(run, f"{tag}: fast, keep_mass {mass}, fit {fit}, t_stop {ts}, fill_alpha {fill}",
                           f"fast, keep_mass {mass}, fit {fit}, t_stop {ts}, fill_alpha {fill}", fb, scene,
                           cams, ts, fill, exact, args.reps)


def fast_lines(run: Run, case: str, tag: str, fb: FastBatch, scene: StaticScene, cams: list, ts: float,
               fill: float, exact: list, reps: int) -> None:
    """PSNR/SSIM vs exact, frames/s (8 cameras per call and 8 separate calls) and the
    per-phase split of one approximate (FastBatch) setting."""
    st0 = RasterSettings(W, H, active_sh_degree=0)
    kw = dict(settings=st0, t_stop=ts, fill_alpha=fill)
    imgs = fb.render(cams, **kw).rgb
    q = [quality(imgs[i], exact[i]) for i in range(len(cams))]
    run.record_all(case, {"psnr_vs_exact_mean": np.mean([a for a, _ in q]), "psnr_vs_exact_min": min(a for a, _ in q),
                          "ssim_vs_exact_mean": np.mean([v for _, v in q]), "ssim_vs_exact_min": min(v for _, v in q)},
                   {"psnr_vs_exact_mean": "dB", "psnr_vs_exact_min": "dB"})
    print(f"  {tag}: PSNR vs exact mean {np.mean([a for a, _ in q]):.1f} / min "
          f"{min(a for a, _ in q):.1f} dB, SSIM mean {np.mean([v for _, v in q]):.4f} / min "
          f"{min(v for _, v in q):.4f}")
    fps_line(run, f"{case}, 8 separate calls of 1 camera", "8 separate calls of 1 camera",
             lambda: [fb.render([c], **kw) for c in cams], len(cams), reps)
    fps_line(run, f"{case}, 8 cameras per call", "8 cameras per call",
             lambda: [fb.render(cams[i:i + 8], **kw) for i in range(0, len(cams), 8)], len(cams), reps)
    print_phases("fast", fast_phases(fb, scene, cams, ts, fill), run, f"{case}, phases")


def fast_phases(fb: FastBatch, scene: StaticScene, cams: list, ts: float, fill: float) -> dict:
    """Per-phase CPU ms per frame of the fast kernels (cull+project, sort+bin, composite)."""
    G = max(len(scene.means), 1)
    q, box = np.empty((2, G, NQ), np.float32), np.empty((2, G, 4), np.int32)
    keys, rows = np.empty((2, G), np.uint32), np.empty((2, G), np.int32)
    inst = np.empty(4 * G, np.int32)
    color = np.empty((H, W, 3), np.float32)
    alpha, depth = np.empty((H, W), np.float32), np.empty((H, W), np.float32)
    shift = TILE_SHIFT
    tile = 1 << shift
    tx, ty = (W + tile - 1) >> shift, (H + tile - 1) >> shift
    pix, rdone = np.empty(5 * NPIX, np.float32), np.empty(32, np.uint64)
    t = {"cull+project": 0.0, "sort/bin": 0.0, "composite": 0.0}
    st = RasterSettings(W, H)
    in_view, blends, covered = 0, 0, 0
    for rep in range(2):  # the first pass compiles and warms up
        for cam in cams:
            view, _, k = camera_arrays(cam)
            t0 = time.process_time()
            n, _ = cull_project(0, len(scene.centers), scene.centers, scene.r_means, scene.rho,
                                scene.cell_start, fb.packed, fb.all_cells, view, k, W, H, st.near,
                                st.far, -1.0, q[0], box[0])
            t1 = time.process_time()
            order = depth_order(q[0], n, keys[0], keys[1], rows[0], rows[1])
            off = np.empty(tx * ty + 1, np.int64)
            inst = sort_bin(q[0], box[0], n, order, q[1], box[1], shift, tx, tx * ty, off, inst)
            t2 = time.process_time()
            b = 0
            for i in range(tx * ty):
                x0, y0 = (i % tx) * tile, (i // tx) * tile
                b += composite_fast(q[1], box[1], off, inst, i, x0, y0, min(x0 + tile, W),
                                    min(y0 + tile, H), np.float32(max(ts, 1e-4)),
                                    np.float32(max(ts, 1e-4, 1.0 - fill)), pix, rdone,
                                    color, alpha, depth)
            t3 = time.process_time()
            if rep:
                for key, dt in zip(t, (t1 - t0, t2 - t1, t3 - t2)):
                    t[key] += dt
                in_view += n
                blends += b
                covered += int((alpha > 0).sum())
    f = len(cams)
    out = {k: 1e3 * v / f for k, v in t.items()}
    out.update(in_view=in_view / f, blends_px=blends / max(covered, 1))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", nargs="+", default=["demo", "gopro"])
    ap.add_argument("--poses", type=int, default=16)
    ap.add_argument("--reps", type=int, default=3)
    # 0.98: the lightest prune that is >= 400 frames per CPU-s on the demo street and still >= 35 dB
    # mean on both real scenes (docs/results.md, 979cc7c); 0.9 + fit: the envs' kind of training trade
    ap.add_argument("--keep-mass", type=float, nargs="+", default=[0.98, 0.9])
    ap.add_argument("--fit-iterations", type=int, nargs="+", default=[0, 600],
                    help="sim-ready fit steps per --keep-mass entry (repeated when shorter)")
    ap.add_argument("--t-stop", type=float, nargs="+", default=[0.05])
    ap.add_argument("--fill-alpha", type=float, nargs="+", default=[1.0],
                    help="fast path: pixels with alpha >= this read as opaque (1.0: off)")
    ap.add_argument("--cell-size", type=int, default=64, help="culling cell of the fast path")
    ap.add_argument("--synthetic-splats", type=int, default=75_000)
    ap.add_argument("--quick", action="store_true",
                    help="the synthetic proxy only, 8 poses, 1 rep, keep_mass 0.9 without fit (smoke run)")
    add_run_args(ap)
    args = ap.parse_args()
    if args.quick:
        args.scenes, args.poses, args.reps = ["synthetic"], 8, 1
        args.keep_mass, args.fit_iterations = [0.9], [0]
    with Run("env_render", args) as run:
        for name in args.scenes:
            bench_scene(run, name, args)


if __name__ == "__main__":
    main()
