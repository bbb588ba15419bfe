"""The benchmark harness: how every script in benchmarks/ starts, records its figures and ends.

A benchmark script keeps printing its human-readable tables, and also records every figure it
prints as a row of a `Run`. The run prints one header line when it starts (hardware, 1-min
load, git commit, command) and writes ONE JSON results file when it ends, which
`benchmarks/render_docs.py` turns into the pages under docs/benchmarks/.

Usage (the whole API)::

    import argparse
    from common import Run, add_run_args    # benchmarks/ is sys.path[0] when a script runs

    def main() -> None:
        ap = argparse.ArgumentParser()
        ap.add_argument("--frames", type=int, default=200)
        add_run_args(ap)                    # --results PATH (see "Where the file goes")
        args = ap.parse_args()
        with Run("raster", args) as run:    # prints the header line; args go into the file
            fps = measure(args.frames)
            run.record("ours 128x72", "fps_wall", fps, "frames/s", config={"frames": args.frames})
            print(f"ours: {fps:.1f} frames/s")        # the printed table stays as it was
            if not data_present:
                run.skip("gopro", "../shared/data is absent")   # prints SKIP and notes it
        # on leaving the block: benchmarks/results/raster-20250101T120000Z.json

Rows. `run.record(case, metric, value, unit="", config=None)` adds one row
(benchmark, case, metric, value, unit, config) and returns `value`, so it can wrap an
expression inside an f-string. `run.record_all(case, {metric: value}, units, config)` adds
several rows of one case (`units`: one unit for all, or {metric: unit}). A case is what was
measured ("list cold, 10000 scenes", "PointNav rgb exact"), a metric one figure of it
("median_ms"); name both so that they stay stable between runs (never a position), and put
what was varied into the case name when it changes the figure (size, resolution, variant),
the rest into `config`. Values are numbers, bools, strings or None (numpy scalars are
converted; NaN / inf are stored as the strings "nan" / "inf").
The renderer keeps, per (benchmark, case), the rows of the latest run that has that case.

Also: `run.note(text)` stores a remark; `run.skip(case, reason)` prints SKIP and notes it
(data absent: the run still ends normally); `run.config[...] = ...` adds run-level settings;
`Run(..., libraries=("duckdb",))` records more library versions; `Run(..., quiet=True)`
prints nothing. If the `with` block raises, the file is still written, with status
"failed: ..." and the rows so far. A script that other code imports (street_registry.py)
imports `common` inside main(). Smoke settings go behind `--quick`; `make bench` runs the
quick set (see the Makefile) and then `benchmarks/render_docs.py`.

What a results file holds (schema 1): benchmark, description (first docstring paragraph of
the script), status ("ok", or "failed: ..." when the block raised: the renderer skips those),
started_utc / started_unix / finished_utc / duration_s, command (shell-quoted, python
relative to the repo), argv, cwd, args (the argparse namespace), config (`run.config`, free-form), env (the
VID2SIM_* / OMP_* / NUMBA_* / CUDA_VISIBLE_DEVICES variables set), hardware (cpu_model,
cpu_id (vendor, family, model), simd (the widest vector set), cores, memory_gib, gpu or null,
platform), load (the 1/5/15-min loadavg at start and end),
git (commit, dirty, branch), versions (python and each of numpy, torch, ray, pycolmap,
open3d, pybullet, gymnasium, stable-baselines3, numba, deltalake that is installed), notes
(skips and remarks) and rows.

Where the file goes: `--results PATH`, else the environment variable VID2SIM_BENCH_RESULTS,
else benchmarks/results/. A PATH that is an existing folder or ends with "/" is a folder
(the file is named <benchmark>-<UTC timestamp>.json in it); anything else is the file itself.
The files in benchmarks/results/ are committed (a few KB each): the docs pages are rendered
from them, so commit a run's file together with the pages it changes.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import importlib.metadata
import json
import math
import os
import platform
import resource
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Mapping, Optional, Union

REPO = Path(__file__).resolve().parent.parent
RESULTS_DIR = REPO / "benchmarks" / "results"
RESULTS_ENV = "VID2SIM_BENCH_RESULTS"
SCHEMA = 1
LIBRARIES = ("numpy", "torch", "ray", "pycolmap", "open3d", "pybullet", "gymnasium",
             "stable-baselines3", "numba", "deltalake")
ENV_PREFIXES = ("VID2SIM_", "OMP_", "NUMBA_", "MKL_", "CUDA_VISIBLE_DEVICES")
ROW_KEYS = ("benchmark", "case", "metric", "value", "unit", "config")


# ----------------------------------------------------------------------------- facts
def cpu_model() -> str:
    return (_cpuinfo_fields().get("model name") or platform.processor() or platform.machine()
            or "unknown CPU")


def _cpuinfo_fields() -> dict:
    """The first processor's `key: value` lines of /proc/cpuinfo ({} where there is none)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return {}
    out: dict = {}
    for line in text.splitlines():
        if not line.strip():
            break
        key, _, value = line.partition(":")
        out[key.strip()] = value.strip()
    return out


def cpu_id() -> Optional[str]:
    """Vendor, family and model numbers (e.g. "AuthenticAMD family 25 model 1"): a virtual
    machine's model name is often only "AMD EPYC", which hides the core generation."""
    f = _cpuinfo_fields()
    if "cpu family" not in f:
        return None
    return f"{f.get('vendor_id', '?')} family {f['cpu family']} model {f.get('model', '?')}"


SIMD_LEVELS = ("avx512f", "avx2", "avx", "sse4_2", "asimd")  # widest first


def simd_level() -> Optional[str]:
    """The widest vector instruction set the CPU reports (the numba kernels' speed depends on
    it: 16 float32 lanes with AVX-512, 8 with AVX2), or None where /proc/cpuinfo has no flags."""
    f = _cpuinfo_fields()
    flags = set((f.get("flags") or f.get("Features") or "").split())
    return next((level for level in SIMD_LEVELS if level in flags), None)


def memory_gib() -> Optional[float]:
    try:
        return round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1)
    except (ValueError, OSError, AttributeError):
        return None


def load_avg() -> list[float]:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except (OSError, AttributeError):
        return [float("nan")] * 3


def gpu_name() -> Optional[str]:
    """The first CUDA device's name via torch.cuda, or None. torch is only imported when the
    script already did or an NVIDIA driver is present (importing it costs seconds)."""
    if "torch" not in sys.modules and not (Path("/proc/driver/nvidia").exists() or Path("/dev/nvidia0").exists()):
        return None
    try:
        import torch

        if torch.cuda.is_available():
            n = torch.cuda.device_count()
            name = torch.cuda.get_device_name(0)
            return name if n == 1 else f"{n} x {name}"
    except Exception:  # a broken CUDA install must not stop a CPU benchmark
        pass
    return None


def hardware() -> dict:
    return {"cpu_model": cpu_model(), "cpu_id": cpu_id(), "simd": simd_level(),
            "cores": os.cpu_count(), "memory_gib": memory_gib(), "gpu": gpu_name(),
            "platform": f"{platform.system()} {platform.release()} {platform.machine()}"}


def git_state(repo: Path = REPO) -> dict:
    """{commit, dirty, branch} of the checkout (None each when git or the repo is absent)."""
    def git(*args: str) -> Optional[str]:
        try:
            r = subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, timeout=20)
        except (OSError, subprocess.TimeoutExpired):
            return None
        return r.stdout.strip() if r.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    status = git("status", "--porcelain", "--untracked-files=no") if commit else None
    return {"commit": commit, "dirty": None if status is None else bool(status),
            "branch": git("rev-parse", "--abbrev-ref", "HEAD") if commit else None}


def versions(extra: tuple[str, ...] = ()) -> dict:
    """python and the installed versions of LIBRARIES + extra (package metadata: no imports)."""
    out = {"python": f"{platform.python_implementation()} {platform.python_version()}"}
    for dist in (*LIBRARIES, *extra):
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            continue
    return out


def command_line(argv: Optional[list[str]] = None) -> str:
    """The command that ran, shell-quoted; the interpreter relative to the repo when inside it."""
    exe = Path(sys.executable)
    try:
        exe_s = str(exe.relative_to(REPO)) if exe.is_absolute() else str(exe)
    except ValueError:
        exe_s = exe.name if exe.parent.name == "bin" else str(exe)
    return shlex.join([exe_s, *(sys.argv if argv is None else argv)])


def cpu_seconds() -> float:
    """User + system CPU seconds this process has used so far (its threads included)."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def hardware_line() -> str:
    """CPU model, cores, loadavg and Python: enough to compare figures across runs."""
    load = load_avg()
    simd = simd_level()
    cpu = cpu_model() + (f" ({simd})" if simd else "")
    return (f"{cpu}; {os.cpu_count()} cores; loadavg {load[0]:.1f}/{load[1]:.1f}/{load[2]:.1f}; "
            f"{platform.python_implementation()} {platform.python_version()}")


# ----------------------------------------------------------------------------- the run
def add_run_args(ap: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds --results PATH (the results file or folder; see the module docstring)."""
    ap.add_argument("--results", default=None, metavar="PATH",
                    help=f"results JSON file or folder (default: ${RESULTS_ENV} or benchmarks/results/)")
    return ap


def jsonable(v: Any) -> Any:
    """Plain JSON value of v: numpy scalars and arrays, paths, tuples, NaN / inf handled."""
    if v is None or isinstance(v, (bool, str)):
        return v
    if isinstance(v, int):
        return int(v)
    if isinstance(v, float):
        return v if math.isfinite(v) else ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))
    if isinstance(v, Mapping):
        return {str(k): jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, set, frozenset)):
        return [jsonable(x) for x in v]
    if isinstance(v, Path):
        return str(v)
    if hasattr(v, "item") and getattr(v, "ndim", 1) == 0:  # numpy / torch scalar
        return jsonable(v.item())
    if hasattr(v, "tolist"):
        return jsonable(v.tolist())
    return str(v)


def first_paragraph(doc: str) -> str:
    """The first paragraph of a docstring, on one line."""
    return " ".join(doc.strip().split("\n\n")[0].split())


def utc_stamp(t: _dt.datetime) -> str:
    return t.strftime("%Y%m%dT%H%M%SZ")


class Run:
    """One benchmark run: header at start, rows while it runs, one JSON results file at the end.

    benchmark: the script's name (its file stem). args: the parsed argparse namespace (its
    `results` attribute, when there, is the output path; all of it is stored). results:
    output path (overrides args.results). config: run-level settings stored as they are.
    libraries: distributions whose versions matter beyond LIBRARIES (e.g. ("duckdb",)).
    """

    def __init__(self, benchmark: str, args: Optional[argparse.Namespace] = None, *,
                 results: Union[str, Path, None] = None, config: Optional[dict] = None,
                 argv: Optional[list[str]] = None, description: Optional[str] = None,
                 libraries: tuple[str, ...] = (), quiet: bool = False) -> None:
        self.benchmark = benchmark
        self.args = {k: v for k, v in vars(args).items() if k != "results"} if args is not None else {}
        self.results_arg = results or (getattr(args, "results", None) if args is not None else None)
        self.config: dict = dict(config or {})
        self.argv = list(sys.argv if argv is None else argv)
        main_doc = getattr(sys.modules.get("__main__"), "__doc__", None) or ""
        self.description = description or first_paragraph(main_doc)
        self.libraries = tuple(libraries)
        self.quiet = quiet
        self.rows: list[dict] = []
        self.notes: list[str] = []
        self.path: Optional[Path] = None
        self.started: Optional[_dt.datetime] = None
        self._t0 = 0.0
        self.info: dict = {}

    # -- recording
    def record(self, case: str, metric: str, value: Any, unit: str = "",
               config: Optional[Mapping] = None) -> Any:
        """Adds the row (benchmark, case, metric, value, unit, config); returns value."""
        self.rows.append({"benchmark": self.benchmark, "case": str(case), "metric": str(metric),
                          "value": jsonable(value), "unit": unit, "config": jsonable(dict(config or {}))})
        return value

    def record_all(self, case: str, values: Mapping[str, Any],
                   units: Union[str, Mapping[str, str]] = "", config: Optional[Mapping] = None) -> None:
        """One row per metric of `values` for `case`; units: one string or {metric: unit}."""
        for metric, value in values.items():
            unit = units if isinstance(units, str) else units.get(metric, "")
            self.record(case, metric, value, unit, config)

    def note(self, text: str) -> None:
        """A remark stored with the run (and shown on its docs page)."""
        self.notes.append(text)

    def skip(self, case: str, reason: str) -> None:
        """Prints `SKIP case: reason` and notes it: for cases whose data is absent."""
        print(f"SKIP {case}: {reason}", flush=True)
        self.notes.append(f"skipped {case}: {reason}")

    # -- start / end
    def header_line(self) -> str:
        hw, load, g = self.info["hardware"], self.info["load"]["start"], self.info["git"]
        gpu = hw["gpu"] or "no GPU"
        commit = (g["commit"] or "no git")[:12] + (" (dirty)" if g["dirty"] else "")
        cpu = hw["cpu_model"] + (f" ({hw['simd']})" if hw.get("simd") else "")
        return (f"# {self.benchmark}: {cpu}, {hw['cores']} cores, {hw['memory_gib']} GiB, {gpu} | "
                f"load {load[0]:.2f} | commit {commit} | {self.info['command']}")

    def start(self) -> "Run":
        self.started = _dt.datetime.now(_dt.timezone.utc)
        self._t0 = time.perf_counter()
        env = {k: v for k, v in sorted(os.environ.items()) if k.startswith(ENV_PREFIXES) and k != RESULTS_ENV}
        self.info = {"command": command_line(self.argv), "argv": self.argv, "cwd": os.getcwd(), "env": env,
                     "hardware": hardware(), "load": {"start": load_avg()}, "git": git_state(),
                     "versions": versions(self.libraries)}
        if not self.quiet:
            print(self.header_line(), flush=True)
        return self

    def output_path(self) -> tuple[Path, bool]:
        """(results file, whether its name was made here) from --results / $VID2SIM_BENCH_RESULTS."""
        target = str(self.results_arg or os.environ.get(RESULTS_ENV) or "")
        name = f"{self.benchmark}-{utc_stamp(self.started)}.json"
        if not target:
            return RESULTS_DIR / name, True
        p = Path(target)
        if p.is_dir() or target.endswith(("/", os.sep)):
            return p / name, True
        return p, False

    def to_dict(self, status: str = "ok") -> dict:
        end = _dt.datetime.now(_dt.timezone.utc)
        return {"schema": SCHEMA, "benchmark": self.benchmark, "description": self.description,
                "status": status, "started_utc": self.started.isoformat(timespec="seconds"),
                "started_unix": round(self.started.timestamp(), 6),
                "finished_utc": end.isoformat(timespec="seconds"),
                "duration_s": round(time.perf_counter() - self._t0, 2),
                "command": self.info["command"], "argv": self.argv, "cwd": self.info["cwd"],
                "args": jsonable(self.args), "config": jsonable(self.config), "env": self.info["env"],
                "hardware": self.info["hardware"],
                "load": {"start": self.info["load"]["start"], "end": load_avg()},
                "git": self.info["git"], "versions": self.info["versions"],
                "notes": self.notes, "rows": self.rows}

    def finish(self, status: str = "ok") -> Path:
        """Writes the results file (atomically) and returns its path."""
        data = self.to_dict(status)
        path, named_here = self.output_path()
        path.parent.mkdir(parents=True, exist_ok=True)
        if named_here and path.exists():  # two runs of one benchmark in the same second
            path = path.with_name(f"{path.stem}-{os.getpid()}.json")
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(data, indent=1) + "\n")
        os.replace(tmp, path)
        self.path = path
        if not self.quiet:
            load = data["load"]["end"]
            what = "" if status == "ok" else f" ({status[:80]})"
            print(f"# {self.benchmark}{what}: {len(self.rows)} rows -> {_shown(path)} "
                  f"({data['duration_s']:.0f} s, load at end {load[0]:.2f})", flush=True)
        return path

    def __enter__(self) -> "Run":
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None or exc_type is SystemExit and exc.code in (0, None):
            self.finish()
        elif exc_type is not KeyboardInterrupt:
            self.finish(f"failed: {exc_type.__name__}: {exc}")
        return False


def _shown(p: Path) -> str:
    try:
        return str(p.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(p)


def load_results(folder: Union[str, Path] = RESULTS_DIR) -> list[dict]:
    """Every results file in `folder` (sorted by start time); unreadable files are skipped."""
    out = []
    for p in sorted(Path(folder).glob("*.json")):
        try:
            d = json.loads(p.read_text())
        except (OSError, ValueError):
            continue
        if isinstance(d, dict) and d.get("schema") == SCHEMA and "rows" in d:
            d["_path"] = str(p)
            out.append(d)
    return sorted(out, key=run_order)


def run_order(d: dict) -> tuple:
    """Sort key of a results file: its start (to the microsecond), then its path."""
    start = d.get("started_unix")
    if start is None:
        try:
            start = _dt.datetime.fromisoformat(d.get("started_utc", "")).timestamp()
        except ValueError:
            start = 0.0
    return (start, d.get("_path", ""))
