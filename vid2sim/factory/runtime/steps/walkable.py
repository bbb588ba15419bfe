"""walkable: meshing outputs + camera path -> the physical layer, its corridor report and gate.

Reads: meshing/ (`ground_points.npy`, `carved_points.npy`, `collision.ply`), metric/ (the
camera path).
Writes (walkable/): `walkable.npz`, the shipped `collision.ply` (agrees with the map),
`walkable.json`, `corridor.json` (the corridor report, part of the work, so before the marker).
Then the step's check, the corridor gate, reads the report and may fail the clip, also on a
cached folder; it writes nothing.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from vid2sim.factory.evaluation.corridor import CorridorConfig, corridor_check, gate_reasons
from vid2sim.factory.geometry import walkable as stage
from vid2sim.factory.geometry.walkable import WalkableConfig
from vid2sim.factory.runtime.stage_cache import StageError, StageWork
from vid2sim.factory.runtime.steps import meshing, metric
from vid2sim.factory.runtime.steps.base import StepOutputs
from vid2sim.formats.walkable import load_walkable
from vid2sim.ranges import checked
from vid2sim.versioning import config_hash

NAME = stage.STAGE
VERSION = stage.STAGE_VERSION
CORRIDOR_REPORT = "corridor.json"


@checked
@dataclass(frozen=True)
class Config:
    walkable: WalkableConfig  # the walkable map and the physical collision mesh
    corridor: CorridorConfig  # the walked-corridor check and its gate (decides corridor.json)


@dataclass(frozen=True)
class Inputs:
    metric: metric.Outputs
    meshing: meshing.Outputs


@dataclass(frozen=True)
class Outputs(StepOutputs):
    @property
    def grid(self) -> Path:
        return self.dir / stage.OUTPUTS.grid

    @property
    def collision(self) -> Path:
        return self.dir / stage.OUTPUTS.collision

    @property
    def summary(self) -> Path:
        return self.dir / stage.OUTPUTS.summary

    @property
    def corridor(self) -> Path:
        return self.dir / CORRIDOR_REPORT


def configure(conf, job) -> Config:
    return Config(conf.walkable, conf.corridor)


def work(conf: Config, inputs: Inputs) -> StageWork:
    """The physical layer and its corridor report; keyed by the walkable config, the meshing and
    metric keys and the corridor config (it decides corridor.json, a file of this step)."""
    key = config_hash(inputs.meshing.key, inputs.metric.key, conf.corridor)
    return StageWork(NAME, stage.STAGE_VERSION, conf.walkable, (key,), lambda out_dir: build(conf, inputs, out_dir))


def build(conf: Config, inputs: Inputs, out_dir: Path) -> dict:
    """walkable.npz, collision.ply, walkable.json, then corridor.json; returns the summary."""
    mesh = inputs.meshing
    path = np.array([f.cam_to_world[:3, 3] for f in inputs.metric.clip().frames])  # [T, 3]
    ground = stage.load_points(mesh.ground_points, "bad_ground_points")
    carved = stage.load_points(mesh.carved_points, "bad_carved_points") if mesh.carved_points.is_file() else None
    summary = stage.build(conf.walkable, ground, mesh.collision, path, out_dir, carved_points=carved)
    corridor_report(conf.corridor, out_dir, path)
    return summary


def check(conf: Config, out: Outputs) -> None:
    """The corridor gate on the finished folder's report (after the marker; writes nothing)."""
    corridor_gate(read_corridor_report(out))


def corridor_report(conf: CorridorConfig, walk_dir: Path, path: np.ndarray) -> dict:
    """Corridor check (vid2sim.factory.evaluation.corridor) of the physical layer in walk_dir
    (walkable.npz + the collision.ply the bundle ships) and its quality-gate verdict, written to
    walk_dir/corridor.json; returns the record."""
    walk = Outputs(Path(walk_dir))
    mesh = trimesh.load(walk.collision, force="mesh", process=False)
    report = corridor_check(load_walkable(walk.grid), mesh, path, conf)
    reasons = gate_reasons(report, conf)
    out = {**report.to_dict(), "passed": not reasons, "reasons": ",".join(reasons)}
    walk.corridor.write_text(json.dumps(out, indent=2))
    return out


def read_corridor_report(walk: Outputs) -> dict:
    try:
        return json.loads(walk.corridor.read_text())
    except (OSError, ValueError) as e:
        raise StageError(NAME, "bad_corridor_report", f"{walk.corridor}: {e}") from None


def corridor_gate(report: dict) -> None:
    """The quality gate on a corridor report (`corridor_report`): raises
    StageError('walkable', reason) when the walked corridor is blocked; writes nothing."""
    reasons = [r for r in str(report.get("reasons", "")).split(",") if r]
    if reasons:
        raise StageError(NAME, reasons[0], f"walked corridor check failed ({', '.join(reasons)}): "
                         f"{report['walkable_fraction']:.1%} of the path walkable, "
                         f"{report['path_components']} components, "
                         f"{report['corridor_area_m2']:.3f} m^2 of collision surface in the corridor")


def check_corridor(conf: CorridorConfig, walk_dir: Path, path: np.ndarray) -> dict:
    """`corridor_report` then `corridor_gate`: the report written to walk_dir/corridor.json,
    StageError('walkable', reason) when the walked corridor is blocked."""
    out = corridor_report(conf, walk_dir, path)
    corridor_gate(out)
    return out
