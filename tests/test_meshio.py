"""Tests for :func:`deformgl.meshio.load_mesh`: formats, gzip, scenes, exact vertices, errors."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest
import trimesh

from deformgl.errors import InputError
from deformgl.grid.meshio import SUPPORTED_SUFFIXES, load_mesh

DRAGON = Path(__file__).resolve().parents[1] / "scenes" / "assets" / "dragon_vrip_res4.ply.gz"

PLY_HEADER = (
    "ply\nformat ascii 1.0\nelement vertex {nv}\nproperty float x\nproperty float y\n"
    "property float z\nelement face {nf}\nproperty list uchar int vertex_indices\nend_header\n"
)


def ascii_ply(vertices: list[str], faces: list[str], nv: int | None = None) -> str:
    """An ASCII PLY file; ``nv`` overrides the declared vertex count (for truncated files)."""
    header = PLY_HEADER.format(nv=len(vertices) if nv is None else nv, nf=len(faces))
    return header + "".join(f"{v}\n" for v in vertices) + "".join(f"{f}\n" for f in faces)


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def load_error(path: Path) -> str:
    """The message of the InputError load_mesh raises for ``path`` (checked to be one line)."""
    with pytest.raises(InputError) as info:
        load_mesh(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path))
    return message


@pytest.fixture
def box() -> trimesh.Trimesh:
    """A box whose vertices are all distinct and in trimesh's fixed order."""
    return trimesh.creation.box(extents=(2.0, 1.0, 0.5))


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".off", ".stl", ".glb"])
def test_each_format_loads_the_same_geometry(tmp_path: Path, box: trimesh.Trimesh, suffix: str):
    path = tmp_path / f"box{suffix}"
    box.export(path)
    mesh = load_mesh(path)
    assert mesh.vertices.dtype == np.float64 and mesh.faces.dtype == np.int64
    assert len(mesh.faces) == 12
    np.testing.assert_allclose(mesh.bounds, box.bounds, atol=1e-6)
    np.testing.assert_allclose(mesh.area, box.area, rtol=1e-6)
    if suffix in (".ply", ".obj", ".off"):  # indexed formats: vertices exactly as written
        np.testing.assert_allclose(mesh.vertices, box.vertices, atol=1e-6)
        np.testing.assert_array_equal(mesh.faces, box.faces)
    if suffix == ".stl":  # STL stores 3 vertices per face; none are merged
        assert len(mesh.vertices) == 36


def test_gltf_with_external_buffer(tmp_path: Path, box: trimesh.Trimesh):
    files = trimesh.Scene(box).export(file_type="gltf")
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    assert any(name.endswith(".bin") for name in files)  # the buffer is a separate file
    mesh = load_mesh(tmp_path / "model.gltf")
    assert len(mesh.faces) == 12
    np.testing.assert_allclose(mesh.bounds, box.bounds, atol=1e-6)


def test_supported_suffixes_are_the_documented_ones():
    assert set(SUPPORTED_SUFFIXES) == {".ply", ".obj", ".stl", ".glb", ".gltf", ".off"}


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".stl", ".glb"])
def test_gzip_round_trip_equals_plain_load(tmp_path: Path, box: trimesh.Trimesh, suffix: str):
    plain = tmp_path / f"box{suffix}"
    box.export(plain)
    packed = tmp_path / f"box{suffix}.GZ"  # suffix case does not matter
    packed.write_bytes(gzip.compress(plain.read_bytes()))
    a, b = load_mesh(plain), load_mesh(packed)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)


def test_dragon_gz_equals_its_decompressed_copy(tmp_path: Path):
    plain = tmp_path / "dragon.ply"
    plain.write_bytes(gzip.decompress(DRAGON.read_bytes()))
    a, b = load_mesh(DRAGON), load_mesh(plain)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)


def test_dragon_vertices_are_the_files_in_file_order():
    text = gzip.decompress(DRAGON.read_bytes()).decode()
    header, body = text.split("end_header\n")
    assert "element vertex 5205" in header and "element face 11102" in header
    lines = body.splitlines()
    in_file = np.array([line.split() for line in lines[:5205]], dtype=np.float32)
    faces = np.array([line.split()[1:] for line in lines[5205:]], dtype=np.int64)
    mesh = load_mesh(DRAGON)
    # processing would merge duplicates and drop unreferenced vertices: 5,203 remain
    assert mesh.vertices.shape == (5205, 3)
    np.testing.assert_array_equal(mesh.vertices, in_file.astype(np.float64))
    np.testing.assert_array_equal(mesh.faces, faces)


def test_obj_keeps_unreferenced_vertices_and_order(tmp_path: Path):
    text = "v 5 5 5\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 2 3 4\nf 2 4 5\n"
    path = write(tmp_path / "m.obj", text)
    mesh = load_mesh(path)
    np.testing.assert_array_equal(mesh.vertices[:2], [[5, 5, 5], [0, 0, 0]])
    np.testing.assert_array_equal(mesh.faces, [[1, 2, 3], [1, 3, 4]])


def test_obj_with_texture_coordinates_is_not_split(tmp_path: Path):
    text = (
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\n"
        "f 1/1 2/2 3/3\nf 1/2 3/3 4/1\n"
    )
    mesh = load_mesh(write(tmp_path / "uv.obj", text))
    assert len(mesh.vertices) == 4
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3]])


def test_glb_scene_with_two_parts_is_concatenated_with_transforms(tmp_path: Path):
    scene = trimesh.Scene()
    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    move = trimesh.transformations.translation_matrix
    scene.add_geometry(cube, geom_name="a", transform=move((5, 0, 0)))
    slab = trimesh.creation.box(extents=(2.0, 0.5, 0.25))
    scene.add_geometry(slab, geom_name="b", transform=move((0, 0, -3)))
    path = tmp_path / "two.glb"
    path.write_bytes(scene.export(file_type="glb"))
    mesh = load_mesh(path)
    assert len(mesh.vertices) == 16 and len(mesh.faces) == 24
    assert mesh.faces.max() == 15  # the second part's faces were offset
    np.testing.assert_allclose(mesh.bounds, [[-1.0, -0.5, -3.125], [5.5, 0.5, 0.5]], atol=1e-6)
    parts = mesh.split(only_watertight=False)
    assert sorted(round(p.volume, 6) for p in parts) == [0.25, 1.0]


def test_nan_vertex_in_ply_names_file_vertex_and_count(tmp_path: Path):
    vertices = ["0 0 0", "1 0 0", "nan 0.1 0.2", "0 1 0", "0 0 inf", "1 1 nan"]
    path = write(tmp_path / "dragon.ply", ascii_ply(vertices, ["3 0 1 3", "3 2 4 5"]))
    message = load_error(path)
    assert message == (
        f"{path}: vertex 2 has a non-finite coordinate (nan, 0.1, 0.2); 3 vertices are bad"
    )


def test_nan_vertex_in_obj(tmp_path: Path):
    path = write(tmp_path / "m.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 nan\nf 1 2 3\nf 1 2 4\n")
    assert "vertex 3 has a non-finite coordinate (0, 0, nan); 1 vertex is bad" in load_error(path)


def test_unreferenced_nan_vertex_is_still_an_error(tmp_path: Path):
    text = ascii_ply(["0 0 0", "1 0 0", "0 1 0", "nan nan nan"], ["3 0 1 2"])
    path = write(tmp_path / "m.ply", text)
    assert "vertex 3 has a non-finite coordinate" in load_error(path)


def test_missing_file(tmp_path: Path):
    assert load_error(tmp_path / "nothere.ply").endswith("file not found")


def test_directory_is_not_a_file(tmp_path: Path):
    folder = tmp_path / "folder.ply"
    folder.mkdir()
    assert load_error(folder).endswith("not a regular file")


@pytest.mark.parametrize("name", ["mesh.txt", "mesh.3ds", "mesh.txt.gz", "mesh"])
def test_unsupported_suffix_lists_the_supported_ones(tmp_path: Path, name: str):
    message = load_error(write(tmp_path / name, "v 0 0 0\n"))
    assert "unsupported mesh format" in message
    assert all(suffix in message for suffix in SUPPORTED_SUFFIXES)


@pytest.mark.parametrize("name", ["empty.ply", "empty.obj", "empty.stl", "empty.off", "empty.glb"])
def test_empty_file(tmp_path: Path, name: str):
    assert load_error(write(tmp_path / name, "")).endswith("file is empty")


def test_empty_gzip_member(tmp_path: Path):
    path = tmp_path / "empty.ply.gz"
    path.write_bytes(gzip.compress(b""))
    assert load_error(path).endswith("file is empty")


def test_truncated_ply_names_the_element_and_counts(tmp_path: Path):
    text = ascii_ply(["0 0 0", "1 0 0", "0 1 0"], ["3 0 1 2"])
    path = write(tmp_path / "cut.ply", text[: text.index("0 1 0")])
    assert load_error(path) == f"{path}: truncated: header declares 3 vertices, file holds 2"
    path = write(tmp_path / "nofaces.ply", text[: text.index("3 0 1 2")])
    assert load_error(path) == f"{path}: truncated: header declares 1 faces, file holds 0"


def test_truncated_dragon_ascii_ply(tmp_path: Path):
    """The fuzzer's case: the dragon cut short used to load 5,075 of its 11,102 faces silently."""
    data = gzip.decompress(DRAGON.read_bytes())
    body = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[body:].split(b"\n")
    path = tmp_path / "dragon.ply"
    path.write_bytes(data[:body] + b"\n".join(lines[: 5205 + 5075]) + b"\n")
    assert load_error(path) == f"{path}: truncated: header declares 11,102 faces, file holds 5,075"


def test_coordinates_of_1e300_name_the_vertex(tmp_path: Path):
    text = ascii_ply(["0 0 0", "1e300 0 0", "0 1 0", "0 0 -1e300"], ["3 0 1 2", "3 0 2 3"])
    text = text.replace("property float", "property double")  # float32 would make them inf
    assert load_error(write(tmp_path / "far.ply", text)).endswith(
        ": vertex 1 has a coordinate beyond ±1e+15 (1e+300, 0, 0); 2 vertices are out of range "
        "(DEFORMGL_MAX_COORDINATE sets the bound)"
    )


@pytest.mark.parametrize("name", ["m.ply", "m.obj", "m.stl", "m.off", "m.glb", "m.gltf"])
def test_random_bytes_never_leak_a_module_or_internal_error(tmp_path: Path, name: str):
    junk = np.random.default_rng(3).integers(0, 256, 3000, dtype=np.uint8).tobytes()
    for path in (tmp_path / name, tmp_path / f"{name}.gz"):
        path.write_bytes(gzip.compress(junk) if path.suffix == ".gz" else junk)
        message = load_error(path)
        assert "module" not in message and "charset" not in message
        fmt = {"gltf": "glTF"}.get(name[2:], name[2:].upper())
        assert f"not a valid {fmt} file" in message or "truncated: header declares" in message


def test_truncated_binary_stl_is_empty(tmp_path: Path, box: trimesh.Trimesh):
    data = box.export(file_type="stl")
    path = tmp_path / "cut.stl"
    path.write_bytes(data[:60])
    assert "empty mesh" in load_error(path)


def test_truncated_gzip(tmp_path: Path):
    path = tmp_path / "cut.ply.gz"
    path.write_bytes(DRAGON.read_bytes()[:5000])
    assert "not a valid gzip file" in load_error(path)


def test_plain_file_named_gz(tmp_path: Path):
    path = write(tmp_path / "m.obj.gz", "v 0 0 0\n")
    assert "not a valid gzip file" in load_error(path)


def test_parse_failure_wraps_trimesh_message(tmp_path: Path):
    message = load_error(write(tmp_path / "junk.ply", "this is not a mesh\n"))
    assert message == f"{tmp_path / 'junk.ply'}: not a valid PLY file (Not a ply file!)"


def test_point_cloud_is_not_a_mesh(tmp_path: Path):
    text = PLY_HEADER.split("element face")[0].format(nv=3) + "end_header\n0 0 0\n1 0 0\n0 1 0\n"
    message = load_error(write(tmp_path / "p.ply", text))
    assert "no triangle mesh in file (found only PointCloud)" in message


@pytest.mark.parametrize("index", ["7", "-1", "3"])
def test_face_index_out_of_range(tmp_path: Path, index: str):
    text = ascii_ply(["0 0 0", "1 0 0", "0 1 0"], ["3 0 1 2", f"3 0 1 {index}"])
    message = load_error(write(tmp_path / "bad.ply", text))
    assert f"face 1 has a vertex index out of range [0, 1, {index}]" in message
    assert "(the mesh has 3 vertices); 1 face is bad" in message


def test_face_index_out_of_range_in_obj_and_off(tmp_path: Path):
    obj = write(tmp_path / "bad.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    assert "out of bounds" in load_error(obj)
    off = write(tmp_path / "bad.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n")
    assert "outside the range" in load_error(off)


def test_zero_extent(tmp_path: Path):
    text = ascii_ply(["0.5 0.5 0.5"] * 3, ["3 0 1 2"])
    assert load_error(write(tmp_path / "dot.ply", text)).endswith(
        "mesh has zero extent (all 3 vertices coincide)"
    )


def test_flat_mesh_is_accepted(tmp_path: Path):
    text = ascii_ply(["0 0 0", "1 0 0", "0 1 0"], ["3 0 1 2"])
    mesh = load_mesh(write(tmp_path / "flat.ply", text))
    np.testing.assert_array_equal(mesh.extents, [1, 1, 0])


def test_uvs_are_kept(tmp_path):
    """Per-vertex UVs survive loading (the normal map uses the mesh's own UVs)."""
    import trimesh as tm

    from deformgl.render.mapped_setup import mesh_uv

    mesh = tm.creation.box()
    uv = np.stack([mesh.vertices[:, 0] + 0.5, mesh.vertices[:, 1] + 0.5], axis=1)
    mesh.visual = tm.visual.TextureVisuals(uv=uv)
    path = tmp_path / "box_uv.obj"
    path.write_text(tm.exchange.obj.export_obj(mesh, include_texture=True, write_texture=False))
    loaded = load_mesh(path)
    got = mesh_uv(loaded)
    assert got is not None and got.shape == (len(loaded.vertices), 2)
    # each loaded vertex keeps the UV of its position
    by_pos = {tuple(np.round(v, 6)): tuple(np.round(t, 6)) for v, t in zip(mesh.vertices, uv)}
    for v, t in zip(loaded.vertices, got):
        assert by_pos[tuple(np.round(v, 6))] == tuple(np.round(t, 6))
