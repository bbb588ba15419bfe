"""splats.ply is checked from its header before any body byte is read: the splat count against
MAX_SPLATS (`BundleTooLarge`), the file size against count x row size (truncated or padded bodies),
and the format, elements and properties against the 3DGS layout (`BundleError`, named)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from plyfile import PlyData
from registry_fixtures import make_bundle
from typer.testing import CliRunner

from vid2sim.cli.app import app
from vid2sim.formats.errors import BundleError, BundleTooLarge
from vid2sim.formats.splat_ply import MAX_SPLATS, check_splats, read_splat_header
from vid2sim.splats import GaussianModel, read_ply, write_ply
from vid2sim.viewer.splats import read_splat_layer

N = 7
READERS = (read_splat_header, check_splats, read_ply, read_splat_layer)  # every reader of a bundle's splats.ply


def valid_ply(path: Path, degree: int = 1) -> Path:
    g = torch.Generator().manual_seed(0)
    model = GaussianModel(torch.randn(N, 3, generator=g), torch.randn(N, 4, generator=g) + 2,
                          torch.randn(N, 3, generator=g), torch.randn(N, generator=g),
                          torch.randn(N, (degree + 1) ** 2, 3, generator=g))
    return write_ply(model, path)


def split(path: Path) -> tuple[str, bytes]:
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    return data[:end].decode("ascii"), data[end:]


def rewrite(path: Path, old: str, new: str, body: bytes | None = None) -> Path:
    """`path` with `old` replaced by `new` in its header (and its body replaced when given)."""
    header, rest = split(path)
    assert old in header
    path.write_bytes(header.replace(old, new).encode("ascii") + (rest if body is None else body))
    return path


@pytest.fixture
def no_body_reads(monkeypatch):
    """Any body read (plyfile) fails the test: the header checks must decide first."""
    def refuse(*args, **kwargs):
        raise AssertionError("the PLY body was read")
    monkeypatch.setattr(PlyData, "read", refuse)


def test_valid_file_passes_the_header_check(tmp_path):
    path = valid_ply(tmp_path / "splats.ply")
    header = read_splat_header(path)
    assert header.format == "binary_little_endian" and header.count == N
    assert header.row_bytes == 4 * 26 and header.header_bytes + header.body_bytes == path.stat().st_size
    assert check_splats(path)[0] == N and read_ply(path).num == N and read_splat_layer(path).total == N


def test_ascii_file_reads(tmp_path):
    path = valid_ply(tmp_path / "splats.ply")
    PlyData([PlyData.read(str(path))["vertex"]], text=True).write(str(tmp_path / "a.ply"))
    assert read_splat_header(tmp_path / "a.ply").format == "ascii" and read_ply(tmp_path / "a.ply").num == N


def test_count_over_the_cap_is_refused_before_the_body(tmp_path, no_body_reads):
    path = rewrite(valid_ply(tmp_path / "splats.ply"), f"element vertex {N}", f"element vertex {MAX_SPLATS + 1}")
    for read in READERS:
        with pytest.raises(BundleTooLarge, match=r"splats.ply: declares 20,000,001 splats, over the cap of 20,000,000"):
            read(path)


def test_count_over_the_cap_in_a_bundle_stores_nothing(tmp_path):
    bundle = make_bundle(tmp_path / "b", "many-splats", n_splats=20)
    rewrite(bundle / "splats.ply", "element vertex 20", f"element vertex {10 * MAX_SPLATS}")
    r = CliRunner().invoke(app, ["registry", "add", str(bundle), "-r", str(tmp_path / "reg")])
    assert r.exit_code == 2 and "over the cap of 20,000,000" in r.stderr and "Traceback" not in r.output
    assert not (tmp_path / "reg").exists()


@pytest.mark.parametrize("cut,kind", [(-10, "truncated"), (-104, "truncated"), (3, "padded"), (104, "padded")])
def test_body_size_must_match_the_header(tmp_path, no_body_reads, cut, kind):
    path = valid_ply(tmp_path / "splats.ply")
    data = path.read_bytes()
    path.write_bytes(data[:cut] if cut < 0 else data + b"\0" * cut)
    for read in READERS:
        with pytest.raises(BundleError, match=rf"splats.ply: {kind} PLY body: .* bytes after the header, the header "
                                              rf"declares 728 \(7 splats x 104 bytes\)"):
            read(path)


HEADER_EDITS = {
    "not a PLY": (None, "it does not start with a 'ply' line"),
    "no end_header": ("end_header\n", "no 'end_header' line within"),
    "unknown format": ("format binary_little_endian 1.0", "unknown PLY format 'binary_middle_endian 1.0'"),
    "PLY version 2": ("format binary_little_endian 1.0", "unknown PLY format"),
    "no format line": ("format binary_little_endian 1.0\n", "is not a format, element or property line"),
    "unknown type": ("property float x\n", "'property half x': not a property of a known type"),
    "double property": ("property float x\n", r"must be float32: x \(double\)"),
    "unknown property": ("property float nx\n", "outside the 3DGS layout: confidence"),
    "repeated property": ("property float nx\n", "repeats properties: y"),
    "list property": ("property float nx\n", "outside the 3DGS layout: ids"),
    "negative count": (f"element vertex {N}", "expected 'element NAME COUNT'"),
    "second element": ("end_header\n", "elements besides 'vertex': face"),
    "no vertex element": (f"element vertex {N}", "no 'vertex' element"),
    "missing property": ("property float scale_1\n", "lacks 3DGS properties: scale_1"),
    "bad SH count": ("property float f_rest_8\n", "f_rest_.* got 8"),
    "garbage line": ("property float z\n", "'zzz' is not a format, element or property line"),
    "non-ASCII header": ("ply\n", "not ASCII text"),
}
REPLACEMENTS = {
    "no end_header": "", "unknown format": "format binary_middle_endian 1.0", "PLY version 2":
    "format binary_little_endian 2.0", "no format line": "", "unknown type": "property half x\n",
    "double property": "property double x\n", "unknown property": "property float nx\nproperty float confidence\n",
    "repeated property": "property float nx\nproperty float y\n",
    "list property": "property float nx\nproperty list uchar int ids\n", "negative count": "element vertex -7",
    "second element": "element face 0\nproperty list uchar int vertex_indices\nend_header\n",
    "no vertex element": f"element splat {N}", "missing property": "", "bad SH count": "",
    "garbage line": "property float z\nzzz\n",
}


@pytest.mark.parametrize("case", list(HEADER_EDITS))
def test_bad_header_is_named(tmp_path, no_body_reads, case):
    path = valid_ply(tmp_path / "splats.ply")
    old, reason = HEADER_EDITS[case]
    if old is None:
        path.write_bytes(b"hello, not a ply\n" + path.read_bytes())
    elif case == "non-ASCII header":
        header, body = split(path)
        path.write_bytes(header.replace(old, "ply\ncomment caf\u00e9\n", 1).encode("utf-8") + body)
    else:
        rewrite(path, old, REPLACEMENTS[case])
    for read in READERS:
        with pytest.raises(BundleError, match=rf"splats.ply: .*{reason}") as err:
            read(path)
        assert not isinstance(err.value, BundleTooLarge)
