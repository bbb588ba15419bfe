"""`vid2sim ingest`: videos / image folders / manifests -> registered scenes."""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Optional

import typer
from rich.console import Console
from rich.table import Table


def interrupted_message(states: dict, workdir: str) -> str:
    """What an interrupted ingest finished, and how to resume it."""
    done = sorted(c for c, (status, _, _) in states.items() if status == "done")
    failed = sorted(c for c, (status, _, _) in states.items() if status == "failed")
    partial = sorted(f"{c} (after {i} stage(s), in {stage or 'queue'})" for c, (status, i, stage) in states.items()
                     if status not in ("done", "failed"))
    lines = [f"interrupted: {len(done)} clip(s) committed to the registry"
             + (f" ({', '.join(done)})" if done else "") + f", {len(failed)} failed, {len(partial)} unfinished"]
    lines += [f"  unfinished: {p}" for p in partial]
    lines.append(f"resume: run the same command again; finished stages are cached in {workdir} and are not redone")
    return "\n".join(lines)


def ingest_command(
    inputs: List[str] = typer.Argument(...,
                                       help="Video files, image folders, URIs or manifests (.yaml/.csv/.parquet)."),
    registry: Optional[str] = typer.Option(None, "--registry",
                                           help="Registry root (default $VID2SIM_REGISTRY or ./vid2sim-registry)."),
    ray_address: Optional[str] = typer.Option(None, "--ray-address",
                                              help="Ray cluster address; default: an embedded local runtime."),
    preset: str = typer.Option("fast", "--preset", help="fast | paper"),
    config: Optional[Path] = typer.Option(None, "--config",
                                          help="PipelineConfig JSON (e.g. a scene.json's pipeline.config); "
                                               "overrides --preset."),
    workdir: str = typer.Option("vid2sim-work", "--workdir",
                                help="Stage outputs (cache; re-runs resume): a folder or an object-store "
                                     "URI (s3://bucket/work) for clusters without a shared disk."),
    num_cpus: Optional[int] = typer.Option(None, "--num-cpus", min=1, help="CPUs for the embedded Ray runtime (>= 1)."),
    licence: str = typer.Option("unknown", "--licence", help="Licence tag for sources given directly."),
    capture_height: Optional[float] = typer.Option(None, "--capture-height", min=0.05, max=100.0,
                                                   help="Camera height above ground (m) for direct sources."),
    sets: List[str] = typer.Option([], "--set", metavar="FIELD=VALUE",
                                   help="Override one pipeline setting, e.g. recon.iterations=500 (repeatable; "
                                        "applied after --preset / --config; list: `vid2sim config show ingest`)."),
    as_json: bool = typer.Option(False, "--json", help="Print the report as JSON."),
) -> None:
    """Turn videos into registered, simulation-ready scenes (each clip's stages run as Ray tasks)."""
    from vid2sim.factory.runtime.pipeline import STEP_NAMES, PipelineConfig, ingest, preset as make_preset
    from vid2sim.factory.runtime.progress import IngestProgress

    from vid2sim.cli.errors import InputError
    from vid2sim.cli.inputs import creatable_folder, existing_sources
    from vid2sim.cli.settings import apply_or_exit

    console = Console(stderr=True)
    try:
        conf = PipelineConfig.load(config) if config else make_preset(preset)
    except (ValueError, TypeError, OSError) as e:
        raise InputError("--config" if config else "--preset", str(e)) from None
    conf = apply_or_exit(conf, sets)
    existing_sources(inputs)
    creatable_folder(registry, "--registry")
    creatable_folder(workdir, "--workdir")
    holder: dict = {}

    def on_plan(ids: list[str]) -> None:
        progress = IngestProgress(ids, list(STEP_NAMES), console=console, enabled=not as_json)
        holder["progress"] = progress.__enter__()

    def on_update(state) -> None:
        holder.setdefault("states", {})[state.clip_id] = (state.status, state.stage_index, state.stage)
        if "progress" in holder:
            holder["progress"].update(state)

    try:
        report = ingest(inputs, registry, workdir=workdir, conf=conf, ray_address=ray_address,
                        num_cpus=num_cpus, licence=licence, capture_height=capture_height,
                        on_update=on_update, on_plan=on_plan)
    except KeyboardInterrupt:
        if "progress" in holder:
            holder.pop("progress").__exit__(None, None, None)
        console.print(interrupted_message(holder.get("states", {}), workdir))
        raise typer.Exit(130)
    finally:
        if "progress" in holder:
            holder["progress"].__exit__(None, None, None)
    data = report.to_json()
    if as_json:
        typer.echo(json.dumps(data, indent=2))
    else:
        table = Table(title=f"ingest finished in {data['seconds']:.0f} s")
        for col in ("clip", "scene", "result"):
            table.add_column(col)
        for c in data["clips"]:
            result = f"[green]v{c['version']}[/green]" if c["ok"] else f"[red]{c['failed_stage']}: {c['reason']}[/red]"
            table.add_row(c["clip"], c["scene_id"] or "", result)
        Console().print(table)
    if any(not c["ok"] for c in data["clips"]):
        raise typer.Exit(1)
