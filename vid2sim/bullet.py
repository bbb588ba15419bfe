"""pybullet without its banner.

Importing pybullet makes its C extension print "pybullet build time: ..." from C code, below
Python's `sys.stdout` / `sys.stderr` (the 3.2.7 wheel writes it to file descriptor 2; other
builds print to 1 through C stdio). `import_pybullet` imports the module with descriptors 1 and
2 pointed at /dev/null, C stdio flushed before they are restored. Later `import pybullet`
statements anywhere get the already imported module and print nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
from types import ModuleType
from typing import Iterator


def _flush_c_stdio() -> None:
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):  # no C library to reach (e.g. Windows): nothing to flush
        pass


@contextlib.contextmanager
def c_output_silenced(fds: tuple[int, ...] = (1, 2)) -> Iterator[None]:
    """Discard what is written to the file descriptors `fds` inside the block, by C code or Python
    (Python's own streams are flushed first, so nothing printed before the block is lost)."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (AttributeError, ValueError):  # no stream, or a closed one
            pass
    saved: dict[int, int] = {}
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        for fd in fds:
            try:
                saved[fd] = os.dup(fd)
            except OSError:  # not open: nothing to silence
                continue
            os.dup2(devnull, fd)
        yield
    finally:
        _flush_c_stdio()
        for fd, copy in saved.items():
            os.dup2(copy, fd)
            os.close(copy)
        os.close(devnull)


def import_pybullet() -> ModuleType:
    """The `pybullet` module, imported without its banner on the first call."""
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    with c_output_silenced():
        import pybullet
    return pybullet
