"""Versioned scene registry: content-addressed blobs + Delta Lake manifests.

The scene-bundle format lives in `vid2sim.formats`; `Registry` (store) commits
bundles, lists/queries/splits them and materialises them back for the envs.
"""

from vid2sim.formats.bundle import BundleInfo, validate_bundle, write_bundle
from vid2sim.formats.errors import BundleError
from vid2sim.formats.scene import make_scene_json
from vid2sim.registry.records import Artifact, SceneRecord
from vid2sim.registry.split import Split, SplitError
from vid2sim.registry.errors import BadGracePeriod, HistoryLost, RegistryError, RegistryNotFound, SceneNotFound
from vid2sim.registry.store import AddResult, Registry, RegistryConfig

__all__ = ["AddResult", "Artifact", "BadGracePeriod", "BundleError", "BundleInfo", "HistoryLost", "Registry",
           "RegistryConfig", "RegistryError", "RegistryNotFound", "SceneNotFound",
           "SceneRecord", "Split", "SplitError", "make_scene_json", "validate_bundle", "write_bundle"]
