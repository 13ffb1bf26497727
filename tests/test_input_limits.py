"""Bounded inputs (issue 14): size limits checked while reading, truncated and corrupt files,
far-out coordinates, node-position files. Every refusal is one InputError line naming the file."""

from __future__ import annotations

import gzip
import io
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from deformgl import inputs
from deformgl.errors import InputError
from deformgl.files import read_png
from deformgl.grid.meshio import load_mesh
from deformgl.inputs import read_bounded, read_image
from deformgl.mapping.node_drivers import load_node_frames

HEADER = (b"ply\nformat binary_little_endian 1.0\nelement vertex 100000000\nproperty float x\n"
          b"property float y\nproperty float z\nend_header\n")


def one_line(call, *args) -> str:
    """The message of the InputError ``call(*args)`` raises, checked to be one line."""
    with pytest.raises(InputError) as info:
        call(*args)
    assert type(info.value) is InputError
    message = str(info.value)
    assert "\n" not in message and "Traceback" not in message
    return message


# --- decompressed size -----------------------------------------------------------------------

def gzip_bomb(path: Path, inflated: int) -> Path:
    """A .ply.gz of a PLY header and ``inflated`` zero bytes, written in 16 MiB pieces."""
    zeros = bytes(16 << 20)
    with gzip.open(path, "wb", compresslevel=9) as out:
        out.write(HEADER)
        for _ in range(inflated // len(zeros)):
            out.write(zeros)
    return path


def test_gzip_bomb_is_refused_while_inflating(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    bomb = gzip_bomb(tmp_path / "bomb.ply.gz", 512 << 20)  # 512 MiB inflated, ~0.5 MB on disk
    assert bomb.stat().st_size < 2 << 20
    monkeypatch.setenv("DEFORMGL_MAX_MESH_BYTES", str(8 << 20))
    read: list[int] = []
    real_read = gzip.GzipFile.read

    def counting_read(self, size=-1):
        chunk = real_read(self, size)
        read.append(len(chunk))
        return chunk

    monkeypatch.setattr(gzip.GzipFile, "read", counting_read)
    start = time.perf_counter()
    message = one_line(load_mesh, bomb)
    assert time.perf_counter() - start < 2.0
    assert sum(read) <= (8 << 20) + (1 << 20)  # stopped one chunk past the cap, not at 512 MiB
    assert message == (f"{bomb}: decompresses to more than 8,388,608 bytes, the limit "
                       f"(set DEFORMGL_MAX_MESH_BYTES to raise it)")


def test_plain_file_over_the_limit_is_refused_from_its_size(tmp_path: Path,
                                                            monkeypatch: pytest.MonkeyPatch):
    box = tmp_path / "box.ply"
    trimesh.creation.box().export(box)
    monkeypatch.setenv("DEFORMGL_MAX_MESH_BYTES", "100")
    assert one_line(load_mesh, box) == (f"{box}: file holds more than 100 bytes, the limit "
                                        f"(set DEFORMGL_MAX_MESH_BYTES to raise it)")
    monkeypatch.setenv("DEFORMGL_MAX_MESH_BYTES", "1_000_000")
    assert len(load_mesh(box).faces) == 12


def test_within_the_limit_a_gzip_reads_whole(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    path = tmp_path / "d.bin.gz"
    payload = bytes(range(256)) * 10000
    path.write_bytes(gzip.compress(payload))
    monkeypatch.setenv("DEFORMGL_MAX_MESH_BYTES", str(len(payload)))
    assert read_bounded(path, "d.bin.gz", compressed=True) == payload


@pytest.mark.parametrize("value", ["abc", "-5", "0", "1.5"])
def test_bad_limit_setting_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, value: str):
    monkeypatch.setenv("DEFORMGL_MAX_MESH_BYTES", value)
    message = one_line(inputs.max_mesh_bytes)
    assert message == (f"environment variable DEFORMGL_MAX_MESH_BYTES: must be a positive integer, "
                       f"got {value!r}")


def test_defaults_are_the_documented_ones(monkeypatch: pytest.MonkeyPatch):
    for name in ("DEFORMGL_MAX_MESH_BYTES", "DEFORMGL_MAX_IMAGE_PIXELS", "DEFORMGL_MAX_COORDINATE"):
        monkeypatch.delenv(name, raising=False)
    assert inputs.max_mesh_bytes() == 2 * 1024**3
    assert inputs.max_image_pixels() == 8192 * 8192
    assert inputs.max_coordinate() == 1e15
    doc = (Path(__file__).resolve().parents[1] / "docs" / "INPUTS.md").read_text()
    for text in ("DEFORMGL_MAX_MESH_BYTES", "2 GiB", "DEFORMGL_MAX_IMAGE_PIXELS", "67,108,864",
                 "DEFORMGL_MAX_COORDINATE", "1e15"):
        assert text in doc


# --- image pixels ----------------------------------------------------------------------------

def test_oversized_png_is_refused_from_its_header(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    path = tmp_path / "huge.png"
    Image.new("1", (3000, 2000)).save(path)  # a 1-bit image: tiny to make, 6 Mpx
    monkeypatch.setenv("DEFORMGL_MAX_IMAGE_PIXELS", "1000000")
    loads: list[int] = []
    monkeypatch.setattr(Image.Image, "load", lambda self: loads.append(1))
    expected = (f"{path}: image is 3,000 x 2,000 = 6,000,000 pixels, over the limit of 1,000,000 "
                f"pixels (set DEFORMGL_MAX_IMAGE_PIXELS to raise it)")
    assert one_line(read_png, path) == expected
    assert one_line(read_image, path) == expected
    assert not loads  # refused before decoding


def test_default_image_limit_is_8k(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.delenv("DEFORMGL_MAX_IMAGE_PIXELS", raising=False)
    path = tmp_path / "big.png"
    Image.new("1", (8192, 8193)).save(path)
    assert "over the limit of 67,108,864 pixels" in one_line(read_png, path)
    assert "over the limit of 67,108,864 pixels" in one_line(read_image, path)


def test_pillow_decompression_bomb_error_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    path = tmp_path / "bomb.png"
    Image.new("1", (400, 300)).save(path)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 1000)  # Pillow's guard: error over 2000
    monkeypatch.setenv("DEFORMGL_MAX_IMAGE_PIXELS", "10000000")
    message = one_line(read_png, path)
    assert message.startswith(f"{path}: image too large for Pillow's decompression-bomb guard (")


def test_pillow_warning_band_is_silent_when_within_the_limit(tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch):
    import warnings

    path = tmp_path / "ok.png"
    Image.new("RGB", (40, 30)).save(path)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 1000)  # 1200 px: Pillow would warn
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_png(path).shape == (30, 40, 3)


def test_corrupt_and_missing_images(tmp_path: Path):
    good = io.BytesIO()
    Image.new("RGB", (64, 64), (200, 10, 10)).save(good, format="PNG")
    cut = tmp_path / "cut.png"
    cut.write_bytes(good.getvalue()[:60])
    assert one_line(read_image, cut).startswith(f"{cut}: ")
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not an image at all")
    assert one_line(read_image, junk).startswith(f"{junk}: cannot read image: cannot identify")
    missing = tmp_path / "missing.png"
    assert one_line(read_image, missing) == f"{missing}: cannot read image: No such file or directory"


# --- truncated meshes ------------------------------------------------------------------------

@pytest.fixture
def sphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=2)  # 162 vertices, 320 faces


@pytest.mark.parametrize("encoding", ["ascii", "binary"])
def test_truncated_ply_names_element_and_counts(tmp_path: Path, sphere: trimesh.Trimesh, encoding: str):
    data = sphere.export(file_type="ply", encoding=encoding)
    body = data.index(b"end_header\n") + len(b"end_header\n")
    if encoding == "ascii":
        lines = data[body:].split(b"\n")
        cut = data[:body] + b"\n".join(lines[: 162 + 100]) + b"\n"  # 100 of the 320 faces
    else:
        cut = data[: body + 162 * 12 + 100 * 13]
    for name, blob in ((f"s_{encoding}.ply", cut), (f"s_{encoding}.ply.gz", gzip.compress(cut))):
        path = tmp_path / name
        path.write_bytes(blob)
        assert one_line(load_mesh, path) == f"{path}: truncated: header declares 320 faces, file holds 100"


def test_truncated_ply_in_the_vertices(tmp_path: Path, sphere: trimesh.Trimesh):
    data = sphere.export(file_type="ply", encoding="binary")
    body = data.index(b"end_header\n") + len(b"end_header\n")
    path = tmp_path / "v.ply"
    path.write_bytes(data[: body + 50 * 12 + 5])
    assert one_line(load_mesh, path) == f"{path}: truncated: header declares 162 vertices, file holds 50"


def test_truncated_off_and_binary_stl(tmp_path: Path, sphere: trimesh.Trimesh):
    off = sphere.export(file_type="off").encode()
    lines = off.split(b"\n")
    path = tmp_path / "s.off"
    path.write_bytes(b"\n".join(lines[: 2 + 162 + 7]))
    assert one_line(load_mesh, path) == f"{path}: truncated: header declares 320 faces, file holds 7"
    stl = sphere.export(file_type="stl")
    path = tmp_path / "s.stl"
    path.write_bytes(stl[: 84 + 50 * 200 + 17])
    assert one_line(load_mesh, path) == f"{path}: truncated: header declares 320 triangles, file holds 200"


def test_complete_files_with_quads_and_extra_properties_load(tmp_path: Path):
    text = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
            "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
            "end_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n")
    path = tmp_path / "quad.ply"
    path.write_text(text)
    assert len(load_mesh(path).faces) == 2
    mesh = trimesh.creation.box()
    path = tmp_path / "box.ply"
    path.write_bytes(mesh.export(file_type="ply", encoding="binary", vertex_normal=True))
    assert len(load_mesh(path).faces) == 12


# --- corrupt files of every format -----------------------------------------------------------

JUNK = np.random.default_rng(7).integers(0, 256, 4000, dtype=np.uint8).tobytes()

CORRUPT = {
    "junk.ply": (JUNK, "not a valid PLY file (Not a ply file!)"),
    "junk.obj": (JUNK, "not a valid OBJ file (not UTF-8 text: byte 0x"),
    "junk.off": (JUNK, "not a valid OFF file (not UTF-8 text: byte 0x"),
    "junk.glb": (JUNK, "not a valid GLB file (incorrect header on GLB file)"),
    "junk.gltf": (JUNK, "not a valid glTF file (not UTF-8 text: byte 0x"),
    "text.gltf": (b"{ not json", "not a valid glTF file (not JSON: "),
    "bad.gltf": ((b'{"asset": {"version": "2.0"}, "meshes": [{"primitives": [{"attributes": '
                  b'{"POSITION": 5}}]}]}'), "not a valid glTF file (corrupt or truncated)"),
    "junk.stl": (JUNK, "truncated: header declares "),
    "text.off": (b"hello\nworld\n", "not a valid OFF file (corrupt or truncated)"),
    "ascii.stl": (b"solid x\nfacet normal 0 0 1\n" + JUNK, "not a valid STL file (neither binary STL nor UTF-8 text)"),
}


@pytest.mark.parametrize("gz", [False, True], ids=["plain", "gz"])
@pytest.mark.parametrize("name", sorted(CORRUPT))
def test_corrupt_file_names_file_and_format(tmp_path: Path, name: str, gz: bool):
    data, expected = CORRUPT[name]
    path = tmp_path / (name + (".gz" if gz else ""))
    path.write_bytes(gzip.compress(data) if gz else data)
    message = one_line(load_mesh, path)
    assert message.startswith(f"{path}: {expected}")
    assert "charset_normalizer" not in message and "module" not in message


def test_corrupt_glb_json_chunk(tmp_path: Path):
    data = bytearray(trimesh.creation.box().export(file_type="glb"))
    data[30:60] = JUNK[:30]
    path = tmp_path / "flip.glb"
    path.write_bytes(bytes(data))
    assert one_line(load_mesh, path).startswith(f"{path}: not a valid GLB file (")


# --- coordinates -----------------------------------------------------------------------------

@pytest.mark.parametrize("value", ["1e300", "-1e300", "1e15"])
def test_far_coordinate_names_the_vertex(tmp_path: Path, value: str):
    path = tmp_path / "far.obj"
    path.write_text(f"v 0 0 0\nv 1 0 0\nv 0 {value} 0\nf 1 2 3\n")
    shown = f"{float(value):.6g}"
    assert one_line(load_mesh, path) == (
        f"{path}: vertex 2 has a coordinate beyond ±1e+15 (0, {shown}, 0); 1 vertex is out of "
        f"range (DEFORMGL_MAX_COORDINATE sets the bound)")


def test_coordinate_bound_is_overridable(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    path = tmp_path / "big.obj"
    path.write_text("v 0 0 0\nv 1e16 0 0\nv 0 1e16 0\nf 1 2 3\n")
    monkeypatch.setenv("DEFORMGL_MAX_COORDINATE", "1e20")
    assert load_mesh(path).extents[0] == 1e16
    monkeypatch.setenv("DEFORMGL_MAX_COORDINATE", "nan")
    assert "DEFORMGL_MAX_COORDINATE: must be a positive number" in one_line(load_mesh, path)


# --- node positions --------------------------------------------------------------------------

OFFSET = np.zeros(3)


def test_node_frames_load(tmp_path: Path):
    path = tmp_path / "pos.npy"
    np.save(path, np.arange(12, dtype=np.float32).reshape(4, 3))
    frames = load_node_frames(path, 4, np.ones(3))
    assert frames.shape == (1, 4, 3) and frames.dtype == np.float64 and frames[0, 0, 0] == -1


def test_node_frames_npz(tmp_path: Path):
    path = tmp_path / "pos.npz"
    np.savez(path, positions=np.zeros((4, 3)))
    assert one_line(load_node_frames, path, 4, OFFSET) == (
        f"{path}: node positions must be a .npy array, got a .npz archive")


def test_node_frames_empty_name_and_directory(tmp_path: Path):
    assert one_line(load_node_frames, "", 4, OFFSET) == "nodes.file: no file name given (an empty path)"
    assert one_line(load_node_frames, tmp_path, 4, OFFSET) == (
        f"{tmp_path}: node positions: a directory, not a .npy file")
    missing = tmp_path / "missing.npy"
    assert one_line(load_node_frames, missing, 4, OFFSET) == (
        f"{missing}: cannot read node positions: No such file or directory")


@pytest.mark.parametrize("array, expected", [
    (np.zeros((5, 3)), "node positions must have shape (4, 3) or (frames, 4, 3) for this grid, got (5, 3)"),
    (np.zeros((4, 2)), "node positions must have shape (4, 3) or (frames, 4, 3) for this grid, got (4, 2)"),
    (np.zeros(12), "node positions must have shape (4, 3) or (frames, 4, 3) for this grid, got (12,)"),
    (np.zeros((0, 4, 3)), "node positions must have shape (4, 3) or (frames, 4, 3) for this grid, got (0, 4, 3)"),
    (np.zeros((4, 3), dtype=complex), "node positions must be real numbers, got dtype complex128"),
    (np.array([["a", "b", "c"]] * 4), "node positions must be real numbers, got dtype <U1"),
])
def test_node_frames_wrong_shape_or_dtype(tmp_path: Path, array: np.ndarray, expected: str):
    path = tmp_path / "pos.npy"
    np.save(path, array)
    assert one_line(load_node_frames, path, 4, OFFSET) == f"{path}: {expected}"


def test_node_frames_object_and_non_finite(tmp_path: Path):
    path = tmp_path / "obj.npy"
    np.save(path, np.array([[None] * 3] * 4, dtype=object), allow_pickle=True)
    assert one_line(load_node_frames, path, 4, OFFSET) == (
        f"{path}: node positions must be real numbers, got dtype object")
    path = tmp_path / "nan.npy"
    data = np.zeros((2, 4, 3))
    data[1, 2, 0] = np.inf
    np.save(path, data)
    assert one_line(load_node_frames, path, 4, OFFSET) == (
        f"{path}: frame 1, node 2 has a non-finite coordinate (inf, 0, 0); 1 node positions are bad")


def test_node_frames_truncated_junk_and_too_large(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    path = tmp_path / "cut.npy"
    np.save(path, np.zeros((10, 4, 3)))
    path.write_bytes(path.read_bytes()[:300])
    assert one_line(load_node_frames, path, 4, OFFSET).startswith(f"{path}: truncated: header declares (10, 4, 3)")
    junk = tmp_path / "junk.npy"
    junk.write_bytes(b"hello")
    assert one_line(load_node_frames, junk, 4, OFFSET) == f"{junk}: node positions must be a .npy array, got not a .npy file"
    big = tmp_path / "big.npy"
    np.save(big, np.zeros((10, 4, 3)))
    monkeypatch.setenv("DEFORMGL_MAX_MESH_BYTES", "100")
    assert one_line(load_node_frames, big, 4, OFFSET) == (
        f"{big}: node positions hold 960 bytes, more than the limit of 100 (set DEFORMGL_MAX_MESH_BYTES to raise it)")


def test_zip_named_npy_is_not_a_zip_traceback(tmp_path: Path):
    path = tmp_path / "z.npy"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("a.txt", "x")
    assert one_line(load_node_frames, path, 4, OFFSET) == f"{path}: node positions must be a .npy array, got a .npz archive"
