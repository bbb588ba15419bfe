"""Versioned scene registry: content-addressed blobs + Delta Lake manifests.

`bundle` defines the scene-bundle folder format (validate/write); `Registry` (store) commits
bundles, lists/queries/splits them and materialises them back for the envs.
"""

from vid2sim.registry.bundle import (BundleError, BundleInfo, make_scene_json, validate_bundle,
                                     write_bundle)

__all__ = ["BundleError", "BundleInfo", "make_scene_json", "validate_bundle", "write_bundle"]
