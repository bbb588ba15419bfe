"""Every numeric field of every config the command line runs with (`vid2sim config show`'s
sections, walked from the configs themselves) refuses a value outside its range by name, and its
default lies inside. The same holds for the Python API: every `*Config` dataclass of the training,
env, registry, factory and splat packages (StudyConfig, DistillConfig, EvalConfig, PipelineConfig,
ReconConfig, DecodeConfig, ...) checks its fields whenever it is built or loaded."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import json
import math
import pkgutil
import re
import types
import typing
from typing import Any

import pytest
from typer.testing import CliRunner

from vid2sim.cli.app import app
from vid2sim.cli.settings import (SECTIONS, _placeholder, apply_eval_overrides, apply_overrides, describe_section,
                                  section_config, type_hints)
from vid2sim.factory.geometry.meshing import MeshingConfig
from vid2sim.factory.geometry.walkable import WalkableConfig
from vid2sim.factory.ingest.decode import DecodeConfig
from vid2sim.factory.recon.config import ReconConfig
from vid2sim.factory.recon.config import preset as recon_preset
from vid2sim.factory.sfm.metric import MetricConfig
from vid2sim.factory.synthetic.config import preset as street_preset
from vid2sim.ranges import CHECKED, RangeError, check_ranges, field_range
from vid2sim.splats.cpu.env_simfit import FitConfig
from vid2sim.splats.cpu.env_simready import SimReadyConfig
from vid2sim.training.config import DistillConfig, TrainConfig
from vid2sim.training.evaluate import EvalConfig
from vid2sim.training.study import StudyConfig, StudyError, run_study


def base(section: str) -> Any:
    conf = section_config(section)
    return _placeholder(conf) if isinstance(conf, type) else conf


NUMERIC_TYPE = re.compile(r"\b(int|float)\b")


def fields(section: str) -> list[tuple[str, Any, bool]]:
    """(path, default, holds floats) of every numeric field, unset (None) sections followed into, as
    `config show` lists them."""
    return [(r.path, r.default, "float" in r.type) for r in describe_section(section)
            if not r.section and NUMERIC_TYPE.search(r.type) and "bool" not in r.type]


FIELDS = [(s, *row) for s in SECTIONS for row in fields(s)]


def apply(section: str, sets: list[str]) -> Any:
    return (apply_eval_overrides if section == "eval" else apply_overrides)(base(section), sets)


def bad_values(path: str, floats: bool) -> list[Any]:
    rng = field_range(path.rsplit(".", 1)[-1])
    out: list[Any] = []
    if rng.lo is not None:
        out.append(rng.lo if rng.lo_open else (rng.lo - 1 if not floats else rng.lo - 0.5))
    if rng.hi is not None:
        out.append(rng.hi + 1)
    if floats:
        out += [math.nan, math.inf]
    return out


def as_set(path: str, value: Any, bad: Any) -> str:
    """`path=...` with `bad` as the value (the first item for a tuple / list field)."""
    if isinstance(value, (list, tuple)):
        return f"{path}={json.dumps([bad, *list(value)[1:]] if value else [bad])}"
    return f"{path}={bad}"


def test_the_walk_covers_every_section():
    paths = {(s, p) for s, p, _, _ in FIELDS}
    assert {("ingest", "metric.capture_height_m"), ("train", "total_steps"), ("train", "sac.batch_size"),
            ("eval", "trials"), ("env", "augment.fog_prob"), ("eval", "env.camera.width")} <= paths
    assert len(FIELDS) > 250


@pytest.mark.parametrize("section", SECTIONS)
def test_defaults_lie_inside_their_ranges(section):
    apply(section, [])


@pytest.mark.parametrize("section,path,value,floats", FIELDS, ids=[f"{s}:{p}" for s, p, _, _ in FIELDS])
def test_out_of_range_value_is_named(section, path, value, floats):
    values = bad_values(path, floats)
    assert values, f"{path} has no range"
    for bad in values:
        with pytest.raises(RangeError, match=rf"{re.escape(path)}: .* is out of range \(must be "):
            apply(section, [as_set(path, value, bad)])


@pytest.mark.parametrize("sets,named", [
    (["metric.capture_height_m=0"], "metric.capture_height_m"),
    (["decode.fps=-1"], "decode.fps"),
    (["decode.jpeg_quality=101"], "decode.jpeg_quality"),
])
def test_cli_reports_a_field_out_of_range(sets, named):
    args = ["config", "show", "ingest", *[a for s in sets for a in ("--set", s)], "--json"]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 2 and r.stderr.startswith(f"error: --set {sets[0]}: {named}: ")
    assert json.loads(r.stdout)["error"]["type"] == "RangeError"


# ------------------------------------------------------------------ the Python API: configs check themselves

CONFIG_PACKAGES = ("vid2sim.training", "vid2sim.envs", "vid2sim.registry", "vid2sim.factory", "vid2sim.splats")


def user_facing_configs() -> list[type]:
    """Every dataclass named `*Config` defined in the training, env, registry, factory and splat packages
    (a factory step's own `Config` included)."""
    found = []
    for name in CONFIG_PACKAGES:
        pkg = importlib.import_module(name)
        for info in pkgutil.walk_packages(pkg.__path__, name + "."):
            mod = importlib.import_module(info.name)
            found += [obj for attr, obj in vars(mod).items() if inspect.isclass(obj) and attr.endswith("Config")
                      and obj.__module__ == mod.__name__ and dataclasses.is_dataclass(obj)]
    return sorted(found, key=lambda c: (c.__name__, c.__module__))


def label(cls: type) -> str:
    """The class name; a step's `Config` with its module's name (`walkable.Config`)."""
    return f"{cls.__module__.rsplit('.', 1)[-1]}.{cls.__name__}" if cls.__name__ == "Config" else cls.__name__


CONFIGS = user_facing_configs()
STAND_INS = {str: "", int: 1, float: 1.0, bool: False}


def leaf_types(tp: Any) -> set:
    """The scalar types a field annotation holds (through Optional, tuple and list; dicts hold none here)."""
    origin = typing.get_origin(tp)
    if origin is dict or tp is dict:
        return set()
    if origin in (typing.Union, types.UnionType, tuple, list):
        return set().union(*(leaf_types(a) for a in typing.get_args(tp) if a is not Ellipsis))
    return {tp}


def built(cls: type) -> Any:
    """`cls` with its required fields given stand-ins (a count list: [1])."""
    hints = type_hints(cls)
    required = {f.name for f in dataclasses.fields(cls)
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING}
    return cls(**{n: [1] if typing.get_origin(hints[n]) is list else STAND_INS.get(hints[n]) for n in required})


def own_numeric_fields(cls: type) -> list[tuple[str, bool]]:
    """(name, holds floats) of the class's own numeric fields (nested configs are classes of their own)."""
    out = []
    for name, tp in type_hints(cls).items():
        kinds = leaf_types(tp)
        if kinds & {int, float} and bool not in kinds:
            out.append((name, float in kinds))
    return out


def with_item(value: Any, bad: Any) -> Any:
    """`bad` in place of a scalar, or as the first item of a tuple / list (kept its type)."""
    if isinstance(value, (tuple, list)):
        return type(value)([bad, *value[1:]])
    return bad


API_FIELDS = [(cls, name, floats) for cls in CONFIGS for name, floats in own_numeric_fields(cls)]


def test_every_config_checks_itself():
    names = {c.__name__ for c in CONFIGS}
    assert {"StudyConfig", "DistillConfig", "StudentConfig", "EvalConfig", "TrainConfig", "SACConfig", "EnvConfig",
            "AugmentConfig", "SplitConfig"} <= names
    assert {"PipelineConfig", "DecodeConfig", "FaceConfig", "PlateConfig", "MasksConfig", "SfMConfig", "MetricConfig",
            "ReconConfig", "DensifyConfig", "MeshingConfig", "WalkableConfig", "CorridorConfig", "StreetConfig",
            "FitConfig", "SimReadyConfig", "StaticSceneConfig"} <= names
    assert {"meshing.Config", "walkable.Config", "bundle.Config"} <= {label(c) for c in CONFIGS}
    assert [label(c) for c in CONFIGS if c not in CHECKED] == []
    assert len(API_FIELDS) > 300


@pytest.mark.parametrize("cls", CONFIGS, ids=[label(c) for c in CONFIGS])
def test_config_defaults_lie_inside_their_ranges(cls):
    check_ranges(built(cls))


@pytest.mark.parametrize("cls,name,floats", API_FIELDS, ids=[f"{label(c)}.{n}" for c, n, _ in API_FIELDS])
def test_building_a_config_out_of_range_is_named(cls, name, floats):
    base = built(cls)
    value = getattr(base, name)
    for bad in bad_values(name, floats):
        with pytest.raises(RangeError, match=rf"^{cls.__name__}\.{name}: .* is out of range \(must be "):
            dataclasses.replace(base, **{name: with_item(value, bad)})


@pytest.mark.parametrize("build,named", [
    (lambda: StudyConfig(registry="r", out_dir="o", counts=[1, -3]), "StudyConfig.counts: -3"),
    (lambda: StudyConfig(registry="r", out_dir="o", counts=[1], total_steps=0), "StudyConfig.total_steps: 0"),
    (lambda: StudyConfig(registry="r", out_dir="o", counts=[1], num_cpus_per_run=math.nan),
     "StudyConfig.num_cpus_per_run: nan"),
    (lambda: DistillConfig(batch_size=0), "DistillConfig.batch_size: 0"),
    (lambda: DistillConfig(student={"pool": 0}), "StudentConfig.pool: 0"),
    (lambda: EvalConfig(registry="r", policy="p", trials=-1), "EvalConfig.trials: -1"),
    (lambda: TrainConfig(run_dir="x", total_steps=10, train_scenes=0), "TrainConfig.train_scenes: 0"),
    (lambda: TrainConfig.from_dict({"run_dir": "x", "total_steps": 10, "sac": {"gamma": math.inf}}),
     "SACConfig.gamma: inf"),
])
def test_python_api_names_the_field_and_the_reason(build, named):
    with pytest.raises(RangeError, match=rf"^{re.escape(named)} is out of range \(must be "):
        build()


@pytest.mark.parametrize("build,named", [
    (lambda: DecodeConfig(fps=0), "DecodeConfig.fps: 0"),
    (lambda: DecodeConfig(jpeg_quality=101), "DecodeConfig.jpeg_quality: 101"),
    (lambda: dataclasses.replace(recon_preset("fast"), iterations=0), "ReconConfig.iterations: 0"),
    (lambda: recon_preset("quick", coarse_scale=1.5), "ReconConfig.coarse_scale: 1.5"),
    (lambda: ReconConfig.from_dict({"densify": {"every": 0}}), "DensifyConfig.every: 0"),
    (lambda: MeshingConfig(voxel_m=math.nan), "MeshingConfig.voxel_m: nan"),
    (lambda: WalkableConfig(resolution_m=-0.1), "WalkableConfig.resolution_m: -0.1"),
    (lambda: MetricConfig(capture_height_m=math.inf), "MetricConfig.capture_height_m: inf"),
    (lambda: street_preset("test", pitch_deg=-91.0), "StreetConfig.pitch_deg: -91.0"),
    (lambda: FitConfig(iterations=0), "FitConfig.iterations: 0"),
    (lambda: SimReadyConfig(keep_mass=1.5), "SimReadyConfig.keep_mass: 1.5"),
])
def test_factory_and_splat_configs_name_the_field_and_the_reason(build, named):
    with pytest.raises(RangeError, match=rf"^{re.escape(named)} is out of range \(must be "):
        build()


def test_factory_presets_lie_inside_their_ranges():
    from vid2sim.factory.ingest.decode import PRESETS as DECODE
    from vid2sim.factory.recon.config import PRESETS as RECON
    from vid2sim.factory.runtime.config import preset
    from vid2sim.factory.sfm.sfm import preset as sfm_preset
    from vid2sim.factory.synthetic.config import PRESETS as STREETS
    from vid2sim.factory.synthetic.config import varied

    built_ = [preset(n) for n in ("fast", "paper")] + [make() for make in RECON.values()]
    built_ += [sfm_preset(n) for n in ("fast", "accurate")] + list(DECODE.values()) + list(STREETS.values())
    built_ += [varied(seed) for seed in range(40)]
    for conf in built_:
        check_ranges(conf)


def test_a_loaded_pipeline_config_is_checked(tmp_path):
    from vid2sim.factory.runtime.config import PipelineConfig, preset

    path = preset("fast").save(tmp_path / "pipeline.json")
    data = json.loads(path.read_text())
    data["walkable"]["robot_radius_m"] = -0.25
    path.write_text(json.dumps(data))
    with pytest.raises(RangeError, match=r"^WalkableConfig.robot_radius_m: -0.25 is out of range \(must be "):
        PipelineConfig.load(path)


def test_a_loaded_run_config_is_checked(tmp_path):
    path = tmp_path / "config.json"
    TrainConfig(run_dir="x", total_steps=10).save(path)
    path.write_text(path.read_text().replace('"batch_size": 128', '"batch_size": 0'))
    with pytest.raises(RangeError, match=r"^DistillConfig.batch_size: 0 is out of range"):
        TrainConfig.load(path)


def test_study_counts_beyond_the_train_pool_are_a_named_error(tmp_path):
    """The pool is the registry split's train side: a larger count is refused before any training starts."""
    from registry_fixtures import make_bundle

    from vid2sim.registry import Registry

    reg = Registry(tmp_path / "reg")
    for i in range(5):
        reg.add(make_bundle(tmp_path / f"b{i}", f"scene-{i}", group=f"walk-{i}", seed=i, n_splats=20))
    pool = len(reg.split(seed=0).train)
    config = StudyConfig(registry=str(reg.root), out_dir=str(tmp_path / "study"), counts=[1, pool + 1], seeds=1)
    with pytest.raises(StudyError, match=rf"bad_count: training-scene counts \[{pool + 1}\] are outside 1\.\.{pool}"):
        run_study(config)
    assert not list((tmp_path / "study").glob("n*_s*"))
