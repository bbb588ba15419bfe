"""`cpu` splat backend: numba tile rasteriser with a hand-written backward.

`rasterize(...)` follows docs/splat_renderer.md (differentiable, fills grad2d/absgrad);
`StaticScene(model).render(camera, settings, background)` is the forward-only env path.
Threads: numba.set_num_threads(n) bounds every kernel.

Modules by role:
- training (differentiable): `train_rasterize` (the autograd Function: forward, backward).
- shared by training and the exact env path: `project` (per-splat projection and its VJP,
  the projected record's columns, `camera_arrays`), `binning` (depth sort and tile lists),
  `composite` (per-tile blend forward and its backward); `_geom`, `_sh`, `_expf`, `_bits`,
  `_sched` (scalar maths, bit intrinsics, work sharing).
- env, exact: `env_scene` (`StaticScene`) with `env_scene_kernels` (cell culling, cached
  projection, finish) and `env_lod` (opt-in level of detail); `env_frame` (one whole frame
  per numba call) and `env_batch` (`SceneBatch`: many cameras per call).
- env, approximate: `env_fast_frame` (the fast kernels), `env_fast_batch` (`FastBatch`),
  `env_fast_view` (`FastView`: one camera straight to the envs' outputs).
- env, made once per scene: `env_simready` (the sim-ready splat set), `env_simfit` (its fit).
- `synthetic`: scenes and cameras for tests and benchmarks.
"""

from .env_batch import EnvFrames, SceneBatch
from .env_fast_batch import FastBatch
from .env_fast_view import FastView
from .env_scene import StaticScene, StaticSceneConfig
from .train_rasterize import rasterize

__all__ = ["rasterize", "StaticScene", "StaticSceneConfig", "SceneBatch", "EnvFrames", "FastBatch",
           "FastView"]
