"""Build a registry of synthetic-street ground-truth bundles (one per seed) for training figures.

    python benchmarks/street_registry.py ROOT --seeds 1 2 3 4 5 6 [--splats 20000]

Each street is a distinct scene and its own source group, so the registry's split is leak-free.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from vid2sim.factory.synthetic import GTBundleConfig, generate_street, preset, render_video, write_ground_truth_bundle
from vid2sim.registry import Registry, RegistryNotFound


def build(root: Path, seeds: list[int], n_splats: int = 20_000, preset_name: str = "test") -> Registry:
    reg = Registry(root / "registry")
    try:
        have = {r.scene_id for r in reg.list()}
    except RegistryNotFound:  # a fresh root: the first `add` creates the registry
        have = set()
    for seed in seeds:
        if f"synthetic-street-s{seed}" in have:
            continue
        t0 = time.perf_counter()
        conf = preset(preset_name, seed=seed)
        scene = generate_street(conf)
        clip = render_video(scene, conf, root / "work" / f"clip{seed}")
        bundle = write_ground_truth_bundle(scene, clip, root / "work" / f"bundle{seed}", GTBundleConfig(n_splats=n_splats))
        reg.add(bundle)
        print(f"seed {seed}: added in {time.perf_counter() - t0:.1f} s", flush=True)
    return reg


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("root", type=Path)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5, 6])
    ap.add_argument("--splats", type=int, default=20_000)
    args = ap.parse_args()
    reg = build(args.root, args.seeds, args.splats)
    print(sorted(r.scene_id for r in reg.list()))


if __name__ == "__main__":
    main()
