"""The valid range of every numeric config field, and the walk that checks a config against them.

A field's range comes from its name (the leaf of its dotted path), by the first rule that names it:
  - signed: offsets, thresholds and directions that may be negative (`ground_z_m`, `reward.failure`,
    `pitch_deg`, `sun_direction`, ...);
  - unit: probabilities and fractions in [0, 1] (`*_prob`, `*fraction`, `gamma`, `tau`, ...);
  - positive: sizes, rates and lengths that must be > 0 (`fps`, `resolution_m`, `capture_height_m`, ...);
  - counts: iterations, batch sizes, envs, trials, widths, ... that must be >= 1;
  - everything else: >= 0.
Some add an upper bound (`jpeg_quality` <= 100, `video_crf` <= 51, grey levels <= 255, `frames` <= 6,
angles below 180 deg, ports, and image sizes that decide an allocation: `width` / `height` <= 8192).
Every float must be finite. Items of a tuple / list field take the field's range; None is allowed
where the type is Optional. `check_ranges(config)` raises `RangeError` naming the dotted path.

A config class decorated with `@checked` checks itself whenever it is built (its constructor,
`dataclasses.replace`, a `from_dict` / `load`), so the Python API refuses what the command line
refuses: `DistillConfig(batch_size=0)` raises `RangeError: DistillConfig.batch_size: 0 is out of
range (must be >= 1)`. `CHECKED` lists those classes (`tests/test_config_ranges.py` walks them).
This module sits in the base layer, so every package's configs can use it.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Optional, TypeVar

T = TypeVar("T")


class RangeError(ValueError):
    """A numeric config field (or option) is outside its valid range or not finite."""


@dataclass(frozen=True)
class Range:
    """lo <= v <= hi (lo < v when lo_open); None: unbounded on that side."""

    lo: Optional[float] = 0
    hi: Optional[float] = None
    lo_open: bool = False

    def holds(self, v: float) -> bool:
        if isinstance(v, float) and not math.isfinite(v):
            return False
        above = self.lo is None or (v > self.lo if self.lo_open else v >= self.lo)
        return above and (self.hi is None or v <= self.hi)

    def describe(self, finite: bool = True) -> str:
        parts = ["finite"] if finite else []
        parts += [] if self.lo is None else [f"{'>' if self.lo_open else '>='} {self.lo:g}"]
        parts += [] if self.hi is None else [f"<= {self.hi:g}"]
        return " and ".join(parts) or "any integer"


SIGNED = {"ground_z_m": None, "failure": None, "exposure_ev": None, "score_threshold": None,
          "camera_params": None, "first_octave": -1, "sde_sample_freq": -1, "min_ncc": -1,
          "pitch_deg": -90, "yaw_deg": None, "sun_direction": -1}
UNIT = re.compile(r"(_prob|fraction)$|^(gamma|tau|beta0|beta_decay|min_beta|keep_mass|view_keep_mass|t_stop|"
                  r"lambda_dssim|min_alpha|max_dynamic|min_area|people_min_motion|segment_min_motion|min_opacity|"
                  r"static_fraction|walk_lateral)$")
POSITIVE = re.compile(r"^(fps|image_fps|fallback_fps|clip_seconds|learning_rate|capture_height_m|wheelbase|"
                      r"max_speed|length|width|height|vfov_deg|near|far|depth_max|success_radius|step_m|"
                      r"area_spacing_m|bin_m|along_m|trunc_voxels|ground_point_cell_m|depth_max_m|timeout_s|"
                      r"resolution_m|map_resolution_m|voxel_m|scale|num_cpus_per_run|num_cpus_per_actor|coarse_scale|"
                      r"hfov_deg|length_m|duration_s|gt_grid_resolution|lookahead|teacher_lookahead|steer_gain)$")
COUNTS = re.compile(r"^(iterations|batch_size|n_envs|trials|total_steps|frame_stack|physics_hz|control_hz|"
                    r"max_side|analysis_width|workers|max_image_size|max_num_features|overlap|num_threads|"
                    r"ransac_iters|max_width|sh_increase_every|checkpoint_every|every|"
                    r"opacity_reset_every|num_planes|ncc_window|ncc_patch|ncc_stride|normal_pca_window|"
                    r"pixel_stride|views|cell_size|steps_per_round|updates_per_round|max_samples|"
                    r"train_max_steps|frames|frame_stride|vector_history|pool|frame_dim|vector_dim|hidden|image_dim|train_freq|"
                    r"gradient_steps|buffer_size|max_steps|seeds|counts|episodes|max_rows|"
                    r"max_gaussians|max_init_points|target_faces|visual_target_faces|net_arch|channels|"
                    r"consistency_views|min_frames|min_ground_points|stuck_steps|eval_max_steps|train_scenes|"
                    r"n_steers|n_splats|min_chars|block_px)$")
UPPER = {"jpeg_quality": 100, "fog_color": 255, "frames": 6, "vector_history": 6, "sh_degree": 3, "port": 65535,
         "vfov_deg": 179, "max_steer_deg": 89, "max_tilt_deg": 90, "ground_normal_deg": 90,
         "static_min_tri_angle_deg": 180, "view_heading_deg": 180, "start_yaw_noise_deg": 180, "hfov_deg": 179,
         # sizes that decide an allocation (an image, a frame stack) are capped too
         "width": 8192, "height": 8192, "max_side": 16384, "max_image_size": 16384, "analysis_width": 8192,
         "max_width": 8192, "frame_stack": 64,
         "pitch_deg": 90, "sun_direction": 1, "roll_deg": 180, "coarse_scale": 1, "black_level": 255,
         "video_crf": 51}


def field_range(name: str) -> Range:
    """The range of a numeric field called `name` (the leaf of its path)."""
    hi = UPPER.get(name)
    if name in SIGNED:
        return Range(SIGNED[name], hi)
    if UNIT.search(name):
        return Range(0, 1 if hi is None else hi)
    if POSITIVE.match(name):
        return Range(0, hi, lo_open=True)
    if COUNTS.match(name):
        return Range(1, hi)
    return Range(0, hi)


def _numbers(value: Any) -> Iterator[float]:
    """The numbers a field holds: itself, or the items of a tuple / list (bools are not numbers)."""
    items = value if isinstance(value, (tuple, list)) else [value]
    for v in items:
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            yield v


def numeric_fields(config: Any, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """(dotted path, value) of every field of a dataclass instance that holds numbers, nested ones
    followed into."""
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            yield from numeric_fields(value, f"{prefix}{f.name}.")
        elif any(True for _ in _numbers(value)):
            yield f"{prefix}{f.name}", value


def check_value(path: str, value: Any) -> Any:
    """`value` of the field at dotted `path` unchanged; RangeError when a number of it is out of range."""
    rng = field_range(path.rsplit(".", 1)[-1])
    bad = [v for v in _numbers(value) if not rng.holds(v)]
    if bad:
        finite = any(isinstance(v, float) for v in _numbers(value))
        raise RangeError(f"{path}: {bad[0]!r} is out of range (must be {rng.describe(finite)})")
    return value


def check_ranges(config: Any, prefix: str = "") -> Any:
    """`config` unchanged; RangeError naming the first field outside its range."""
    for path, value in numeric_fields(config, prefix):
        check_value(path, value)
    return config


CHECKED: list[type] = []  # the config classes that check their ranges whenever they are built


def checked(cls: type[T]) -> type[T]:
    """Class decorator for a config dataclass: building it checks every numeric field (nested configs
    included) and raises `RangeError` naming `Class.field`; before the class's own `__post_init__`,
    so its cross-field checks see values inside their ranges."""
    post = getattr(cls, "__post_init__", None)
    if post is not None:
        @functools.wraps(post)
        def __post_init__(self: Any, *args: Any) -> None:
            check_ranges(self, f"{type(self).__name__}.")
            post(self, *args)

        cls.__post_init__ = __post_init__  # type: ignore[attr-defined]
    else:
        init: Callable[..., None] = cls.__init__  # type: ignore[misc]

        @functools.wraps(init)
        def __init__(self: Any, *args: Any, **kwargs: Any) -> None:
            init(self, *args, **kwargs)
            check_ranges(self, f"{type(self).__name__}.")

        cls.__init__ = __init__  # type: ignore[misc]
    CHECKED.append(cls)
    return cls
