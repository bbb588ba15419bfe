"""`vid2sim ensemble`: several distilled students as one policy (argument parsing only)."""

from __future__ import annotations

import json
from typing import List

import typer


def ensemble_command(
    runs: List[str] = typer.Argument(..., help="Distillation run folders (or student .pt files), two or more."),
    out: str = typer.Option(..., "--out", help="Ensemble folder (student.pt, ensemble.json)."),
    as_json: bool = typer.Option(False, "--json", help="Print the ensemble's ensemble.json."),
) -> None:
    """Students that drive together (the mean of their actions): a folder that `vid2sim eval policy
    --policy` and `export_policy` take like one run."""
    from vid2sim.cli.inputs import creatable_folder, existing_sources
    from vid2sim.training.ensemble import ENSEMBLE_META, build_ensemble

    existing_sources(runs, "RUNS")
    creatable_folder(out, "--out")
    folder = build_ensemble(runs, out)
    text = (folder / ENSEMBLE_META).read_text()
    typer.echo(text if as_json else f"ensemble of {len(json.loads(text)['members'])} students: {folder}")
