"""Benchmark: the training composites on a reconstruction's own views, per tile edge, interleaved.

The reconstruction's training loop spends most of its time in the `cpu` backend's forward and
backward composites. This times them (sort and bin, forward composite, backward composite) on a
trained model at the training views it was made from, for each variant (tile edge, median depth
on or off), and runs the variants one after the other on every view, in alternating order from
round to round: a machine whose speed drifts by 10-30 % from minute to minute (shared VMs) then
slows every variant alike, and the per-round ratios to the first variant stay tight. The
backward gets random per-pixel loss gradients (its cost does not depend on their values).

    .venv/bin/python benchmarks/train_composite.py POSED SPLATS [--variants 16 32 32:nomedian]
        [--threads 2] [--rounds 6] [--every 6]

POSED is a factory work folder's `metric` stage (the PosedClip the recon stage reads); SPLATS
the `splats.ply` the recon stage made from it (`vid2sim recon run POSED OUT`).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from common import Run, add_run_args
from vid2sim.factory.recon.config import preset
from vid2sim.factory.recon.data import load_views
from vid2sim.factory.sfm.posed import PosedClip
from vid2sim.splats.camera import Camera
from vid2sim.splats.cpu import train_rasterize as tr
from vid2sim.splats.cpu.binning import sort_and_bin
from vid2sim.splats.cpu.composite import MAX_TILE, raster_backward, raster_forward
from vid2sim.splats.ply import read_ply
from vid2sim.splats.types import RasterSettings

PHASES = ("sort and bin", "forward composite", "backward composite")


@dataclass(frozen=True)
class Variant:
    tile: int  # px
    median: bool  # forward tracks the median splat

    @property
    def name(self) -> str:
        return f"{self.tile} px tiles" + ("" if self.median else ", no median")


def parse_variant(text: str) -> Variant:
    """'32' or '32:nomedian' -> Variant."""
    edge, _, flag = text.partition(":")
    if not edge.isdigit() or flag not in ("", "nomedian"):
        raise argparse.ArgumentTypeError(f"{text!r}: expected EDGE or EDGE:nomedian")
    return Variant(int(edge), flag != "nomedian")


@dataclass
class ViewCase:
    frame: tr.Frame  # the projected visible splats of the view
    width: int
    height: int
    d_rgb: np.ndarray  # [H, W, 3] random loss gradients
    d_plane: np.ndarray  # [H, W]


def view_cases(posed: Path, splats: Path, every: int, seed: int = 0) -> list[ViewCase]:
    """Every `every`-th training view of the clip at the `fast` preset's size, with the model's
    projection (SH degree 3) and random loss gradients."""
    views = [v for v in load_views(PosedClip.load(posed), preset("fast").max_width) if v.split == "train"]
    m = read_ply(splats)
    arrays = [tr._np32(t) for t in (m.means, m.quats, m.log_scales, m.opacity_logits, m.sh)]
    deg = min(3, int(round(arrays[4].shape[1] ** 0.5)) - 1)
    rng = np.random.default_rng(seed)
    cases = []
    for v in views[::every]:
        cam = Camera.from_cam_to_world(v.K, v.cam_to_world, v.width, v.height)
        frame = tr.forward_frame(*arrays, deg, cam, RasterSettings(v.width, v.height, active_sh_degree=deg))
        cases.append(ViewCase(frame, v.width, v.height, rng.normal(size=(v.height, v.width, 3)).astype(np.float32),
                              rng.normal(size=(v.height, v.width)).astype(np.float32)))
    return cases


def time_view(c: ViewCase, var: Variant, workers: int) -> np.ndarray:
    """Wall seconds [3] of sort and bin, forward and backward composite for one view."""
    w, h, fr, tile = c.width, c.height, c.frame, var.tile
    tiles_x = (w + tile - 1) // tile
    n_tiles = tiles_x * ((h + tile - 1) // tile)
    planes = [np.empty((h, w), np.float32) for _ in range(4)]  # alpha, depth, median, T
    color, normal = np.empty((h, w, 3), np.float32), np.empty((h, w, 3), np.float32)
    n_contrib, med_idx = np.empty((h, w), np.int32), np.empty((h, w), np.int32)
    t0 = time.perf_counter()  # outputs allocated outside the timed phases
    offsets, inst, row_start, pos = sort_and_bin(fr.fo, fr.box, fr.fo.shape[0], tile, tiles_x, n_tiles, True, workers)
    t1 = time.perf_counter()
    raster_forward(fr.fo, fr.box, offsets, inst, w, h, tile, color, planes[0], planes[1], normal, planes[2],
                   planes[3], n_contrib, med_idx, workers, var.median)
    t2 = time.perf_counter()
    raster_backward(fr.fo, fr.box, offsets, inst, row_start, pos, fr.fo.shape[0], w, h, tile, planes[3],
                    n_contrib, med_idx, c.d_rgb, c.d_plane, c.d_plane, c.d_rgb, c.d_plane, workers)
    return np.array([t1 - t0, t2 - t1, time.perf_counter() - t2])


def measure(run: Run, cases: list[ViewCase], variants: list[Variant], workers: int, rounds: int) -> None:
    for var in variants:  # compile and warm every variant
        time_view(cases[0], var, workers)
    per_round = np.zeros((rounds, len(variants), len(PHASES)))  # mean ms per view
    for r in range(rounds):
        order = list(range(len(variants)))[:: 1 if r % 2 == 0 else -1]
        for c in cases:
            for i in order:
                per_round[r, i] += time_view(c, variants[i], workers) * 1e3 / len(cases)
    base = variants[0].name
    print(f"\n## {len(cases)} views, {workers} thread(s), {rounds} rounds: median ms per view, "
          f"and per-round ratios to {base}")
    for i, var in enumerate(variants):
        for k, phase in enumerate(PHASES):
            ms = per_round[:, i, k]
            ratio = ms / per_round[:, 0, k]
            run.record_all(var.name, {f"{phase} ms": float(np.median(ms)),
                                      f"{phase} ratio to {base} (median)": float(np.median(ratio)),
                                      f"{phase} ratio to {base} (max)": float(ratio.max())},
                           {f"{phase} ms": "ms"}, {"threads": workers, "rounds": rounds, "views": len(cases)})
            print(f"  {var.name:26s} {phase:19s} {np.median(ms):7.2f} ms   ratio "
                  + " ".join(f"{x:.3f}" for x in ratio))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("posed", type=Path, help="a PosedClip folder (a work folder's metric stage)")
    ap.add_argument("splats", type=Path, help="the splats.ply the recon stage made from it")
    ap.add_argument("--variants", type=parse_variant, nargs="+",
                    default=[parse_variant(v) for v in ("16", "32", "32:nomedian")],
                    help="EDGE or EDGE:nomedian per variant; ratios are to the first")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--every", type=int, default=6, help="time every k-th training view")
    add_run_args(ap)
    a = ap.parse_args()
    if not (a.posed / "cameras.parquet").is_file():
        raise SystemExit(f"{a.posed}: not a PosedClip folder (cameras.parquet missing)")
    if not a.splats.is_file():
        raise SystemExit(f"{a.splats}: no such splat file")
    if any(not 1 <= v.tile <= MAX_TILE for v in a.variants):
        raise SystemExit(f"--variants: tile edges run from 1 to {MAX_TILE} px (the kernels' MAX_TILE)")
    if a.threads < 1 or a.rounds < 1 or a.every < 1:
        raise SystemExit("--threads, --rounds and --every must be at least 1")
    numba.set_num_threads(min(a.threads, numba.config.NUMBA_NUM_THREADS))
    with Run("train_composite", a) as run:
        cases = view_cases(a.posed, a.splats, a.every)
        measure(run, cases, a.variants, numba.get_num_threads(), a.rounds)


if __name__ == "__main__":
    main()
