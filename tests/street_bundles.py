"""Ground-truth street bundles for the env tests: the 1-s synthetic street, and renamed copies
that a test then alters (walkable map, collision mesh)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from vid2sim.factory.synthetic import GTBundleConfig, generate_street, preset, render_video, write_ground_truth_bundle


def street_bundle(root: Path, seed: int = 11, n_splats: int = 20_000) -> Path:
    """GT bundle of the `test` preset's street `seed` (1 s clip) under root/bundle."""
    conf = preset("test", seed=seed)
    scene = generate_street(conf)
    clip = render_video(scene, conf, root / "clip")
    return write_ground_truth_bundle(scene, clip, root / "bundle", GTBundleConfig(n_splats=n_splats))


def renamed_copy(bundle: Path, out: Path, scene_id: str) -> Path:
    """A copy of `bundle` at `out` whose scene.json names `scene_id`."""
    shutil.copytree(bundle, out)
    meta = json.loads((out / "scene.json").read_text())
    meta["scene_id"] = scene_id
    (out / "scene.json").write_text(json.dumps(meta))
    return out
