"""Build a registry of synthetic-street ground-truth bundles (one per seed) for training figures.

    python benchmarks/street_registry.py ROOT --seeds 1 2 3 4 5 6 [--splats 20000]
    python benchmarks/street_registry.py --quick    # one street into a temp folder, timed
    python benchmarks/street_registry.py ROOT --seeds $(seq 1 40) --vary   # 40 streets that differ

Each street is a distinct scene and its own source group, so the registry's split is leak-free.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any, Optional

from vid2sim.factory.synthetic import (GTBundleConfig, generate_street, preset, render_video, varied,
                                       write_ground_truth_bundle)
from vid2sim.registry import Registry, RegistryNotFound


def scene_id(seed: int, vary: bool) -> str:
    return f"street-v{seed}" if vary else f"synthetic-street-s{seed}"


def build(root: Path, seeds: list[int], n_splats: int = 20_000, preset_name: str = "test",
          run: Optional[Any] = None, vary: bool = False) -> Registry:
    """Adds the streets of `seeds` that the registry under root lacks; run: a benchmarks/common.py
    Run recording each added street's seconds. `vary`: layout, furniture and light drawn from the
    seed too (`synthetic.varied`; scene ids street-vN), for the training studies."""
    reg = Registry(root / "registry")
    try:
        have = {r.scene_id for r in reg.list()}
    except RegistryNotFound:  # a fresh root: the first `add` creates the registry
        have = set()
    for seed in seeds:
        if scene_id(seed, vary) in have:
            continue
        t0 = time.perf_counter()
        conf = varied(seed, preset_name) if vary else preset(preset_name, seed=seed)
        scene = generate_street(conf)
        clip = render_video(scene, conf, root / "work" / f"clip{seed}")
        bundle = write_ground_truth_bundle(scene, clip, root / "work" / f"bundle{seed}",
                                           GTBundleConfig(n_splats=n_splats, scene_id=scene_id(seed, vary)))
        reg.add(bundle)
        seconds = time.perf_counter() - t0
        if run is not None:
            run.record(f"{scene_id(seed, vary)}, {preset_name} preset, {n_splats} splats", "build_and_add_s",
                       seconds, "s", {"seed": seed, "preset": preset_name, "n_splats": n_splats, "vary": vary})
        print(f"seed {seed}: added in {seconds:.1f} s", flush=True)
    return reg


def main() -> None:
    from common import Run, add_run_args  # benchmarks/common.py (build() is imported by tests too)

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("root", type=Path, nargs="?", default=None,
                    help="registry + work folder (default: a temp folder, removed after)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5, 6])
    ap.add_argument("--splats", type=int, default=20_000)
    ap.add_argument("--quick", action="store_true", help="seed 1 only (smoke run)")
    ap.add_argument("--vary", action="store_true", help="layout, furniture and light drawn from the seed too")
    add_run_args(ap)
    args = ap.parse_args()
    seeds = [1] if args.quick and args.seeds == [1, 2, 3, 4, 5, 6] else args.seeds
    root = args.root or Path(tempfile.mkdtemp(prefix="vid2sim-bench-streets-"))
    try:
        with Run("street_registry", args) as run:
            reg = build(root, seeds, args.splats, run=run, vary=args.vary)
            print(sorted(r.scene_id for r in reg.list()))
    finally:
        if args.root is None:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
