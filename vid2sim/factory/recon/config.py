"""Reconstruction configs (nerfstudio style): one dataclass per component and named presets.

Every run saves its `ReconConfig` as `config.json` beside the result (see trainer.py).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from vid2sim.ranges import checked
from vid2sim.versioning import from_jsonable, to_jsonable


@checked
@dataclass
class DepthPriorConfig:
    """Which depth prior supervises the geometry losses.

    kind: "mvs" (default, no weights: plane-sweep stereo over neighbouring posed frames),
          "depth_anything" (Depth-Anything-V2 via transformers from `checkpoint`, a local path),
          "none" (plain 3DGS; geometry losses that need a prior are off).
    """

    kind: str = "mvs"  # "mvs" | "depth_anything" | "none" (see above)
    # --- mvs (plane sweep with NCC) ---
    neighbours: int = 4  # nearest frames (by index) on each side are candidates; best `neighbours` used
    num_planes: int = 48  # inverse-depth hypotheses between the near and far bound
    ncc_window: int = 7  # NCC window (pixels, odd)
    min_ncc: float = 0.5  # confidence threshold on the best matching score
    near_far_percentiles: tuple = (2.0, 98.0)  # depth range from sparse points seen by the frame
    max_width: int = 256  # plane sweep runs at most at this width (then upsampled)
    # geometric consistency (`depth_prior.consistent_mask`, as COLMAP's fusion): a confident
    # pixel stays confident when its depth, projected into at least `min_consistent` of the
    # `consistency_views` nearest training views on each side, lands within `consistency_rel`
    # (relative) of that view's own confident prior depth. Plane-sweep NCC is confidently wrong
    # on uniform surfaces and under forward motion: on the demo street 18 % of the confident
    # prior pixels were > 20 % off (the first frames' median 42 %, a parked car placed 1.5-5x too
    # far, which pulled the splats 20 % too far); with the check 2.9 %, keeping 76 %
    # (docs/studies/physical_layer.md).
    # 0 disables
    consistency_rel: float = 0.05
    consistency_views: int = 3  # nearest training views on each side a prior depth is checked against
    min_consistent: int = 2  # views (of those 2 x consistency_views) that must agree
    # --- depth_anything ---
    checkpoint: Optional[str] = None  # local folder with a transformers Depth-Anything-V2 model
    device: str = "cpu"  # torch device the Depth-Anything model runs on


@checked
@dataclass
class DensifyConfig:
    """AbsGS densification (3DGS schedule; thresholds in 3DGS NDC units)."""

    start_iter: int = 500  # first iteration that densifies
    stop_iter: int = 15_000  # last densification (a final low-opacity prune runs here)
    every: int = 100  # densify and prune every n iterations (opacity resets on multiples of opacity_reset_every)
    grad_threshold: float = 0.0002  # clone: mean plain 2D gradient norm
    absgrad_threshold: float = 0.0008  # split: mean absolute (AbsGS) 2D gradient norm
    percent_dense: float = 0.01  # clone if max scale <= this * extent, else split
    opacity_reset_every: int = 3000  # iterations between opacity resets
    min_opacity: float = 0.005  # Gaussians below this opacity are pruned
    max_screen_radius: float = 20.0  # pixels, at the training resolution (after first reset)
    max_world_scale: float = 0.1  # fraction of scene extent
    max_gaussians: int = 1_000_000  # densification stops growing the model at this count


@checked
@dataclass
class LossConfig:
    """Loss weights (paper eq. 5: all geometry weights 1) and options."""

    lambda_dssim: float = 0.2  # RGB loss = (1 - lambda) L1 + lambda D-SSIM
    w_depth: float = 1.0  # weight of the patch-NCC depth loss against the prior
    w_normal: float = 1.0  # weight of the normal loss against the prior's PCA normals
    w_geo: float = 1.0  # weight of the geometry-consistency loss (neighbouring normals agree where depth is smooth)
    w_scale: float = 1.0  # weight of the flat-Gaussian (smallest scale) loss
    geometry: bool = True  # depth / normal / geo / scale losses on
    geometry_from_iter: int = 500  # paper: from iteration 500 to the end
    ncc_patch: int = 8  # K (patch K x K)
    ncc_stride: int = 4  # patches every `stride` pixels (overlapping when < K)
    normal_pca_window: int = 5  # PCA neighbourhood for prior normals (pixels, odd)


@checked
@dataclass
class LRConfig:
    """3DGS learning rates; means are scaled by the scene extent and decay exponentially."""

    means: float = 1.6e-4  # positions at the start (x scene extent)
    means_final: float = 1.6e-6  # positions at the last iteration (x scene extent)
    sh0: float = 2.5e-3  # base colour (degree-0 SH)
    shN: float = 2.5e-3 / 20  # higher SH degrees
    opacity: float = 0.05  # opacity logits
    scales: float = 5e-3  # log scales
    quats: float = 1e-3  # rotations


@checked
@dataclass
class ReconConfig:
    """Geometry-consistent Gaussian-splat reconstruction of one PosedClip."""

    preset: str = "fast"  # name of the preset this config started from (a label saved with the result)
    iterations: int = 2000  # optimisation steps (one training view each)
    max_width: int = 200  # training/eval images are downscaled to at most this width
    sh_degree: int = 3  # spherical-harmonics degree of the view-dependent colour
    sh_increase_every: int = 1000  # iterations per active SH degree step (0 up to sh_degree)
    background: tuple = (0.0, 0.0, 0.0)  # RGB in [0, 1] behind the splats
    backend: str = "auto"  # renderer backend: "auto" | "torch" | "cpu" | "cuda"
    max_init_points: int = 100_000  # SfM points the Gaussians start from, at most (random subset)
    seed: int = 0  # torch / numpy seed (initial point subset, view order)
    checkpoint_every: int = 500  # iterations between checkpoints (a re-run resumes from the last; >= iterations: none)
    eval_max_frames: int = 0  # 0 = every held-out frame
    # coarse-to-fine: the first `coarse_iterations` steps render at `coarse_scale` x the training
    # resolution (images, masks, intrinsics and priors downscaled alike); 0 = off
    coarse_iterations: int = 0
    coarse_scale: float = 0.5  # fraction of the training width (and height) while coarse
    # stop at convergence: every `holdout_every` steps the held-out frames' masked L1 is measured;
    # from `densify.stop_iter` on, training stops once `holdout_patience` checks in a row
    # improve on the best by less than `holdout_min_delta` (relative). 0 = run every iteration
    holdout_every: int = 0
    holdout_patience: int = 2  # checks without improvement before stopping
    holdout_min_delta: float = 0.002  # relative L1 improvement that counts
    lr: LRConfig = field(default_factory=LRConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    prior: DepthPriorConfig = field(default_factory=DepthPriorConfig)

    @property
    def uses_geometry(self) -> bool:
        return self.loss.geometry

    def to_dict(self) -> dict:
        return to_jsonable(self)

    def save(self, path: Path) -> Path:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2))
        return Path(path)

    @classmethod
    def from_dict(cls, data: dict) -> "ReconConfig":
        return from_jsonable(cls, data)

    @classmethod
    def load(cls, path: Path) -> "ReconConfig":
        return cls.from_dict(json.loads(Path(path).read_text()))


def fast() -> ReconConfig:
    """Minutes on 2 CPU cores: ~1/3 resolution, 1.5k iterations, 150k Gaussian cap, no opacity reset.

    Densification runs from iteration 300 until 1000 and no opacity reset happens (resets run with
    the densification, `start_iter <= it < stop_iter`, so the one at 1000 never fires). Until
    2026-12-01 it densified until 1500 with a reset at 1000 over 2000 iterations; the reset cost
    1.1-1.2 dB of held-out PSNR on the GoPro clip, and without it 1500 iterations beat the old
    2000: demo street 31.77 -> 32.41 dB, walkable IoU 0.841 -> 0.851, collision accuracy median
    0.052 -> 0.047 m, recon 1.38x faster (docs/studies/reconstruction_time.md).

    320 px wide (was 160 until f666213): on the demo street's splats the collision mesh's
    accuracy median goes 0.049 -> 0.038 m, completeness 86.1 -> 87.7 % and the walkable IoU
    0.809 -> 0.847, at about twice the training time (docs/studies/physical_layer.md; the GoPro clip's path
    holds with the walkable stage's carved-piece rule); 240 px gave less, 3000 iterations at
    160 px nothing. Not a win on every street: a second 854 px street trades accuracy for
    completeness, a 4 s 640 px clip loses on every figure.
    """
    return ReconConfig(
        preset="fast", iterations=1500, max_width=320, sh_degree=2, sh_increase_every=500,
        checkpoint_every=500,
        lr=LRConfig(means=1.6e-4 * 2, means_final=1.6e-6 * 2),
        # At this budget and resolution the plane-sweep prior (and its PCA normals) is noisy;
        # weights 1 (paper) cost ~1-2 dB held-out PSNR, these keep the depth gain (see
        # benchmarks/reconstruction.py). The `paper` preset keeps the paper's weights of 1.
        loss=LossConfig(geometry_from_iter=300, ncc_patch=8, ncc_stride=4,
                        w_depth=0.05, w_normal=0.01, w_geo=0.05, w_scale=0.01),
        densify=DensifyConfig(start_iter=300, stop_iter=1000, every=100, opacity_reset_every=1000,
                              max_gaussians=150_000),
        prior=DepthPriorConfig(kind="mvs", num_planes=48, max_width=320),
    )


def quick() -> ReconConfig:
    """`fast`'s losses, resolution and prior on the schedule `fast` had until 2026-12-01 (2000
    iterations, an opacity reset at 1000), made cheaper: the first 1000 iterations at half
    resolution (coarse-to-fine), densification until 1200 (half the Gaussians), then training
    stops once two held-out checks 100 iterations apart gain < 0.2 % L1 (at most 2000). Since
    `fast` dropped the reset it is about as quick as this and better; `quick` stays as it was
    for the reconstructions measured with it (`benchmarks/sim2real.py`). Measured against the
    old `fast`:

    GoPro clip (105 frames, 320x150), process CPU of the training loop: fast 322 s, 82.3k
    Gaussians, held-out PSNR 27.06 dB / SSIM 0.854 (static pixels 28.83 dB); quick 215 s (1.5x),
    40.3k, 26.81 dB / 0.842 (static 28.94 dB). The held-out L1 still fell 0.7-1.8 % per 100
    iterations from 1500 to 2000 (the means' learning rate decays over the whole run), so the
    stop did not fire there; the same schedule cut to 1600 iterations (150 s) lost 0.86 dB.
    Demo street: recon CPU 437 -> 319 s, PSNR 31.86 -> 31.28 dB (over the 0.3 dB budget), walkable
    IoU 0.834 -> 0.877 (docs/results.md), so it is opt-in.
    `benchmarks/pipeline.py speed` compares it with `fast` stage by stage and on the walked
    corridor and, on the demo street, walkable IoU against ground truth.
    """
    base = fast()
    return dataclasses.replace(
        base, preset="quick", iterations=2000, coarse_iterations=1000, coarse_scale=0.5,
        holdout_every=100, holdout_patience=2, holdout_min_delta=0.002,
        densify=dataclasses.replace(base.densify, stop_iter=1200))


def paper() -> ReconConfig:
    """Paper: 30k iterations, 3DGS hyper-parameters, AbsGS, geometry losses from iteration 500."""
    return ReconConfig(
        preset="paper", iterations=30_000, max_width=1600, sh_degree=3, sh_increase_every=1000,
        checkpoint_every=5000,
        loss=LossConfig(geometry_from_iter=500),
        densify=DensifyConfig(start_iter=500, stop_iter=15_000, every=100, opacity_reset_every=3000,
                              max_gaussians=3_000_000),
        prior=DepthPriorConfig(kind="mvs", num_planes=96, max_width=640),
    )


PRESETS = {"fast": fast, "quick": quick, "paper": paper}


def preset(name: str, **overrides: Any) -> ReconConfig:
    """A named preset; `overrides` replace top-level fields."""
    if name not in PRESETS:
        raise ValueError(f"unknown reconstruction preset {name!r}; choose one of {sorted(PRESETS)}")
    return dataclasses.replace(PRESETS[name](), **overrides)


def baseline(conf: ReconConfig) -> ReconConfig:
    """Plain 3DGS at the same budget: no depth prior, no geometry losses."""
    return dataclasses.replace(conf, loss=dataclasses.replace(conf.loss, geometry=False),
                               prior=dataclasses.replace(conf.prior, kind="none"))
