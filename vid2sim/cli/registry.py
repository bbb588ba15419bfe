"""`vid2sim registry ...`: the registry operations on the command line.

Every command takes `--registry ROOT` (default $VID2SIM_REGISTRY or ./vid2sim-registry);
commands that report data take `--json`. Errors follow the CLI's convention (`vid2sim.cli.errors`:
one line, exit 2); `verify` exits 1 when it finds problems.
"""

from __future__ import annotations

import json
from typing import Any, List, Optional

import typer

app = typer.Typer(help="Versioned scene registry (content-addressed blobs + Delta Lake manifests).",
                  no_args_is_help=True, pretty_exceptions_show_locals=False)

RegistryOpt = typer.Option(None, "--registry", "-r", help="Registry root: folder or URI "
                           "(default $VID2SIM_REGISTRY or ./vid2sim-registry).")
JsonOpt = typer.Option(False, "--json", help="Print JSON instead of a table.")
AsOfOpt = typer.Option(None, "--as-of", help="Registry version number or ISO timestamp.")


def _open(root: Optional[str]):
    from vid2sim.registry.store import Registry

    return Registry(root)


def _echo_json(obj: Any) -> None:
    typer.echo(json.dumps(obj, indent=2, sort_keys=True, default=str))


def _records_table(recs, title: str) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title=title)
    for col in ("scene", "ver", "status", "event", "created", "group", "frames", "splats", "walk m2", "tags"):
        t.add_column(col)
    for r in recs:
        t.add_row(r.scene_id, str(r.version), r.status, r.event, r.created_at.strftime("%Y-%m-%d %H:%M:%S"),
                  r.source_group[:12], str(r.num_frames), str(r.num_splats), f"{r.walkable_area_m2:.1f}",
                  ",".join(r.tags))
    Console().print(t)


def _record_out(rec, as_json: bool, title: str) -> None:
    if as_json:
        _echo_json(rec.to_dict())
    else:
        _records_table([rec], title)


@app.command()
def add(bundle_dir: str = typer.Argument(..., help="Scene bundle folder."),
        registry: Optional[str] = RegistryOpt, as_json: bool = JsonOpt) -> None:
    """Validate a bundle, store its artifacts and commit a new scene version."""
    res = _open(registry).add_result(bundle_dir)
    rec, noop = res.record, res.noop
    if as_json:
        _echo_json({**rec.to_dict(), "noop": noop})
    else:
        _records_table([rec], "unchanged (identical content)" if noop else "added")


@app.command("list")
def list_(registry: Optional[str] = RegistryOpt, as_json: bool = JsonOpt, as_of: Optional[str] = AsOfOpt,
          all_: bool = typer.Option(False, "--all", help="Include deprecated scenes.")) -> None:
    """Latest version of each scene (optionally as of an older registry version or time)."""
    recs = _open(registry).list(as_of=as_of, include_deprecated=all_)
    if as_json:
        _echo_json([r.to_dict() for r in recs])
    else:
        _records_table(recs, f"{len(recs)} scene(s)")


@app.command()
def show(ref: str = typer.Argument(..., help="SCENE or SCENE@VERSION"),
         registry: Optional[str] = RegistryOpt, as_json: bool = JsonOpt) -> None:
    """One scene version with metrics and artifacts."""
    from vid2sim.registry.store import parse_ref

    scene, version = parse_ref(ref)
    rec = _open(registry).show(scene, version)
    if as_json:
        _echo_json(rec.to_dict())
        return
    from rich.console import Console
    from rich.table import Table

    _records_table([rec], rec.ref)
    t = Table(title="artifacts")
    for c in ("name", "sha256", "bytes"):
        t.add_column(c)
    for a in rec.artifacts:
        t.add_row(a.name, a.sha256[:16], str(a.size))
    Console().print(t)
    Console().print({"metrics": rec.metrics, "source": rec.source_uri, "bounds": rec.bounds,
                     "message": rec.message})


@app.command()
def history(scene: Optional[str] = typer.Argument(None, help="Scene id (default: all scenes)."),
            registry: Optional[str] = RegistryOpt, as_json: bool = JsonOpt) -> None:
    """Every version (of one scene, or all, in commit order)."""
    recs = _open(registry).history(scene)
    if as_json:
        _echo_json([r.to_dict() for r in recs])
    else:
        _records_table(recs, f"history of {scene or 'all scenes'}")


@app.command()
def tag(scene: str, tags: List[str] = typer.Argument(..., help="Tags to add."),
        registry: Optional[str] = RegistryOpt, as_json: bool = JsonOpt) -> None:
    """Add tags (a new scene version)."""
    _record_out(_open(registry).tag(scene, *tags), as_json, "tagged")


@app.command()
def untag(scene: str, tags: List[str] = typer.Argument(..., help="Tags to remove."),
          registry: Optional[str] = RegistryOpt, as_json: bool = JsonOpt) -> None:
    """Remove tags (a new scene version)."""
    _record_out(_open(registry).untag(scene, *tags), as_json, "untagged")


@app.command()
def deprecate(scene: str, reason: str = typer.Option(..., "--reason", help="Why (stored)."),
              registry: Optional[str] = RegistryOpt, as_json: bool = JsonOpt) -> None:
    """Mark a scene deprecated (a new version; excluded from list and split)."""
    _record_out(_open(registry).deprecate(scene, reason), as_json, "deprecated")


def _parse_min(items: List[str]) -> dict[str, float]:
    out = {}
    for it in items:
        name, sep, val = it.partition("=")
        try:
            out[name] = float(val)
        except ValueError:
            sep = ""
        if not sep or not name:
            raise ValueError(f"--min {it!r}: expected METRIC=VALUE")
    return out


@app.command()
def split(seed: int = typer.Option(0, "--seed", min=0),
          test_fraction: float = typer.Option(0.2, "--test-fraction", min=0.0, max=1.0,
                                              help="Share of scenes held out (whole source videos)."),
          test_group: List[str] = typer.Option([], "--test-group", help="Fixed held-out source group (repeat)."),
          train_size: List[int] = typer.Option([], "--train-size", min=1, help="Nested train subset size (repeat)."),
          tag_: List[str] = typer.Option([], "--tag", help="Require this tag (repeat)."),
          min_: List[str] = typer.Option([], "--min", help="Quality threshold METRIC=VALUE (repeat)."),
          registry: Optional[str] = RegistryOpt, as_json: bool = JsonOpt, as_of: Optional[str] = AsOfOpt) -> None:
    """Deterministic, leak-free train/test split with nested train subsets."""
    s = _open(registry).split(seed=seed, test_fraction=test_fraction, test_groups=test_group or None,
                              train_sizes=train_size, tags=tag_, min_metrics=_parse_min(min_), as_of=as_of)
    if as_json:
        _echo_json(s.to_dict())
        return
    typer.echo(f"registry version {s.registry_version}, seed {s.seed}")
    typer.echo(f"test  ({len(s.test)} scenes, {len(s.test_groups)} videos): {' '.join(s.test)}")
    typer.echo(f"train ({len(s.train)} scenes, {len(s.train_groups)} videos): {' '.join(s.train)}")
    for k, ids in s.train_subsets.items():
        typer.echo(f"train-{k}: {' '.join(ids)}")


@app.command()
def verify(registry: Optional[str] = RegistryOpt, as_json: bool = JsonOpt,
           repair: bool = typer.Option(False, "--repair", help="Rewrite missing/corrupt blobs from --from folders."),
           from_: List[str] = typer.Option([], "--from", help="Bundle folder holding good copies (repeat).")) -> None:
    """Check the manifest log and re-hash every blob; exit 1 naming each problem."""
    reg = _open(registry)
    if repair and not from_:
        raise ValueError("--repair needs --from BUNDLE_DIR (a folder holding good copies of the artifacts)")
    repaired = reg.repair(from_) if repair else []
    for line in repaired if not as_json else []:
        typer.echo(line)
    problems = reg.verify()
    if as_json:
        _echo_json({"ok": not problems, "problems": problems, **({"repaired": repaired} if repair else {})})
    elif problems:
        for p in problems:
            typer.secho(p, fg=typer.colors.RED, err=True)
    else:
        typer.echo("ok: manifest log continuous, every referenced artifact present and intact, no stray blobs")
    if problems:
        raise typer.Exit(1)


@app.command()
def gc(registry: Optional[str] = RegistryOpt, as_json: bool = JsonOpt,
       grace_seconds: float = typer.Option(3600.0, "--grace-seconds", min=0.0, max=1e9,
                                           help="Keep unreferenced blobs younger than this."),
       dry_run: bool = typer.Option(False, "--dry-run"),
       force: bool = typer.Option(False, "--force", help="Delete unreferenced blobs even when the manifest "
                                  "log looks damaged or blobs exist that nothing accounts for (lost history).")
       ) -> None:
    """Delete blobs of adds that never committed (never a referenced one); refuses on lost history."""
    removed = _open(registry).gc(grace_s=grace_seconds, dry_run=dry_run, force=force)
    if as_json:
        _echo_json({"removed": removed, "dry_run": dry_run})
    else:
        typer.echo(f"{'would remove' if dry_run else 'removed'} {len(removed)} unreferenced blob(s)")


@app.command()
def compact(registry: Optional[str] = RegistryOpt, as_json: bool = JsonOpt,
            vacuum_hours: Optional[int] = typer.Option(
                None, "--vacuum-hours", min=0,
                help="Also delete manifest files replaced more than H hours ago: time travel to older "
                     "versions stops working. Without it nothing is deleted."),
            dry_run: bool = typer.Option(False, "--dry-run", help="With --vacuum-hours: only list the files.")) -> None:
    """Merge the manifest's small Parquet files and checkpoint (rows and history unchanged)."""
    metrics = _open(registry).compact(vacuum_hours=vacuum_hours, dry_run=dry_run)
    if as_json:
        _echo_json(metrics)
        return
    typer.echo(f"compacted: {metrics.get('numFilesRemoved', 0)} files -> {metrics.get('numFilesAdded', 0)}")
    if vacuum_hours is not None:
        typer.echo(f"vacuum: {'would delete' if dry_run else 'deleted'} {len(metrics['vacuumed'])} manifest file(s)")


@app.command()
def query(sql: str = typer.Argument(..., help="DuckDB SQL over tables `scenes` (all versions) and `latest`."),
          registry: Optional[str] = RegistryOpt, as_json: bool = JsonOpt, as_of: Optional[str] = AsOfOpt,
          max_rows: int = typer.Option(1000, "--max-rows", min=1, help="Print at most this many rows."),
          memory: str = typer.Option("512MB", "--memory", help="DuckDB memory limit.")) -> None:
    """Read-only SQL over the manifests (one SELECT; no files, URLs, extensions; capped)."""
    from vid2sim.registry.query import QueryLimits

    table, more = _open(registry).query_head(sql, as_of=as_of, limits=QueryLimits(memory=memory, max_rows=max_rows))
    rows = table.to_pylist()
    if more:
        typer.secho(f"note: showing the first {max_rows} rows; the result has more (--max-rows, or add LIMIT)",
                    fg=typer.colors.YELLOW, err=True)
    if as_json:
        _echo_json(rows)
        return
    from rich.console import Console
    from rich.table import Table

    t = Table()
    for c in table.column_names:
        t.add_column(c)
    for r in rows:
        t.add_row(*(str(v) for v in r.values()))
    Console().print(t)


@app.command()
def checkout(ref: str = typer.Argument(..., help="SCENE or SCENE@VERSION"),
             dest: Optional[str] = typer.Option(None, "--dest", help="Folder (default ./vid2sim-checkouts/SCENE@V)."),
             registry: Optional[str] = RegistryOpt, as_json: bool = JsonOpt) -> None:
    """Materialise a scene bundle folder (hash-verified) for the envs."""
    from vid2sim.registry.store import parse_ref

    from vid2sim.cli.inputs import creatable_folder

    scene, version = parse_ref(ref)
    out = _open(registry).checkout(scene, version, creatable_folder(dest, "--dest"))
    if as_json:
        _echo_json({"path": str(out)})
    else:
        typer.echo(str(out))
