"""Real factory scenes for the env render benchmark, built once and cached outside the repo.

    .venv/bin/python benchmarks/env_scenes.py [demo] [gopro] [--refresh]   # build (or find) the cached bundles

`--refresh` ingests again into the same work folder: the stage cache keeps every stage whose
key is unchanged and reruns the rest (e.g. a new walkable-stage version), committing the new
bundle; it prints the registry root and scene id for `benchmarks/envs.py --factory ROOT ID`, and
how far the cells the envs may put the robot on stay from collision surface in the robot's band.

`demo`: the `make demo` street (synthetic 10 s 854x480 video -> fast-preset ingest).
`gopro`: the shared GoPro MAX sidewalk clip (`../shared/data`, skipped when absent).
The cache root is `$VID2SIM_CACHE/env_render` (default `~/.cache/vid2sim/env_render`); each scene's
bundle folder is `<root>/<name>/clips/<clip>/bundle/scene` (found by its `scene.json`).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Optional

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

DATA = Path(os.environ.get("VID2SIM_SHARED_DATA", ROOT.parent / "shared" / "data"))
CACHE = Path(os.environ.get("VID2SIM_CACHE", Path.home() / ".cache" / "vid2sim")) / "env_render"
GOPRO = DATA / "gopro_max_sidewalk" / "max-heromode.mp4"


def find_bundle(name: str) -> Optional[Path]:
    """The cached bundle folder of scene `name`, or None when it was not built yet."""
    hits = sorted((CACHE / name).glob("clips/**/scene.json"))
    return hits[0].parent if hits else None


def _ingest(name: str, video: str, licence: str, capture_height: float) -> Path:
    from vid2sim.factory.runtime.pipeline import bundle_path, ingest, preset

    work = CACHE / name
    report = ingest([video], str(work / "registry"), workdir=work / "clips", conf=preset("fast"),
                    num_cpus=2, licence=licence, capture_height=capture_height)
    res = report.results[0]
    if not res.ok:
        raise RuntimeError(f"{name}: failed at {res.failed_stage}: {res.reason}")
    return bundle_path(res.work)


def build(name: str, refresh: bool = False) -> Optional[Path]:
    """Build scene `name` ('demo' or 'gopro') once; returns its bundle folder (None: no data).
    refresh: ingest again (cached stages are kept, changed ones rerun)."""
    hit = find_bundle(name)
    if hit is not None and not refresh:
        return hit
    t0 = time.perf_counter()
    if name == "demo":
        from vid2sim.factory.synthetic.config import preset as street_preset
        from vid2sim.factory.synthetic.make_street import main as make_street

        street = street_preset("demo", seed=0)
        video = CACHE / name / "synthetic" / "video.mp4"
        if not video.is_file():
            video = make_street(street, CACHE / name / "synthetic") / "video.mp4"
        out = _ingest(name, str(video), "CC0-synthetic", street.capture_height)
    elif name == "gopro":
        if not GOPRO.is_file():
            print(f"SKIP gopro: {GOPRO} is absent (../shared/data beside the project)")
            return None
        out = _ingest(name, str(GOPRO), "Apache-2.0 OR MIT", 1.5)
    else:
        raise ValueError(f"unknown scene {name!r} (demo, gopro)")
    print(f"built {name} in {time.perf_counter() - t0:.0f} s: {out}")
    return out


def agreement(bundle: Path) -> str:
    """Map vs physics, in words (agreement_figures)."""
    f = agreement_figures(bundle)
    return (f"{f['planner_cells']} planner cells; nearest collision surface in the robot's {f['band_low_m']:.2f}-"
            f"{f['band_high_m']:.2f} m band: {f['nearest_surface_m']:.3f} m (robot half-width "
            f"{f['robot_half_width_m']:.2f} m)")


def agreement_figures(bundle: Path) -> dict:
    """Map vs physics: the smallest horizontal distance from a cell the envs may put the robot
    on (planner map) to collision-mesh surface inside the robot box's height band."""
    import numpy as np
    import trimesh
    from scipy.spatial import cKDTree

    from vid2sim.envs.config import EpisodeConfig, RobotConfig
    from vid2sim.envs.planning import GridPlanner
    from vid2sim.envs.scenes import walkable_inflation
    from vid2sim.factory.geometry.surface_sampling import points_by_spacing
    from vid2sim.formats.scene import read_scene_json
    from vid2sim.formats.walkable import load_walkable

    robot, clearance = RobotConfig(), EpisodeConfig().clearance
    pre = walkable_inflation(read_scene_json(bundle / "scene.json"))
    planner = GridPlanner(load_walkable(bundle / "walkable.npz"), clearance=max(clearance - pre, 0.0))
    rows, cols = np.nonzero(planner.free)
    mesh = trimesh.load(bundle / "collision.ply", force="mesh", process=False)
    pts = points_by_spacing(np.asarray(mesh.vertices), np.asarray(mesh.faces), 0.02)  # [P, 3]
    lo, hi = robot.ground_clearance, robot.ground_clearance + robot.height
    band = pts[(pts[:, 2] >= lo) & (pts[:, 2] <= hi)]
    d = cKDTree(band[:, :2]).query(planner.to_world(rows, cols))[0] if len(band) else [np.inf]
    return {"planner_cells": len(rows), "nearest_surface_m": float(np.min(d)), "band_low_m": lo,
            "band_high_m": hi, "robot_half_width_m": robot.width / 2}


def scene_id(bundle: Path) -> str:
    import json

    return json.loads((bundle / "scene.json").read_text())["scene_id"]


def main() -> None:
    import argparse

    from common import Run, add_run_args  # benchmarks/common.py

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", default=["demo", "gopro"], help="demo, gopro")
    ap.add_argument("--refresh", action="store_true", help="ingest again (cached stages are kept)")
    add_run_args(ap)
    args = ap.parse_args()
    with Run("env_scenes", args, config={"cache": str(CACHE)}) as run:
        for n in args.names or ["demo", "gopro"]:
            cached = find_bundle(n) is not None and not args.refresh
            t0 = time.perf_counter()
            b = build(n, refresh=args.refresh)
            if b is None:
                run.note(f"skipped {n}: its data is absent")
                print(n, b)
                continue
            run.record_all(f"{n}: build", {"seconds": time.perf_counter() - t0, "cached": cached}, {"seconds": "s"},
                           {"refresh": args.refresh})
            print(n, b, f"--factory {CACHE / n / 'registry'} {scene_id(b)}")
            f = agreement_figures(b)
            run.record_all(f"{n}: map vs physics", {k: f[k] for k in ("planner_cells", "nearest_surface_m")},
                           {"nearest_surface_m": "m"},
                           {k: f[k] for k in ("band_low_m", "band_high_m", "robot_half_width_m")})
            print(f"{n} map vs physics: {agreement(b)}")


if __name__ == "__main__":
    main()
