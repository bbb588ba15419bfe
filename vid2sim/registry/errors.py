"""Registry error types (one module so the manifest, blob store and CLI share them)."""

from __future__ import annotations


class RegistryError(RuntimeError):
    """A registry operation failed; the message names the scene/file and the reason."""


class SceneNotFound(RegistryError, KeyError):
    def __str__(self) -> str:  # KeyError would add quotes
        return str(self.args[0])


class RegistryNotFound(RegistryError):
    """A read-only command was pointed at a path that holds no registry."""


class HistoryLost(RegistryError):
    """The manifest log is missing, has a gap, or is damaged: the registry has lost history."""


class BadGracePeriod(RegistryError, ValueError):
    """`gc` was given a grace period that is negative or not a number."""
