"""`vid2sim eval ...`: evaluation commands (pose accuracy against ground truth, policies on held-out
episodes, two policies compared on the same episodes)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Optional

import typer

app = typer.Typer(help="Evaluate factory outputs against ground truth.", no_args_is_help=True)


@app.command("poses")
def poses(
    estimate: Path = typer.Option(..., "--estimate",
                                  help="PosedClip folder, COLMAP model, transforms.json or poses.txt."),
    gt: Path = typer.Option(..., "--gt",
                            help="Ground truth: KITTI poses.txt, synthetic clip folder, transforms.json or GoPro CSV."),
    gt_format: str = typer.Option("auto", "--gt-format",
                                  help="kitti | synthetic | transforms | gopro-csv | colmap | auto"),
    est_format: str = typer.Option("auto", "--est-format", help="posed | colmap | transforms | kitti | auto"),
    fps: Optional[float] = typer.Option(None, "--fps", min=0.001, max=10_000.0,
                                        help="GoPro: frame rate to key sub-sampled estimate frames by timestamp."),
    stride: int = typer.Option(1, "--stride", min=1, help="GoPro: estimate frame j is video frame j * stride."),
    as_json: bool = typer.Option(False, "--json", help="Print the full report as JSON."),
) -> None:
    """ATE / RPE after Sim(3) alignment, or relative rotation error against GoPro telemetry."""
    from rich.console import Console
    from rich.table import Table

    from vid2sim.factory.evaluation.poses import evaluate_paths

    rep = evaluate_paths(estimate, gt, gt_format, est_format, fps=fps, stride=stride)
    if as_json:
        typer.echo(json.dumps(rep, indent=2))
        return
    table = Table(title=f"poses: {estimate}")
    table.add_column("metric")
    table.add_column("value", justify="right")
    if "rotation" in rep:
        r = rep["rotation"]
        table.add_row("matched frames", str(r["n_matched"]))
        for k, d in r["deltas"].items():
            table.add_row(f"rel. rot. err (k={k}) fitted mean/median deg",
                          f"{d['fitted_mean_deg']:.3f} / {d['fitted_median_deg']:.3f}")
            table.add_row(f"rel. rot. angle gap (k={k}) mean deg", f"{d['angle_gap_mean_deg']:.3f}")
    else:
        a = rep["ate"]
        table.add_row("matched / gt frames", f"{rep['n_matched']} / {rep['n_gt']}")
        table.add_row("ATE rmse (gt units)", f"{a['rmse']:.4f}")
        table.add_row("ATE % of path", f"{a['rmse_pct_of_path']:.3f}")
        table.add_row("Sim(3) scale", f"{a['scale']:.4f}")
        for k, d in rep["rpe"].items():
            table.add_row(f"RPE k={k} trans rmse / rot mean deg", f"{d['trans_rmse']:.4f} / {d['rot_mean_deg']:.3f}")
    Console().print(table)


@app.command("policy")
def policy(
    policy: str = typer.Option(..., "--policy", help="Training run folder (or SAC .zip), 'random' or 'expert'."),
    registry: str = typer.Option(..., "--registry", help="Registry root."),
    split_seed: int = typer.Option(0, "--split-seed", min=0, help="Split whose held-out test scenes are used."),
    scenes: Optional[str] = typer.Option(None, "--scenes", help="Comma-separated scene ids instead of the test split."),
    trials: int = typer.Option(25, "--trials", min=1, help="Episodes per scene (paper: 25)."),
    obstacles: str = typer.Option("static", "--obstacles", help="none | static (0-5, paper) | dynamic (SocialNav)"),
    variant: str = typer.Option("rgb", "--variant", help="rgb | depth (oracle) | mesh-rgb (baseline)"),
    max_steps: Optional[int] = typer.Option(None, "--max-steps", min=1,
                                            help="Episode limit (default: the env's 3000)."),
    seed: int = typer.Option(1000, "--seed", min=0, help="Trial k of every scene uses seed + k."),
    privileged: bool = typer.Option(False, "--privileged", help="Goal vector + range observations (privileged agent)."),
    out: Optional[Path] = typer.Option(None, "--out", help="Write the JSON report here."),
    record: int = typer.Option(0, "--record", min=0, help="MP4s of the first N trials of every scene."),
    record_dir: Path = typer.Option(Path("vid2sim-eval-videos"), "--record-dir", help="Folder for the MP4s."),
    sets: List[str] = typer.Option([], "--set", metavar="FIELD=VALUE",
                                   help="Override an EvalConfig field, or env.FIELD of its env config "
                                        "(repeatable; list: `vid2sim config show eval`)."),
    as_json: bool = typer.Option(False, "--json", help="Print the JSON report."),
) -> None:
    """Navigation policy on held-out scenes: SR, SPL, Cost, SNS with 95 % bootstrap intervals."""
    from rich.console import Console
    from rich.table import Table

    from vid2sim.training.evaluate import METRICS, EvalConfig, evaluate

    config = EvalConfig(registry=registry, policy=policy, split_seed=split_seed, trials=trials, obstacles=obstacles,
                        variant=variant, max_steps=max_steps, seed=seed,
                        env_id="vid2sim/PointNavPrivileged-v0" if privileged else None,
                        scene_ids=[s for s in (scenes or "").split(",") if s],
                        record=record, record_dir=str(record_dir) if record else None)
    from vid2sim.cli.settings import apply_eval_overrides, apply_or_exit
    config = apply_or_exit(config, sets, apply_eval_overrides)
    from vid2sim.cli.inputs import creatable_folder, registry_root

    registry_root(registry)
    creatable_folder(str(out.parent) if out else None, "--out")
    report = evaluate(config)
    if out:
        out.write_text(report.to_json())
    if as_json:
        typer.echo(report.to_json())
        return
    table = Table(title=f"{policy}: {report.episodes} episodes ({config.trials} per scene), "
                        f"obstacles={config.obstacles}, {config.variant}")
    table.add_column("metric")
    table.add_column("mean")
    table.add_column("95% CI")
    for k in METRICS:
        m = report.metrics[k]
        table.add_row(k, f"{m.mean:.3f}", f"[{m.low:.3f}, {m.high:.3f}]")
    Console().print(table)
    typer.echo("outcomes: " + ", ".join(f"{k} {n}" for k, n in report.outcomes().items())
               + " (pinned: a time-out spent mostly pressed against something)")
    for v in report.videos:
        typer.echo(f"video: {v}")


def read_report(path: Path, flag: str):
    """The EvalReport at `path`; InputError naming `flag` when it is missing or not a report."""
    from vid2sim.cli.errors import InputError
    from vid2sim.training.evaluate import EvalReport

    if not path.is_file():
        raise InputError(f"{flag} {path}", "no such file")
    try:
        return EvalReport.from_json(path.read_text())
    except (ValueError, TypeError, KeyError) as exc:
        raise InputError(f"{flag} {path}", f"not an evaluation report ({type(exc).__name__}: {exc})") from exc


@app.command("compare")
def compare(
    report_a: Path = typer.Argument(..., help="Evaluation report A (`eval policy --out`)."),
    report_b: Path = typer.Argument(..., help="Evaluation report B, made on the same episodes."),
    metric: str = typer.Option("sr", "--metric", help="sr | spl | cost | sns | sns_proximity"),
    as_json: bool = typer.Option(False, "--json", help="Print the comparison as JSON."),
) -> None:
    """Two policies on the same episodes: B - A of a metric with its 95 % paired-bootstrap interval."""
    from dataclasses import asdict

    from vid2sim.training.compare import paired_difference

    c = paired_difference(read_report(report_a, "REPORT_A"), read_report(report_b, "REPORT_B"), metric)
    if as_json:
        typer.echo(json.dumps(asdict(c), indent=2))
        return
    d = c.difference
    typer.echo(f"{c.metric} over {c.episodes} shared episodes: A {c.mean_a:.3f}, B {c.mean_b:.3f}; "
               f"B - A {d.mean:+.3f} (95 % {d.low:+.3f} .. {d.high:+.3f}), P(B - A <= 0) {c.p_not_better:.4f}; "
               f"A ahead in {c.only_a}, B ahead in {c.only_b}")
