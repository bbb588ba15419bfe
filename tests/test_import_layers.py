"""Import contract: the package layers only import downward, and no module cycles.

Layers (low -> high): formats, versioning, ranges, threads, vid2sim/__init__ (the base, importing each other
without cycles) < splats, registry < factory <
envs < training < viewer < cli. splats and registry do not import each other. Inside the factory the
stage packages only import downward too: ingest < sfm < recon < geometry < synthetic <
evaluation < runtime, with `runtime.stage_cache` (the stage marker/error base) usable by all.
Every import counts, also those inside functions, so a lazy import cannot dodge the rule.
Reads the source files only (AST); imports nothing.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "vid2sim"
LAYERS = {"formats": 0, "versioning": 0, "bullet": 0, "ranges": 0, "threads": 0, "": 0, "splats": 1, "registry": 1,
          "factory": 2, "envs": 3, "training": 4, "viewer": 5, "cli": 6}
FACTORY = {"stage_base": 0, "ingest": 1, "sfm": 2, "recon": 3, "geometry": 4, "synthetic": 5,
           "evaluation": 6, "runtime": 7, "": 7}
FACTORY_BASE = ("vid2sim.factory.runtime.stage_cache",)


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path: Path, name: str) -> list[tuple[str, int]]:
    """(absolute vid2sim module, line) for every import in the file, at any depth."""
    pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names if a.name.startswith("vid2sim")]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            if base.startswith("vid2sim"):
                out += [(_submodule(base, a.name), node.lineno) for a in node.names]
    return out


def _submodule(base: str, name: str) -> str:
    cand = ROOT.parent / Path(*f"{base}.{name}".split("."))
    return f"{base}.{name}" if cand.with_suffix(".py").exists() or cand.is_dir() else base


def all_modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def top(mod: str) -> str:
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 else ""


def factory_rank(mod: str) -> int:
    if mod.startswith(FACTORY_BASE):
        return FACTORY["stage_base"]
    parts = mod.split(".")
    return FACTORY[parts[2] if len(parts) > 3 else ""]


def violation(src: str, dst: str) -> str | None:
    """Why importing dst from src breaks the layering, or None."""
    a, b = top(src), top(dst)
    if a == b:
        if a == "factory" and factory_rank(dst) > factory_rank(src):
            return "factory stage imports a later stage"
        return None
    if LAYERS[b] > LAYERS[a] or (LAYERS[b] == LAYERS[a] > 0):
        return f"layer {a or 'vid2sim'} imports {b} (same or higher layer)"
    return None


def test_every_package_is_in_a_layer():
    unknown = sorted({top(m) for m in all_modules()} - set(LAYERS))
    assert not unknown, f"packages without a layer: {unknown} (add them to LAYERS)"


def test_imports_only_go_down_the_layers():
    bad = []
    for mod, path in all_modules().items():
        for dst, line in imported_modules(path, mod):
            why = violation(mod, dst)
            if why:
                bad.append(f"{path.relative_to(ROOT.parent)}:{line} {mod} -> {dst}: {why}")
    assert not bad, "import layering broken:\n" + "\n".join(bad)


def test_no_import_cycles_between_modules():
    mods = all_modules()
    graph = {m: {d for d, _ in imported_modules(p, m) if d in mods and d != m} for m, p in mods.items()}
    cycle = _find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def _find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for d in sorted(graph[n]):
            if state.get(d) == 1:
                return stack[stack.index(d):] + [d]
            if d not in state and (c := visit(d)):
                return c
        state[n] = 2
        stack.pop()
        return None

    for n in sorted(graph):
        if n not in state and (c := visit(n)):
            return c
    return None


@pytest.mark.parametrize("src,dst,bad", [
    ("vid2sim.registry.store", "vid2sim.factory.sfm.posed", True),
    ("vid2sim.formats.bundle", "vid2sim.splats.ply", True),
    ("vid2sim.splats.ply", "vid2sim.registry.store", True),
    ("vid2sim.factory.ingest.decode", "vid2sim.factory.geometry.meshing", True),
    ("vid2sim.cli.ingest", "vid2sim.factory.runtime.pipeline", False),
    ("vid2sim.factory.geometry.walkable", "vid2sim.factory.runtime.stage_cache", False),
    ("vid2sim.formats.scene", "vid2sim.versioning", False),
    ("vid2sim.versioning", "vid2sim.registry.store", True),
])
def test_the_checker_catches_arrows_back(src, dst, bad):
    assert (violation(src, dst) is not None) == bad


def test_the_cycle_finder_finds_a_cycle():
    assert _find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _find_cycle({"a": {"b"}, "b": set()}) is None
