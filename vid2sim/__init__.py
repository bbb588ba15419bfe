"""Vid2Sim factory: monocular walking videos -> simulation-ready navigation scenes.

Subpackages (one responsibility each):
  formats/   bundle contract shared by all layers (scene.json, cameras, walkable grid, PLY)
  registry/  versioned scene registry (content-addressed blobs + Delta Lake manifests)
  splats/    Gaussian-splat model, PLY I/O and the renderer (torch reference, numba CPU, gsplat CUDA)
  factory/   pipeline stages: decode -> privacy/masks -> SfM -> metric frame -> splats -> mesh -> commit
  envs/      Gymnasium hybrid environments (splat rendering + pybullet physics)
  training/  rollouts, training and evaluation of navigation policies
  cli/       the `vid2sim` command line (one module per sub-app)
"""

import os as _os

# torch's OpenMP threads spin after every op and steal the cores from the numba
# splat kernels (measured: fwd+bwd CPU time doubled). Must be set before torch loads.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
