"""`python -m vid2sim.cli` runs the `vid2sim` command line."""

from vid2sim.cli import main

main()
