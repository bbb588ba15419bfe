"""Stage entry: a synthetic clip (and optionally its GT bundle) from a config, skipping done work."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from vid2sim.factory.synthetic.gt_bundle import GTBundleConfig, write_ground_truth_bundle
from vid2sim.factory.synthetic.config import StreetConfig
from vid2sim.factory.synthetic.render import render_video
from vid2sim.factory.synthetic.street import generate_street


def main(conf: StreetConfig, out_dir: Path, bundle_dir: Optional[Path] = None,
         bundle_conf: GTBundleConfig = GTBundleConfig()) -> Path:
    """Render the street for `conf` into out_dir (a finished render is reused); write the GT bundle
    into bundle_dir when given. Returns out_dir."""
    scene = generate_street(conf)
    clip = render_video(scene, conf, Path(out_dir))
    if bundle_dir is not None:
        write_ground_truth_bundle(scene, clip, Path(bundle_dir), bundle_conf)
    return Path(out_dir)
