"""`vid2sim` command line package: one module per sub-app; `app.py` assembles them.

The console entry point is `vid2sim.cli:main`.
"""

from vid2sim.cli.app import main

__all__ = ["main"]
