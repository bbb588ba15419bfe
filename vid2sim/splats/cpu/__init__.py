"""`cpu` splat backend: numba tile rasteriser with a hand-written backward.

`rasterize(...)` follows docs/splat_renderer.md (differentiable, fills grad2d/absgrad);
`StaticScene(model).render(camera, settings, background)` is the forward-only env path.
Threads: numba.set_num_threads(n) bounds every kernel.
"""

from .function import rasterize
from .static import StaticScene, StaticSceneConfig

__all__ = ["rasterize", "StaticScene", "StaticSceneConfig"]
