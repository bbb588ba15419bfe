"""3DGS PLY: the property list of `splats.ply` (binary little-endian, one `vertex` element).

Properties, all float32: x y z [nx ny nz] f_dc_0..2 f_rest_0..(3*(K-1)-1) opacity scale_0..2
rot_0..3. f_rest is channel-major (the K-1 higher-band coefficients of R, then G, then B);
opacity is the logit, scale_* the log-scales, rot_* the (w, x, y, z) quaternion. Normals are
written (zeros) but optional on read. `read_splat_header` checks a PLY from its header alone,
before any body byte is read: the layout above (no other property or element), at most MAX_SPLATS
splats (`BundleTooLarge`), and for the binary formats a file of exactly header + count x row size
bytes (a truncated or padded body is a `BundleError`). `check_splats` then reads the body and
checks the values.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from plyfile import PlyData

from vid2sim.formats.errors import BundleError, BundleTooLarge

SPLATS_PLY = "splats.ply"
NORMAL_PROPERTIES = ("nx", "ny", "nz")
REQUIRED_PROPERTIES = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
                       "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")
MAX_SPLATS = 20_000_000  # Gaussians a splats.ply may declare (at SH degree 3: 248 bytes each, 4.96 GB)
MAX_PLY_HEADER_BYTES = 65_536  # the header (up to and including `end_header`) must end within these
PLY_FORMATS = ("binary_little_endian", "binary_big_endian", "ascii")
PLY_TYPES = ("char", "uchar", "short", "ushort", "int", "uint", "float", "double",
             "int8", "uint8", "int16", "uint16", "int32", "uint32", "float32", "float64")
FLOAT32_TYPES = ("float", "float32")
SH_REST_COUNTS = (0, 9, 24, 45)  # f_rest_* properties at SH degree 0, 1, 2, 3


@dataclass(frozen=True)
class PlyElementHeader:
    """One `element` of a PLY header: its name, declared count and (property name, type) pairs
    (a list property's type reads `list COUNT_TYPE ITEM_TYPE`)."""

    name: str
    count: int
    properties: tuple[tuple[str, str], ...]


@dataclass(frozen=True)
class SplatHeader:
    """The checked header of a 3DGS PLY: format, splat count, property names, header length."""

    format: str
    count: int
    properties: tuple[str, ...]
    header_bytes: int

    @property
    def row_bytes(self) -> int:
        return 4 * len(self.properties)

    @property
    def body_bytes(self) -> int:
        return self.count * self.row_bytes


def _header_text(path: Path) -> tuple[list[str], int]:
    """The header's lines and its length in bytes (through the `end_header` line); BundleError when
    the file is not a PLY or its header does not end within MAX_PLY_HEADER_BYTES."""
    with open(path, "rb") as f:
        head = f.read(MAX_PLY_HEADER_BYTES)
    if not head.startswith((b"ply\n", b"ply\r\n")):
        raise BundleError(path, "not a PLY file (it does not start with a 'ply' line)")
    end = re.search(rb"(?:^|\n)end_header\r?\n", head)
    if end is None:
        raise BundleError(path, f"PLY header has no 'end_header' line within its first {MAX_PLY_HEADER_BYTES:,} bytes")
    try:
        text = head[:end.end()].decode("ascii")
    except UnicodeDecodeError:
        raise BundleError(path, "PLY header is not ASCII text") from None
    return text.splitlines()[1:-1], end.end()


def _property(path: Path, words: list[str]) -> tuple[str, str]:
    """(name, type) of a `property` line's words; BundleError for an unknown type or a bad line."""
    types = words[2:4] if len(words) == 5 and words[1] == "list" else words[1:2]
    if len(words) != (5 if words[1:2] == ["list"] else 3) or any(t not in PLY_TYPES for t in types):
        raise BundleError(path, f"PLY header line {' '.join(words)!r}: not a property of a known type "
                          f"({', '.join(PLY_TYPES)})")
    return words[-1], " ".join(words[1:-1])


def _element(path: Path, words: list[str]) -> PlyElementHeader:
    if len(words) != 3 or not words[2].isdigit():
        raise BundleError(path, f"PLY header line {' '.join(words)!r}: expected 'element NAME COUNT'")
    return PlyElementHeader(words[1], int(words[2]), ())


def parse_ply_header(path: Path) -> tuple[str, list[PlyElementHeader], int]:
    """(format, elements, header length in bytes) of any PLY, read from its header alone."""
    lines, length = _header_text(path)
    fmt, elements = "", []
    for line in lines:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and not fmt and not elements:
            if len(words) != 3 or words[1] not in PLY_FORMATS or words[2] != "1.0":
                raise BundleError(path, f"unknown PLY format {' '.join(words[1:])!r} "
                                  f"(known: {', '.join(PLY_FORMATS)}, version 1.0)")
            fmt = words[1]
        elif words[0] == "element" and fmt:
            elements.append(_element(path, words))
        elif words[0] == "property" and elements and len(words) >= 3:
            last = elements[-1]
            elements[-1] = PlyElementHeader(last.name, last.count, (*last.properties, _property(path, words)))
        else:
            raise BundleError(path, f"PLY header line {line.strip()!r} is not a format, element or property line")
    if not fmt:
        raise BundleError(path, "PLY header has no 'format' line")
    return fmt, elements, length


def read_splat_header(path: Path) -> SplatHeader:
    """The header of a 3DGS PLY, checked before any body byte is read: one `vertex` element of known
    float32 properties (the 3DGS set), at most MAX_SPLATS splats (`BundleTooLarge`), and for binary
    formats a body of exactly count x row size bytes (a truncated or padded file is a BundleError)."""
    fmt, elements, length = parse_ply_header(path)
    vertex = next((e for e in elements if e.name == "vertex"), None)
    if vertex is None:
        raise BundleError(path, "PLY has no 'vertex' element")
    header = SplatHeader(fmt, vertex.count, tuple(name for name, _ in vertex.properties), length)
    _check_layout(path, vertex, elements)
    if vertex.count > MAX_SPLATS:
        raise BundleTooLarge(path, f"declares {vertex.count:,} splats, over the cap of {MAX_SPLATS:,}")
    if fmt != "ascii":
        _check_body_size(path, header)
    return header


def _check_layout(path: Path, vertex: PlyElementHeader, elements: list[PlyElementHeader]) -> None:
    """The 3DGS properties present, named and typed as the contract says, in the only element."""
    names = [name for name, _ in vertex.properties]
    missing = [p for p in REQUIRED_PROPERTIES if p not in names]
    if missing:
        raise BundleError(path, f"PLY lacks 3DGS properties: {', '.join(missing)}")
    rest = sorted(int(n[7:]) for n in names if n.startswith("f_rest_") and n[7:].isdigit())
    if rest != list(range(len(rest))) or len(rest) not in SH_REST_COUNTS:
        raise BundleError(path, f"f_rest_* properties must be f_rest_0..f_rest_{{n-1}} with n in "
                          f"{', '.join(map(str, SH_REST_COUNTS))} (SH degree 0..3), got {len(rest)}")
    known = {*REQUIRED_PROPERTIES, *NORMAL_PROPERTIES, *(f"f_rest_{i}" for i in rest)}
    unknown = [n for n in names if n not in known]
    if unknown:
        raise BundleError(path, f"PLY vertex has properties outside the 3DGS layout: {', '.join(unknown)}")
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise BundleError(path, f"PLY vertex repeats properties: {', '.join(repeated)}")
    typed = [f"{n} ({t})" for n, t in vertex.properties if t not in FLOAT32_TYPES]
    if typed:
        raise BundleError(path, f"PLY properties must be float32: {', '.join(typed)}")
    others = [e.name for e in elements if e is not vertex]
    if others:
        raise BundleError(path, f"PLY has elements besides 'vertex': {', '.join(others)}")


def _check_body_size(path: Path, header: SplatHeader) -> None:
    """A binary body of exactly count x row bytes; BundleError naming a truncated or padded file."""
    body = path.stat().st_size - header.header_bytes
    if body != header.body_bytes:
        kind = "truncated" if body < header.body_bytes else "padded"
        raise BundleError(path, f"{kind} PLY body: {body:,} bytes after the header, the header declares "
                          f"{header.body_bytes:,} ({header.count:,} splats x {header.row_bytes} bytes)")


def property_names(n_sh_coeffs: int) -> list[str]:
    """Written property order for K = n_sh_coeffs SH coefficients per channel (normals included)."""
    rest = [f"f_rest_{i}" for i in range(3 * (n_sh_coeffs - 1))]
    return ["x", "y", "z", *NORMAL_PROPERTIES, "f_dc_0", "f_dc_1", "f_dc_2", *rest,
            "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]


def check_splats(path: Path) -> tuple[int, tuple[float, ...]]:
    """3DGS PLY -> (count, bounds [6]); BundleError when the layout is not 3DGS (BundleTooLarge over
    the cap), both checked from the header before the body is read."""
    if not path.is_file():
        raise BundleError(path, "missing splats file")
    header = read_splat_header(path)
    if header.count == 0:
        raise BundleError(path, "PLY holds no Gaussians")
    try:
        vertex = PlyData.read(str(path))["vertex"]
    except Exception as e:  # plyfile raises several types on malformed input
        raise BundleError(path, f"unreadable PLY ({type(e).__name__}: {e})") from None
    _check_values(path, vertex, list(header.properties))
    xyz = np.stack([np.asarray(vertex[c], np.float64) for c in ("x", "y", "z")], 1)  # [N, 3]
    return header.count, tuple(float(v) for v in (*xyz.min(0), *xyz.max(0)))


def _check_values(path: Path, vertex, names: list[str]) -> None:
    """Every Gaussian parameter finite and every rotation quaternion non-zero."""
    groups = {"positions": ("x", "y", "z"), "opacities": ("opacity",), "scales": ("scale_0", "scale_1", "scale_2"),
              "rotations": ("rot_0", "rot_1", "rot_2", "rot_3"),
              "colours": tuple(n for n in names if n.startswith(("f_dc_", "f_rest_")))}
    for label, cols in groups.items():
        for c in cols:
            bad = int(np.count_nonzero(~np.isfinite(np.asarray(vertex[c], np.float64))))
            if bad:
                raise BundleError(path, f"non-finite splat {label}: {bad} NaN/inf value(s) in '{c}'")
    quat = np.stack([np.asarray(vertex[c], np.float64) for c in groups["rotations"]], 1)
    zero = int(np.count_nonzero(np.abs(quat).sum(1) == 0))
    if zero:
        raise BundleError(path, f"{zero} splat(s) with a zero rotation quaternion (rot_0..rot_3 all 0)")
