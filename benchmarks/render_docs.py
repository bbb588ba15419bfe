"""Render the benchmark results files into markdown pages: docs/benchmarks/<benchmark>.md + index.md.

    .venv/bin/python benchmarks/render_docs.py [--results benchmarks/results] [--out docs/benchmarks]

Reads every results file (benchmarks/common.py's `Run`), skips failed runs, and keeps, per
(benchmark, case), the rows of the latest run that has that case. Each page names, for every
run it draws on, the command, commit, date, hardware, load and library versions, then shows
that run's figures as tables. The output depends only on the results files (no clock), so
rendering twice gives the same pages.
"""

from __future__ import annotations

import argparse
import sys
from collections import OrderedDict
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import REPO, RESULTS_DIR, load_results, run_order  # noqa: E402

DOCS = REPO / "docs" / "benchmarks"
NOT_BENCHMARKS = {"common", "render_docs"}
TRANSPOSE_OVER = 8  # more metrics than this in one table: metrics become rows, cases columns


def fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        a = abs(v)
        if a == 0:
            return "0"
        if a >= 1000:
            return f"{v:.0f}"
        return f"{v:.4g}" if a >= 100 else f"{v:.3g}"
    if isinstance(v, (list, dict)):
        return cell(str(v))
    return cell(str(v))


def cell(s: str) -> str:
    return s.replace("|", "\\|").replace("\n", " ")


def fmt_config(c: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in c.items())


def latest_cases(runs: list[dict]) -> dict[str, "OrderedDict[str, tuple[dict, list[dict]]]"]:
    """{benchmark: {case: (run, rows)}}: per case the latest ok run that has it."""
    out: dict[str, OrderedDict] = {}
    for run in runs:  # sorted by start time: later runs replace earlier ones case by case
        if run.get("status") != "ok":
            continue
        cases: OrderedDict[str, list[dict]] = OrderedDict()
        for r in run["rows"]:
            cases.setdefault(r["case"], []).append(r)
        for case, rows in cases.items():
            bench = out.setdefault(rows[0]["benchmark"], OrderedDict())
            bench.pop(case, None)
            bench[case] = (run, rows)
    return out


def tables(cases: list[tuple[str, list[dict]]]) -> list[str]:
    """Markdown tables of one run's cases, one table per run of cases sharing the same metrics."""
    groups: list[tuple[tuple, list[tuple[str, list[dict]]]]] = []
    for case, rows in cases:
        key = tuple((r["metric"], r["unit"]) for r in rows)
        if groups and groups[-1][0] == key:
            groups[-1][1].append((case, rows))
        else:
            groups.append((key, [(case, rows)]))
    lines: list[str] = []
    for key, members in groups:
        configs = [rows[0]["config"] for _, rows in members]
        varying = any(c != configs[0] for c in configs)
        head = [f"{m} ({u})" if u else m for m, u in key]
        if len(key) > TRANSPOSE_OVER:
            lines.append("| metric | " + " | ".join(cell(c) for c, _ in members) + " |")
            lines.append("|---" * (len(members) + 1) + "|")
            for i, h in enumerate(head):
                lines.append(f"| {cell(h)} | " + " | ".join(fmt(rows[i]["value"]) for _, rows in members) + " |")
            if varying:
                lines.append("| config | " + " | ".join(cell(fmt_config(c)) or "-" for c in configs) + " |")
        else:
            extra = ["config"] if varying else []
            lines.append("| case | " + " | ".join(cell(h) for h in head + extra) + " |")
            lines.append("|---" * (len(head) + len(extra) + 1) + "|")
            for (case, rows), c in zip(members, configs):
                vals = [fmt(r["value"]) for r in rows] + ([cell(fmt_config(c)) or "-"] if varying else [])
                lines.append(f"| {cell(case)} | " + " | ".join(vals) + " |")
        if configs[0] and not varying:
            lines.append("")
            lines.append(f"config: {cell(fmt_config(configs[0]))}")
        lines.append("")
    return lines


def run_facts(run: dict) -> list[str]:
    hw, g, load = run["hardware"], run["git"], run["load"]
    commit = f"`{g['commit'][:12]}`" if g.get("commit") else "unknown"
    if g.get("dirty"):
        commit += " (uncommitted changes in the tree)"
    if g.get("branch"):
        commit += f" on {g['branch']}"
    date = run["started_utc"].replace("T", " ").replace("+00:00", " UTC")
    gpu = hw.get("gpu") or "no GPU"
    vers = ", ".join(f"{k} {v}" for k, v in run["versions"].items())
    out = [f"- command: `{run['command']}`",
           f"- commit: {commit}",
           f"- date: {date}, {run['duration_s']:.0f} s",
           f"- hardware: {cpu_line(hw)}, {hw['cores']} cores, {hw['memory_gib']} GiB RAM, {gpu}; "
           f"1-min loadavg {load['start'][0]:.2f} at start, {load['end'][0]:.2f} at end",
           f"- versions: {vers}"]
    if run.get("env"):
        out.append("- environment: " + ", ".join(f"`{k}={v}`" for k, v in run["env"].items()))
    out.append(f"- results file: `{rel(run['_path'])}`")
    for n in run.get("notes", []):
        out.append(f"- note: {cell(n)}")
    return out


def cpu_line(hw: dict) -> str:
    """The CPU model with its family/model numbers and vector set where the file has them
    (files written before they were recorded give the model name alone)."""
    extra = [x for x in (hw.get("cpu_id"), hw.get("simd")) if x]
    return hw["cpu_model"] + (f" ({', '.join(extra)})" if extra else "")


def rel(p: str) -> str:
    try:
        return str(Path(p).resolve().relative_to(REPO))
    except ValueError:
        return Path(p).name


def page(benchmark: str, cases: "OrderedDict[str, tuple[dict, list[dict]]]") -> str:
    by_run: OrderedDict[str, tuple[dict, list]] = OrderedDict()
    for case, (run, rows) in cases.items():
        by_run.setdefault(run["_path"], (run, []))[1].append((case, rows))
    runs = sorted(by_run.values(), key=lambda x: run_order(x[0]), reverse=True)
    desc = runs[0][0].get("description") or ""
    lines = [f"# Benchmark: {benchmark}", ""]
    if desc:
        lines += [cell(desc), ""]
    lines += [f"Script: `benchmarks/{benchmark}.py`. Generated by `benchmarks/render_docs.py` from "
              f"`benchmarks/results/` (per case, the latest run that measured it); do not edit by hand.", ""]
    for run, run_cases in runs:
        date = run["started_utc"][:16].replace("T", " ")
        lines += [f"## Run of {date} UTC", ""] + run_facts(run) + [""]
        lines += tables(run_cases)
    return "\n".join(lines).rstrip() + "\n"


def index(found: dict, scripts: list[str], others: list[str] = ()) -> str:
    lines = ["# Benchmarks", "",
             "Measured figures of the scripts in `benchmarks/`, rendered by `benchmarks/render_docs.py` "
             "from the results files in `benchmarks/results/` (one JSON file per run, written by the "
             "harness in `benchmarks/common.py`). `make bench` runs the quick set and renders these pages; "
             "the other benchmarks need external data, a Ray cluster or long runs: run them by hand "
             "(`.venv/bin/python benchmarks/NAME.py --help`) and render again.", "",
             "| benchmark | what it measures | latest run (UTC) | commit | command | cases |",
             "|---|---|---|---|---|---|"]
    for b, cases in sorted(found.items()):
        runs = {r["_path"]: r for r, _ in cases.values()}
        last = max(runs.values(), key=run_order)
        commit = (last["git"].get("commit") or "")[:12] + (" (dirty)" if last["git"].get("dirty") else "")
        lines.append(f"| [{b}]({b}.md) | {cell(last.get('description') or '')} | "
                     f"{last['started_utc'][:16].replace('T', ' ')} | `{commit}` | `{cell(last['command'])}` | "
                     f"{len(cases)} |")
    missing = [s for s in scripts if s not in found]
    if missing:
        lines += ["", "No results yet: " + ", ".join(f"`benchmarks/{s}.py`" for s in missing) + "."]
    if others:
        lines += ["", "Other pages: " + ", ".join(f"[{p}]({p})" for p in others) + "."]
    return "\n".join(lines) + "\n"


def render(results: Path = RESULTS_DIR, out: Path = DOCS) -> list[Path]:
    """Writes the pages; returns their paths."""
    runs = load_results(results)
    for r in runs:
        if r.get("status") != "ok":
            print(f"skipped {rel(r['_path'])}: {r.get('status')}")
    found = latest_cases(runs)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for b, cases in sorted(found.items()):
        p = out / f"{b}.md"
        p.write_text(page(b, cases))
        written.append(p)
    scripts = sorted(p.stem for p in (REPO / "benchmarks").glob("*.py") if p.stem not in NOT_BENCHMARKS)
    others = sorted(p.name for p in out.glob("*.md") if p.stem not in found and p.name != "index.md"
                    and p.stem not in scripts)
    p = out / "index.md"
    p.write_text(index(found, scripts, others))
    written.append(p)
    return written


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", type=Path, default=RESULTS_DIR, help="folder of results JSON files")
    ap.add_argument("--out", type=Path, default=DOCS, help="folder of the markdown pages")
    args = ap.parse_args()
    for p in render(args.results, args.out):
        print(f"wrote {rel(str(p))}")


if __name__ == "__main__":
    main()
