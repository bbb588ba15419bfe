"""`vid2sim config show`: every setting of a config with its default, unit and meaning."""

from __future__ import annotations

import json
from typing import List, Optional

import typer

from vid2sim.cli.errors import InputError
from vid2sim.cli.settings import SECTIONS, describe_section, format_rows

app = typer.Typer(help="Inspect the configs the commands run with.", no_args_is_help=True)

SECTION_HELP = {
    "ingest": "the factory pipeline (`vid2sim ingest`; --preset fast | paper)",
    "env": "the navigation envs (EnvConfig)",
    "train": "a training run (TrainConfig, with its SACConfig)",
    "eval": "`vid2sim eval policy` (EvalConfig, and the env config it evaluates with under env.)",
}


@app.command("show")
def show(
    section: Optional[str] = typer.Argument(None, help=f"{' | '.join(SECTIONS)} (default: all)", show_default=False),
    preset: Optional[str] = typer.Option(None, "--preset", help="Pipeline preset for ingest: fast (default) | paper."),
    sets: List[str] = typer.Option([], "--set", metavar="FIELD=VALUE",
                                   help="Show the config after this override (repeatable; needs a section)."),
    as_json: bool = typer.Option(False, "--json", help="Print the fields as JSON."),
) -> None:
    """Every field (nested configs included) with its type, default, unit and one line of meaning.

    The paths are what `--set PATH=VALUE` takes on `vid2sim ingest`, `vid2sim train` and `vid2sim eval policy`."""
    if section is not None and section not in SECTIONS:
        raise InputError("SECTION", f"unknown config section {section!r} ({' | '.join(SECTIONS)})")
    names = [section] if section else list(SECTIONS)
    if len(names) > 1 and sets:
        raise InputError("--set", "needs a section (e.g. `vid2sim config show ingest --set recon.iterations=500`)")
    rows = {name: describe_section(name, preset if name == "ingest" or section else None, sets) for name in names}
    if as_json:
        data = {name: {"preset": (preset or "fast") if name == "ingest" else None,
                       "fields": [r.to_json() for r in section_rows]} for name, section_rows in rows.items()}
        typer.echo(json.dumps(data[section] if section else data, indent=2))
        return
    for i, (name, section_rows) in enumerate(rows.items()):
        head = f"# {name}: {SECTION_HELP[name]}"
        if name == "ingest":
            head += f", preset {preset or 'fast'}"
        typer.echo(("\n" if i else "") + head)
        typer.echo(format_rows(section_rows))
