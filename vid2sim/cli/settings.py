"""Config introspection and `--set section.field=value` overrides for the command line.

`describe(config)` lists every field of a config dataclass, recursively through nested
dataclasses, with its type, value, unit and one line of meaning. Meaning and unit come from the
source: a field's trailing comment (plus the comment lines continuing it), the comment block
right above a field that has no trailing comment, an attribute docstring, or
`field(metadata={"help": ..., "unit": ...})`. A unit is a leading unit token of the comment
("m, footprint box", "Hz", "1/m: ...") or a unit suffix of the name (`_m`, `_deg`, `_px`, ...).

`apply_overrides(config, ["recon.iterations=500", "decode.fps=5"])` returns a copy with the
dotted fields replaced, each value parsed by the field's type: int, float, bool, str, Literal,
Optional (`none` / `null`), tuple / list (comma-separated or JSON), dict (JSON), or a nested
dataclass (a JSON object of its fields). `apply_eval_overrides` does the same for an
`EvalConfig`, whose `env.` paths reach the evaluation env config. A bad override raises
`SettingError` with a one-line message naming the field and the reason.
"""

from __future__ import annotations

import ast
import dataclasses
import difflib
import inspect
import io
import json
import re
import textwrap
import tokenize
import types
import typing
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Optional, Sequence

from vid2sim.ranges import RangeError, check_ranges, check_value

MISSING = dataclasses.MISSING


class SettingError(ValueError):
    """An override names no field or carries a value of the wrong type (one-line message)."""


# ------------------------------------------------------------------ field documentation

# units a comment may start with ("m, footprint box", "Hz", "m/s (official ...)", "1/m: ...")
_UNITS = ("m/s^2", "m/s", "m^2", "m", "cm", "mm", "s", "ms", "Hz", "deg", "rad", "px", "pixels", "fps",
          "dB", "%", "kg", "1/m", "bytes", "MiB", "GiB")
_UNIT_RE = re.compile(r"^(" + "|".join(re.escape(u) for u in sorted(_UNITS, key=len, reverse=True))
                      + r")(?:$|[,;:]\s*|\s+(?=\())")
_UNIT_LEAD_RE = re.compile(r"^(m/s|m|s|Hz|deg|px)\s+\w")  # "m above the ground"
# unit suffixes of field names (checked in order: the longest first)
_NAME_UNITS = (("_m2", "m^2"), ("_mps", "m/s"), ("_deg", "deg"), ("_rad", "rad"), ("_px", "px"),
               ("_hz", "Hz"), ("_seconds", "s"), ("_s", "s"), ("_m", "m"), ("_fps", "fps"), ("fps", "fps"))
# a comment line that goes on with the sentence of the line above ("or ...", "... and ...")
_CONTINUATION = re.compile(r"^(\.\.\.|or\b|and\b|but\b|then\b|which\b|so\b|\()")
_SECTION_HEADER = re.compile(r"^-{2,}.*-{2,}$|^={2,}.*={2,}$")


@dataclass(frozen=True)
class FieldDoc:
    """One row of `vid2sim config show`."""

    path: str  # dotted path, as `--set` takes it
    type: str  # the annotation, readable
    default: Any  # the value in the shown config (JSON-able); None when required
    unit: str  # "" when the field has none
    meaning: str  # one line: the comment's first sentence
    comment: str = ""  # the whole comment (its measured reasons, options, ...)
    section: bool = False  # a nested config (its fields follow)
    required: bool = False  # no default: the caller must give it

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


def _source_comments(cls: type) -> dict[str, tuple[str, str]]:
    """Field name -> (comment, further comment) for the fields `cls` itself declares: the trailing
    comment with its continuation (or the comment block above), and the block above a field
    that also has a trailing comment. Empty when the source cannot be read."""
    try:
        src = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    try:
        tree = ast.parse(src)
        tokens = list(tokenize.generate_tokens(io.StringIO(src).readline))
    except (SyntaxError, tokenize.TokenError, IndentationError):
        return {}
    lines = src.splitlines()
    trailing: dict[int, str] = {}  # line -> comment after code on that line
    full: dict[int, str] = {}  # line -> comment alone on its line
    for tok in tokens:
        if tok.type != tokenize.COMMENT:
            continue
        row, col = tok.start
        text = tok.string.lstrip("#").strip()
        (full if not lines[row - 1][:col].strip() else trailing)[row] = text
    body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
    fields: list[tuple[str, int, int, str]] = []  # (name, first line, last line, docstring)
    for i, node in enumerate(body):
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            nxt = body[i + 1] if i + 1 < len(body) else None
            doc = (nxt.value.value if isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant)
                   and isinstance(nxt.value.value, str) else "")
            fields.append((node.target.id, node.lineno, node.end_lineno or node.lineno, doc))
    own = [[trailing[r] for r in range(first, last + 1) if r in trailing] for _, first, last, _ in fields]
    above: list[list[str]] = [[] for _ in fields]
    below: list[list[str]] = [[] for _ in fields]
    for k in range(len(fields) + 1):
        # the comment lines between field k-1 and field k, in groups of consecutive lines
        lo = fields[k - 1][2] + 1 if k else 1
        hi = fields[k][1] - 1 if k < len(fields) else len(lines)
        groups: list[tuple[int, int]] = []
        for r in range(lo, hi + 1):
            if r in full:
                if groups and groups[-1][1] == r - 1:
                    groups[-1] = (groups[-1][0], r)
                else:
                    groups.append((r, r))
        for a, b in groups:
            text = [full[r] for r in range(a, b + 1) if not _SECTION_HEADER.match(full[r])]
            if not text:
                continue
            after_prev, before_next = k > 0 and a == lo and own[k - 1], k < len(fields) and b == hi
            continues = after_prev and (not before_next or (own[k] and _CONTINUATION.match(text[0])))
            if continues:
                below[k - 1] += text  # continues the trailing comment of the field above
            elif before_next:
                above[k] += text  # the block right above a field describes it
    out = {}
    for k, (name, _, _, doc) in enumerate(fields):
        primary = " ".join(" ".join(own[k] + below[k] + ([doc] if doc else []) or above[k]).split())
        extra = " ".join(" ".join(above[k]).split()) if own[k] or doc else ""
        if primary:
            out[name] = (primary, extra)
    return out


@lru_cache(maxsize=None)
def field_comments(cls: type) -> dict[str, tuple[str, str]]:
    """Field name -> (comment, further comment) for every field of dataclass `cls`, bases included."""
    out: dict[str, tuple[str, str]] = {}
    for klass in reversed(cls.__mro__):
        if dataclasses.is_dataclass(klass):
            out.update(_source_comments(klass))
    return out


def class_summary(cls: type) -> str:
    """First line of a class's own docstring ("" for the signature dataclasses generate)."""
    doc = cls.__dict__.get("__doc__") or ""
    if not doc or doc.startswith(f"{cls.__name__}("):
        return ""
    return " ".join(inspect.cleandoc(doc).split("\n\n")[0].split())


_SENTENCE_END = re.compile(r"(?<=[a-z0-9)\]%'\"])\.\s+(?=[A-Z(`])")


def first_sentence(text: str) -> str:
    """The text up to its first full stop that a capitalised sentence follows."""
    return _SENTENCE_END.split(text, maxsplit=1)[0].strip()


def split_unit(name: str, comment: str) -> tuple[str, str]:
    """(unit, meaning) of a field from its comment and name."""
    m = _UNIT_RE.match(comment)
    if m:
        return m.group(1), comment[m.end():].strip()
    m = _UNIT_LEAD_RE.match(comment)
    if m:  # "m above the ground": the unit reads as part of the sentence, keep it there
        return m.group(1), comment
    low = name.lower()
    for suffix, unit in _NAME_UNITS:
        if low.endswith(suffix):
            return unit, comment
    return "", comment


# ------------------------------------------------------------------ types

def type_hints(cls: type) -> dict[str, Any]:
    """Resolved annotations of a dataclass (string annotations evaluated)."""
    try:
        return typing.get_type_hints(cls)
    except Exception:  # an unresolvable forward reference: fall back to the raw annotations
        return {f.name: f.type for f in dataclasses.fields(cls)}


def _optional_inner(tp: Any) -> tuple[bool, list[Any]]:
    """(accepts None, the other members) of a Union / Optional; (False, [tp]) otherwise."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        return type(None) in args, [a for a in args if a is not type(None)]
    return False, [tp]


def dataclass_type(tp: Any) -> Optional[type]:
    """The dataclass a field holds (through Optional), else None."""
    _, inner = _optional_inner(tp)
    if len(inner) == 1 and isinstance(inner[0], type) and dataclasses.is_dataclass(inner[0]):
        return inner[0]
    return None


def type_name(tp: Any) -> str:
    """Readable annotation: int, Optional[float], tuple[int, ...], Literal['a', 'b']."""
    if isinstance(tp, str):
        return tp
    if tp is type(None):
        return "None"
    if tp is Any:
        return "Any"
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        none, inner = _optional_inner(tp)
        body = type_name(inner[0]) if len(inner) == 1 else f"Union[{', '.join(type_name(a) for a in inner)}]"
        return f"Optional[{body}]" if none else body
    if origin is typing.Literal:
        return f"Literal[{', '.join(repr(a) for a in args)}]"
    if origin is not None:
        base = getattr(origin, "__name__", str(origin))
        if not args:
            return base
        return f"{base}[{', '.join('...' if a is Ellipsis else type_name(a) for a in args)}]"
    return getattr(tp, "__name__", str(tp))


# ------------------------------------------------------------------ describe

def _jsonable(value: Any) -> Any:
    from vid2sim.versioning import to_jsonable

    return to_jsonable(value)


def _field_default(f: dataclasses.Field) -> tuple[Any, bool]:
    """(default value, required) of a dataclass field, from its declaration."""
    if f.default is not MISSING:
        return f.default, False
    if f.default_factory is not MISSING:  # type: ignore[misc]
        return f.default_factory(), False  # type: ignore[misc]
    return None, True


def describe(config: Any, prefix: str = "") -> list[FieldDoc]:
    """Every field of `config` (a dataclass instance or class), depth first, nested dataclasses
    followed into (an Optional one that is None: its type's defaults, to show what `--set` can fill)."""
    cls = config if isinstance(config, type) else type(config)
    hints, comments = type_hints(cls), field_comments(cls)
    rows: list[FieldDoc] = []
    for f in dataclasses.fields(cls):
        if isinstance(config, type):
            value, required = _field_default(f)
        else:
            value, required = getattr(config, f.name), False
        tp = hints.get(f.name, f.type)
        comment, extra = comments.get(f.name, ("", ""))
        comment = str(f.metadata.get("help", "")) or comment
        sub = dataclass_type(tp)
        if sub is not None and not comment:
            comment = class_summary(sub)
        unit, text = split_unit(f.name, comment)
        unit = str(f.metadata.get("unit", unit))
        path = prefix + f.name
        full = f"{text} ({extra})" if text and extra else text or extra
        rows.append(FieldDoc(path, type_name(tp), _jsonable(value), unit, first_sentence(text), full,
                             section=sub is not None, required=required))
        if sub is not None:
            inner = value if value is not None else _default_instance(sub)
            rows.extend(describe(inner if inner is not None else sub, path + "."))
    return rows


def _default_instance(cls: type) -> Any:
    try:
        return cls()
    except TypeError:  # required fields: describe the class instead
        return None


def format_rows(rows: Sequence[FieldDoc]) -> str:
    """`path: type = value [unit]  meaning` lines (a section's lines indented under it)."""
    out = []
    for r in rows:
        indent = "  " * r.path.count(".")
        if r.section:  # its fields follow; an unset (None) one lists the defaults a --set starts from
            head = f"{indent}{r.path}: {r.type}" + (" = null" if r.default is None else "")
            out.append(head + (f"  # {r.meaning}" if r.meaning else ""))
            continue
        value = "(required)" if r.required else json.dumps(r.default)
        unit = f" [{r.unit}]" if r.unit else ""
        out.append(f"{indent}{r.path}: {r.type} = {value}{unit}" + (f"  # {r.meaning}" if r.meaning else ""))
    return "\n".join(out)


# ------------------------------------------------------------------ parsing values

_TRUE = {"true", "1", "yes", "on", "y", "t"}
_FALSE = {"false", "0", "no", "off", "n", "f"}


def _fail(path: str, tp: Any, raw: Any, why: str = "") -> SettingError:
    return SettingError(f"{path}: expected {type_name(tp)}, got {raw!r}" + (f" ({why})" if why else ""))


def parse_value(tp: Any, raw: Any, path: str = "value") -> Any:
    """`raw` (a command-line string, or a JSON value inside a list / object) as type `tp`."""
    none_ok, inner = _optional_inner(tp)
    if isinstance(raw, str) and raw.strip().lower() in ("none", "null") and tp is not str:
        if none_ok or tp is Any:
            return None
        raise SettingError(f"{path}: expected {type_name(tp)}, got {raw!r} (the field cannot be None)")
    if raw is None:
        if none_ok or tp is Any:
            return None
        raise _fail(path, tp, raw, "the field cannot be None")
    if len(inner) > 1:  # a real union: the first member that parses
        for member in inner:
            try:
                return parse_value(member, raw, path)
            except SettingError:
                continue
        raise _fail(path, tp, raw)
    tp = inner[0]
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is Any:
        return _json_or_str(raw) if isinstance(raw, str) else raw
    if tp is bool:
        if isinstance(raw, bool):
            return raw
        if isinstance(raw, str) and raw.strip().lower() in _TRUE | _FALSE:
            return raw.strip().lower() in _TRUE
        raise _fail(path, tp, raw, "use true or false")
    if tp is int:
        if isinstance(raw, bool) or isinstance(raw, float) and not raw.is_integer():
            raise _fail(path, tp, raw)
        try:
            return int(raw.strip()) if isinstance(raw, str) else int(raw)
        except (TypeError, ValueError):
            raise _fail(path, tp, raw) from None
    if tp is float:
        if isinstance(raw, bool):
            raise _fail(path, tp, raw)
        try:
            return float(raw.strip()) if isinstance(raw, str) else float(raw)
        except (TypeError, ValueError):
            raise _fail(path, tp, raw) from None
    if tp is str:
        if isinstance(raw, str):
            s = raw.strip()
            if len(s) >= 2 and s[0] == s[-1] == '"':
                try:
                    return json.loads(s)
                except json.JSONDecodeError:
                    pass
            return raw
        raise _fail(path, tp, raw)
    if tp is Path:
        if isinstance(raw, str):
            return Path(raw)
        raise _fail(path, tp, raw)
    if origin is typing.Literal:
        for choice in args:
            try:
                value = parse_value(type(choice), raw, path)
            except SettingError:
                continue
            if value == choice:
                return choice
        raise SettingError(f"{path}: expected one of {', '.join(repr(a) for a in args)}, got {raw!r}")
    if tp in (tuple, list) or origin in (tuple, list, typing.Sequence):
        return _parse_sequence(tp, origin or tp, args, raw, path)
    if tp is dict or origin is dict:
        value = _json_or_str(raw) if isinstance(raw, str) else raw
        if not isinstance(value, dict):
            raise _fail(path, tp, raw, "a JSON object")
        vt = args[1] if len(args) == 2 else Any
        return {k: parse_value(vt, v, f"{path}.{k}") for k, v in value.items()}
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        value = _json_or_str(raw) if isinstance(raw, str) else raw
        if not isinstance(value, dict):
            raise SettingError(f"{path}: is a {tp.__name__} section: set its fields ({path}.FIELD=VALUE) "
                               f"or give a JSON object, got {raw!r}")
        base = _default_instance(tp)
        if base is None:
            raise SettingError(f"{path}: {tp.__name__} has required fields; set them through a JSON object")
        return _apply_items(base, [(k.split("."), v) for k, v in value.items()], path + ".")
    if isinstance(tp, type) and isinstance(raw, tp):
        return raw
    if isinstance(tp, type) and isinstance(raw, str):
        try:
            return tp(raw)
        except Exception as e:
            raise _fail(path, tp, raw, str(e)) from None
    raise _fail(path, tp, raw)


def _json_or_str(raw: str) -> Any:
    try:
        return json.loads(raw)
    except json.JSONDecodeError:
        return raw


def _parse_sequence(tp: Any, origin: Any, args: tuple, raw: Any, path: str) -> Any:
    if isinstance(raw, str):
        s = raw.strip()
        if s.startswith("["):
            try:
                items = json.loads(s)
            except json.JSONDecodeError as e:
                raise _fail(path, tp, raw, f"bad JSON: {e.msg}") from None
        else:
            items = [] if not s else [p.strip() for p in s.split(",")]
    elif isinstance(raw, (list, tuple)):
        items = list(raw)
    else:
        raise _fail(path, tp, raw, "comma-separated or a JSON list")
    if not isinstance(items, list):
        raise _fail(path, tp, raw, "comma-separated or a JSON list")
    if origin is tuple and args and not (len(args) == 2 and args[1] is Ellipsis):
        if len(items) != len(args):
            raise SettingError(f"{path}: expected {len(args)} values ({type_name(tp)}), got {len(items)} in {raw!r}")
        values = [parse_value(a, v, f"{path}[{i}]") for i, (a, v) in enumerate(zip(args, items))]
    else:
        et = args[0] if args else Any
        values = [parse_value(et, v, f"{path}[{i}]") for i, v in enumerate(items)]
    return tuple(values) if origin is tuple else values


# ------------------------------------------------------------------ overrides

def parse_set(item: str) -> tuple[str, str]:
    """'a.b=value' -> ('a.b', 'value'); SettingError when there is no '=' or no name."""
    if "=" not in item:
        raise SettingError(f"--set {item!r}: expected FIELD=VALUE (e.g. recon.iterations=500)")
    path, raw = item.split("=", 1)
    path = path.strip()
    if not path or any(not p.isidentifier() for p in path.split(".")):
        raise SettingError(f"--set {item!r}: {path!r} is not a dotted field name")
    return path, raw


def _unknown(cls: type, name: str, where: str) -> SettingError:
    names = [f.name for f in dataclasses.fields(cls)]
    close = difflib.get_close_matches(name, names, n=1)
    hint = f"; did you mean {close[0]}?" if close else f"; fields: {', '.join(names)}"
    return SettingError(f"{where}{name}: unknown field of {cls.__name__}{hint}")


def _apply_items(obj: Any, items: list[tuple[list[str], Any]], prefix: str = "") -> Any:
    """A copy of dataclass `obj` with each (path parts, raw value) applied in order."""
    for parts, raw in items:
        obj = _apply_one(obj, parts, raw, prefix)
    return obj


def _apply_one(obj: Any, parts: list[str], raw: Any, prefix: str) -> Any:
    cls = type(obj)
    name, rest = parts[0], parts[1:]
    known = {f.name: f for f in dataclasses.fields(cls)}
    if name not in known:
        raise _unknown(cls, name, prefix)
    path = prefix + name
    tp = type_hints(cls).get(name, known[name].type)
    current = getattr(obj, name)
    if rest:
        sub = dataclass_type(tp)
        if sub is not None:
            if current is None:
                current = _default_instance(sub)
                if current is None:
                    raise SettingError(f"{path}: is None and {sub.__name__} has required fields; "
                                       f"set it as a JSON object")
            value = _apply_one(current, rest, raw, path + ".")
        elif isinstance(current, dict) or typing.get_origin(_optional_inner(tp)[1][0]) is dict:
            vt = typing.get_args(_optional_inner(tp)[1][0])
            value = dict(current or {})
            key = ".".join(rest)
            value[key] = parse_value(vt[1] if len(vt) == 2 else Any, raw, f"{path}.{key}")
        else:
            raise SettingError(f"{path}.{'.'.join(rest)}: {path} is not a section (it holds {type_name(tp)})")
    elif dataclass_type(tp) is not None and isinstance(raw, str) and raw.strip().startswith("{"):
        # a JSON object of a section's fields: applied over its current value
        fields_ = _json_or_str(raw)
        if not isinstance(fields_, dict):
            raise SettingError(f"{path}: bad JSON object {raw!r}")
        sub = dataclass_type(tp)
        base = current if current is not None else _default_instance(sub)  # type: ignore[arg-type]
        if base is None:
            raise SettingError(f"{path}: {sub.__name__} has required fields")  # type: ignore[union-attr]
        value = base
        for key, item in fields_.items():
            value = _apply_one(value, str(key).split("."), item if isinstance(item, str) else json.dumps(item),
                               path + ".")
    else:
        value = check_value(path, parse_value(_with_item_type(tp, current), raw, path))
    try:
        return dataclasses.replace(obj, **{name: value})
    except (ValueError, TypeError) as e:  # the config's own validation (__post_init__)
        raise SettingError(f"{path}: {e}") from None


def _with_item_type(tp: Any, current: Any) -> Any:
    """A bare `tuple` / `list` annotation made precise by the current value: a tuple keeps its
    length and item type (`background: tuple = (0.0, 0.0, 0.0)` parses as tuple[float, float,
    float]), a list its item type."""
    if tp in (tuple, list) and current and isinstance(current, (tuple, list)):
        kinds = {type(v) for v in current}
        if len(kinds) == 1 and kinds <= {int, float, str, bool}:
            kind = kinds.pop()
            return typing.Tuple[(kind,) * len(current)] if tp is tuple else list[kind]  # type: ignore[misc]
    return tp


def apply_overrides(config: Any, sets: Optional[Sequence[str]]) -> Any:
    """A copy of dataclass `config` with every 'dotted.field=value' of `sets` applied, in order.

    Raises SettingError (one line, naming the field and the reason) on an unknown field or a value
    that does not parse as the field's type, RangeError on a numeric field out of its range (any
    field, set or not). The input is not modified."""
    return _apply_sets(config, sets)


def _apply_sets(config: Any, sets: Optional[Sequence[str]], prefix: str = "") -> Any:
    """`apply_overrides` for a config that sits at `prefix` (its paths given without it); the result's
    numeric fields are range-checked (`vid2sim.ranges`)."""
    for item in sets or ():
        path, raw = parse_set(item)
        try:
            config = _apply_one(config, path.split("."), raw, prefix)
        except (SettingError, RangeError) as e:
            raise type(e)(f"--set {prefix}{item}: {e}") from None
    return check_ranges(config, prefix)


def apply_or_exit(config: Any, sets: Optional[Sequence[str]], apply: Any = None) -> Any:
    """`apply(config, sets)` (default `apply_overrides`) for a command: a bad override raises
    SettingError, which the CLI reports by its error convention (one line, exit 2)."""
    return (apply or apply_overrides)(config, sets)


# ------------------------------------------------------------------ the command line's configs

SECTIONS = ("ingest", "env", "train", "eval")
PRESETS = ("fast", "paper")
EVAL_ENV = "env"  # `--set env.X=...` on `vid2sim eval policy` reaches the evaluation env config


def ingest_config(preset: str = "fast") -> Any:
    """The factory pipeline config of a preset (what `vid2sim ingest --preset` runs)."""
    from vid2sim.factory.runtime.pipeline import preset as make_preset

    if preset not in PRESETS:
        raise SettingError(f"--preset: unknown preset {preset!r} (fast | paper)")
    return make_preset(preset)


def section_config(section: str, preset: Optional[str] = None) -> Any:
    """The config (instance, or class when it has required fields) a section's `config show` lists."""
    if preset is not None and section != "ingest":
        raise SettingError(f"--preset: presets are pipeline presets (ingest only), not {section}")
    if section == "ingest":
        return ingest_config(preset or "fast")
    if section == "env":
        from vid2sim.envs.config import EnvConfig

        return EnvConfig()
    if section == "train":
        from vid2sim.training.config import TrainConfig

        return TrainConfig
    if section == "eval":
        from vid2sim.training.evaluate import EvalConfig

        return EvalConfig
    raise SettingError(f"unknown config section {section!r} ({' | '.join(SECTIONS)})")


def describe_section(section: str, preset: Optional[str] = None, sets: Optional[Sequence[str]] = None
                     ) -> list[FieldDoc]:
    """`config show` rows of a section after `sets`; the eval section adds its env config under `env.`.
    Fields without a default (TrainConfig.run_dir, ...) are listed as required unless `sets` gives them."""
    conf = section_config(section, preset)
    required: list[str] = []
    if isinstance(conf, type):
        required = _required(conf)
        conf = _placeholder(conf)
    if isinstance(conf, type):
        if sets:
            raise SettingError(f"--set: {conf.__name__} cannot be built without {', '.join(required)}")
        return describe(conf)
    if section == "eval":
        conf = apply_eval_overrides(conf, sets)
        rows = describe(conf) + _eval_env_rows(conf)
    else:
        rows = describe(apply_overrides(conf, sets))
    given = {parse_set(item)[0] for item in sets or ()}
    return [dataclasses.replace(r, default=None, required=True) if r.path in required and r.path not in given else r
            for r in rows]


def _required(cls: type) -> list[str]:
    return [f.name for f in dataclasses.fields(cls)
            if f.default is MISSING and f.default_factory is MISSING]  # type: ignore[misc]


def _placeholder(cls: type) -> Any:
    """An instance of `cls` whose required fields hold a stand-in ("", 1, ...); the class itself when
    its own checks refuse those."""
    hints = type_hints(cls)
    stand_in = {str: "", int: 1, float: 1.0, bool: False}
    values = {}
    for name in _required(cls):
        _, inner = _optional_inner(hints.get(name))
        values[name] = stand_in.get(inner[0]) if len(inner) == 1 else None
    try:
        return cls(**values)
    except (TypeError, ValueError):
        return cls


def _eval_env_rows(config: Any) -> list[FieldDoc]:
    """The env config `vid2sim eval policy` evaluates with (its env_kwargs applied), under `env.`."""
    from vid2sim.training.evaluate import eval_env_config

    _, env = eval_env_config(config)
    names = {f.name for f in dataclasses.fields(env)}
    env = dataclasses.replace(env, **{k: v for k, v in config.env_kwargs.items() if k in names})
    head = FieldDoc(EVAL_ENV, type_name(type(env)), _jsonable(env), "",
                    "the env config evaluation runs with: from the fields above, then env.FIELD overrides",
                    section=True)
    return [head] + describe(env, EVAL_ENV + ".")


def split_eval_sets(sets: Optional[Sequence[str]]) -> tuple[list[str], list[str]]:
    """(EvalConfig overrides, env config overrides with the `env.` prefix removed)."""
    own, env = [], []
    for item in sets or ():
        path, raw = parse_set(item)
        if path.split(".")[0] == EVAL_ENV:
            if "." not in path:
                raise SettingError(f"--set {item}: env is a section: set its fields (env.FIELD=VALUE)")
            env.append(f"{path.split('.', 1)[1]}={raw}")
        else:
            own.append(item)
    return own, env


def apply_eval_overrides(config: Any, sets: Optional[Sequence[str]]) -> Any:
    """An `EvalConfig` with `sets` applied: its own fields directly, `env.`-prefixed paths to the
    evaluation env config (carried to the env as `env_kwargs`, which `NavEnv` applies over it)."""
    from vid2sim.training.evaluate import eval_env_config

    own, env_sets = split_eval_sets(sets)
    config = apply_overrides(config, own)
    if not sets:
        return config
    try:
        _, base = eval_env_config(config)
    except ValueError as e:
        raise SettingError(f"--set: {e}") from None
    if not env_sets:
        return config
    changed = _apply_sets(base, env_sets, EVAL_ENV + ".")
    diff = {f.name: getattr(changed, f.name) for f in dataclasses.fields(base)
            if getattr(changed, f.name) != getattr(base, f.name)}
    return dataclasses.replace(config, env_kwargs={**config.env_kwargs, **diff})
