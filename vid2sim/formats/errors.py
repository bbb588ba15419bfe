"""The one error every bundle-format reader raises: it names the file and the reason."""

from __future__ import annotations

import os
from typing import Union

PathLike = Union[str, os.PathLike]


class BundleError(ValueError):
    """A bundle (or a file in it) is invalid; the message names the file and the reason."""

    def __init__(self, path: PathLike, reason: str) -> None:
        self.path, self.reason = str(path), reason
        super().__init__(f"{self.path}: {reason}")


class BundleTooLarge(BundleError):
    """A bundle file declares more data than the format's size cap allows (checked before reading it)."""
