"""Synthetic sidewalk street with exact ground truth (poses, depth, mesh, walkable area).

    conf = StreetConfig(seed=3)
    scene = generate_street(conf)
    clip = render_video(scene, conf, "work/synthetic")
    write_ground_truth_bundle(scene, clip, "work/gt_bundle")
"""

from vid2sim.factory.synthetic.config import PRESETS, StreetConfig, preset, varied
from vid2sim.factory.synthetic.render import SyntheticClip, StreetRenderer, intrinsics, render_video
from vid2sim.factory.synthetic.street import Obstacle, StreetScene, generate_street

__all__ = ["PRESETS", "StreetConfig", "preset", "varied", "SyntheticClip", "StreetRenderer", "intrinsics",
           "render_video", "Obstacle", "StreetScene", "generate_street"]

from vid2sim.factory.synthetic.gt_bundle import GTBundleConfig, write_ground_truth_bundle  # noqa: E402

__all__ += ["GTBundleConfig", "write_ground_truth_bundle"]
