"""A stage's folder and file names are spelled once: in the stage's own modules.

The names: the stage folders (`steps.STEP_NAMES`), every path of each step's `Outputs` record
and of its stage module's `OUTPUTS` record (each '/'-part too), and the marker
(`stage_cache.MARKER`). Such a name may be a string literal only in the step module
(`factory/runtime/steps/<stage>.py`), the module that declares the stage's `OUTPUTS` record, and
the runner, marker and staging modules (`runner.py`, `stage_cache.py`, `staging.py`,
`object_store.py`); every other module of vid2sim/ takes it from those records. The string
constants are found with `ast`, so comments and docstrings do not count (f-string pieces do); a
constant matches when it, or one of its '/'-parts, is a name. `GENERIC` names the three generic
words that are not guarded, and `ALLOWED_BY` the literals that spell a guarded name for another
purpose, each with its reason; an entry that no longer matches fails too, so the list cannot go
stale.
"""

from __future__ import annotations

import ast
import sys
from dataclasses import asdict
from pathlib import Path

from vid2sim.factory.runtime import object_store, runner, stage_cache, staging
from vid2sim.factory.runtime.stage_cache import MARKER
from vid2sim.factory.runtime.steps import STEPS
from vid2sim.formats.bundle import IGNORED_FILES

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "vid2sim"

# Generic words that are also an output folder's name; not guarded, as most of their literals
# name something else.
GENERIC = {
    "images": "any image folder: the `images` source kind, COLMAP's and nerfstudio's image folders",
    "sparse": "COLMAP's model folder (sfm's sparse/0 and undistorted/sparse, any COLMAP project)",
    "scene": "table headings, the viewer's scene graph (/scene/...), scene.json",
}

# Literals that spell a guarded name for another purpose: (module, names, why).
ALLOWED_BY = [
    ("vid2sim/cli/app.py", ("sfm", "recon"), "the `vid2sim sfm` and `vid2sim recon` command groups"),
    ("vid2sim/cli/sfm.py", ("metric",), "the `vid2sim sfm metric` command"),
    ("vid2sim/cli/eval.py", ("metric",), "a table column heading"),
    ("vid2sim/factory/runtime/steps/bundle.py", ("recon", "sfm", "meshing", "walkable"),
     "scene.json's metric groups ('recon.psnr', read by the viewer and the demo): a format key"),
    ("vid2sim/envs/scenes.py", ("walkable",), "the `walkable` section of the pipeline config in scene.json"),
    ("vid2sim/factory/synthetic/gt_bundle.py", ("bundle",), "the `bundle` section of the config in scene.json"),
    ("vid2sim/factory/synthetic/render.py", ("walkable",), "a key of the ground truth's file list"),
    ("vid2sim/viewer/scene_view.py", ("walkable",), "a node of the viewer's scene graph (/scene/walkable)"),
    ("vid2sim/factory/sfm/sfm.py", ("masks",), "the undistorted COLMAP project's masks/ (sfm's own layout)"),
    ("vid2sim/factory/sfm/undistort.py", ("masks",), "the undistorted COLMAP project's masks/ (sfm's own layout)"),
    ("vid2sim/factory/sfm/metric.py", ("masks",), "the sfm folder's undistorted/masks, not the masks stage's"),
    ("vid2sim/factory/ingest/video_io.py", ("decode",),
     "the failure label of the video reader; decode.py imports it, so it cannot import decode.STAGE"),
    ("vid2sim/formats/bundle.py", ("collision.ply", "visual_mesh.ply"), "the scene bundle's file names"),
    ("vid2sim/formats/splat_ply.py", ("splats.ply",), "the scene bundle's file name"),
    ("vid2sim/formats/walkable.py", ("walkable.npz",),
     "the bundle's walkable grid; walkable.OUTPUTS.grid takes its name from here"),
    ("vid2sim/formats/bundle.py", (MARKER,),
     "a bundle ignores a marker beside its files; formats sits below the factory (checked equal below)"),
]
ALLOWED = {(module, name) for module, names, _ in ALLOWED_BY for name in names}


def _rel(module_name: str) -> str:
    return Path(sys.modules[module_name].__file__).resolve().relative_to(ROOT).as_posix()


def _paths(record: type) -> set[str]:
    """The relative paths an `Outputs` record names (its Path properties)."""
    out = record(Path("STEP"))
    props = [n for n, v in vars(record).items() if isinstance(v, property)]
    return {getattr(out, n).relative_to("STEP").as_posix() for n in props if isinstance(getattr(out, n), Path)}


def guarded_names() -> dict[str, set[str]]:
    """{name: the modules that may spell it}."""
    common = {_rel(m.__name__) for m in (runner, stage_cache, staging, object_store)}
    owners: dict[str, set[str]] = {MARKER: set(common)}
    for step in STEPS:
        step_module = sys.modules[step.outputs.__module__]
        mine, paths = {_rel(step_module.__name__)}, _paths(step.outputs)
        for stage in vars(step_module).values():  # the stage code module(s) the step wraps
            if getattr(stage, "STAGE", None) == step.name and hasattr(stage, "OUTPUTS"):
                mine.add(_rel(type(stage.OUTPUTS).__module__))
                paths |= set(asdict(stage.OUTPUTS).values())
        for name in {step.name} | {part for p in paths for part in p.split("/")}:
            owners.setdefault(name, set(common)).update(mine)
    return owners


def _strings(tree: ast.AST) -> list[ast.Constant]:
    """String constants that are not docstrings (a bare string statement is a docstring)."""
    docs = {id(n.value) for n in ast.walk(tree) if isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant)}
    return [n for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs]


def _spelled_in(source: str, rel: str, owners: dict[str, set[str]]) -> list[tuple[str, str, int, str]]:
    """(module, name, line, literal) of every literal of `source` spelling a name `rel` does not own."""
    found = []
    for node in _strings(ast.parse(source, rel)):
        for name in sorted(({node.value} | set(node.value.split("/"))) & (owners.keys() - GENERIC.keys())):
            if rel not in owners[name]:
                found.append((rel, name, node.lineno, node.value))
    return found


def spelled() -> list[tuple[str, str, int, str]]:
    """The literals of every module of vid2sim/ that spell a guarded name outside its owners."""
    owners = guarded_names()
    return [hit for path in sorted(PACKAGE.rglob("*.py"))
            for hit in _spelled_in(path.read_text(), path.relative_to(ROOT).as_posix(), owners)]


def test_no_module_spells_another_stages_folder_or_file_names():
    found = spelled()
    bad = [f"{m}:{line}: {lit!r} spells {name!r}" for m, name, line, lit in found if (m, name) not in ALLOWED]
    assert not bad, "read these names from the owning stage's record:\n" + "\n".join(bad)
    stale = set(ALLOWED) - {(m, name) for m, name, _, _ in found}
    assert not stale, f"allow-list entries that match nothing any more: {sorted(stale)}"


def test_the_names_come_from_the_records():
    owners = guarded_names()
    assert {"recon", "bundle", "splats.ply", "metrics.json", "corridor.json", "walkable.npz", MARKER} <= owners.keys()
    assert "vid2sim/factory/recon/data.py" in owners["metrics.json"]
    assert "vid2sim/factory/runtime/steps/walkable.py" in owners["corridor.json"]
    assert owners["collision.ply"] >= {"vid2sim/factory/geometry/meshing.py", "vid2sim/factory/geometry/walkable.py"}
    assert GENERIC.keys() <= owners.keys()
    assert MARKER in IGNORED_FILES  # the bundle contract's literal is the marker's name


def test_the_scan_sees_literals_not_docstrings_or_comments():
    source = '''"""Reads recon/metrics.json."""
def f(out, clip):
    """Writes walkable/."""
    # corridor.json
    return out / "walkable", f"{clip}/recon/metrics.json", "walkable.json".upper()
'''
    hits = {(name, line) for _, name, line, _ in _spelled_in(source, "vid2sim/other.py", guarded_names())}
    assert hits == {("walkable", 5), ("recon", 5), ("metrics.json", 5), ("walkable.json", 5)}
