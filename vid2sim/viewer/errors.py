"""Viewer errors: each names what was asked for and why it cannot be shown."""

from __future__ import annotations


class ViewerError(RuntimeError):
    """The viewer cannot start or cannot show what was asked for; the message says why."""


class UnknownScene(ViewerError):
    """A scene id that is neither a bundle folder nor a scene of the registry."""


class NotABundle(ViewerError):
    """A folder that holds none of a bundle's layers."""


class PortInUse(ViewerError):
    """The requested port is taken by another process."""


class EpisodeInputError(ViewerError):
    """An episode file (trace, eval report or MP4) that cannot be replayed."""
