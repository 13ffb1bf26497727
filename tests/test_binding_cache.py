"""Tests for the verifying binding cache (:mod:`deformgl.mapping.binding_cache` and
:func:`deformgl.render.mapped_setup.get_binding`): every damaged entry is found, warned about,
rebuilt and replaced; every obstruction is warned about and the run goes on (no GL)."""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import pytest
import trimesh

from deformgl.errors import DeformglWarning
from deformgl.grid.nodes import NodeGrid
from deformgl.grid.surface import GridSurface, grid_surface
from deformgl.grid.voxelize import voxelize
from deformgl.mapping import binding_cache as cache
from deformgl.mapping.binding import Binding, BindingReport, bind
from deformgl.render import mapped_setup
from deformgl.render.mapped_setup import get_binding
from deformgl.sim.normals import rest_normals


@dataclass
class Scene:
    mesh: trimesh.Trimesh
    grid: NodeGrid
    surface: GridSurface
    fresh: Binding


@pytest.fixture(scope="module")
def scene() -> Scene:
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    mesh = trimesh.Trimesh(mesh.vertices + [0.3, -0.2, 0.1], mesh.faces, process=False)
    vox = voxelize(mesh, nodes_along_longest=5)
    grid = NodeGrid(np.asarray(vox.origin), float(vox.spacing), np.asarray(vox.occupied))
    surface = grid_surface(grid)
    fresh = bind(mesh.vertices, mesh.faces, grid.rest_positions, rest_normals(grid), surface,
                 spacing=grid.spacing)
    return Scene(mesh, grid, surface, fresh)


@pytest.fixture
def cache_folder(tmp_path, monkeypatch) -> Path:
    folder = tmp_path / "cache"
    monkeypatch.setenv(mapped_setup.CACHE_ENV, str(folder))
    return folder


def assert_bindings_equal(a: Binding, b: Binding) -> None:
    for f in fields(Binding):
        if f.name != "report":
            x, y = getattr(a, f.name), getattr(b, f.name)
            np.testing.assert_array_equal(x, y, err_msg=f.name)
            assert x.dtype == y.dtype, f.name
    for f in fields(BindingReport):
        np.testing.assert_array_equal(getattr(a.report, f.name), getattr(b.report, f.name), err_msg=f.name)


def quiet_get(s: Scene) -> Binding:
    """get_binding, failing on any warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return get_binding(s.mesh, s.grid, s.surface, use_cache=True, uv=None)


def entry(folder: Path) -> Path:
    (path,) = folder.glob("binding-*.npz")
    return path


def key_of(s: Scene) -> str:
    return cache.binding_key(s.mesh.vertices, s.mesh.faces, s.grid.rest_positions, s.surface.triangles,
                             s.grid.spacing, {"format": mapped_setup.BINDING_FORMAT}, uv=None)


def assert_valid(path: Path, s: Scene) -> None:
    """The file at ``path`` passes every check and holds the fresh binding."""
    loaded = cache.read_binding(path, key_of(s), vertices=s.mesh.vertices, node_positions=s.grid.rest_positions,
                                node_normals=rest_normals(s.grid))
    assert loaded is not None
    assert_bindings_equal(loaded, s.fresh)


def test_every_binding_field_has_a_spec():
    assert set(cache.FIELD_SPECS) == {f.name for f in fields(Binding)} - {"report"}
    assert set(cache.REPORT_SPECS) == set(cache._REPORT_ARRAYS)


def test_miss_then_honest_hit_returns_the_saved_arrays_without_warning(scene, cache_folder):
    first = quiet_get(scene)
    assert_bindings_equal(first, scene.fresh)
    path = entry(cache_folder)
    assert sorted(os.listdir(cache_folder)) == [path.name]  # no temporary file left behind
    stamp = path.stat().st_mtime_ns
    with np.load(path, allow_pickle=False) as npz:
        saved = dict(npz)
    assert saved["checksum"].item() == cache.checksum(saved)
    again = quiet_get(scene)
    assert path.stat().st_mtime_ns == stamp  # a hit does not rewrite the entry
    for name in cache.FIELD_SPECS:
        np.testing.assert_array_equal(getattr(again, name), saved[name], err_msg=name)
        assert getattr(again, name).dtype == saved[name].dtype
    assert_bindings_equal(again, scene.fresh)


def rewrite(path: Path, change, *, fix_checksum: bool = True) -> None:
    with np.load(path, allow_pickle=False) as npz:
        arrays = {name: np.array(npz[name]) for name in npz.files}
    change(arrays)
    if fix_checksum and "checksum" in arrays:
        arrays["checksum"] = np.asarray(cache.checksum(arrays))
    with open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)


def _set(name, index, value):
    def change(a):
        a[name][index] = value
    return change


def _flip_array_byte(a):
    raw = bytearray(a["weights"].tobytes())
    raw[5] ^= 0x10
    a["weights"] = np.frombuffer(bytes(raw), dtype=a["weights"].dtype).reshape(a["weights"].shape).copy()


def _shift(name, by):
    def change(a):
        a[name] = a[name] + by
    return change


def _retype(name, dtype):
    def change(a):
        a[name] = a[name].astype(dtype)
    return change


def _drop(name):
    def change(a):
        del a[name]
    return change


def _node_count_index(a):
    a["tri_nodes"][3, 1] = NODE_COUNT[0]


NODE_COUNT = [0]  # filled in by the test (the change functions only see the arrays)

#: (case, change to the arrays, recompute the checksum, a word of the warning)
ARRAY_DAMAGE = {
    "flipped_array_byte": (_flip_array_byte, False, "checksum"),
    "shifted_offsets_stale_checksum": (_shift("offset_world", 0.01), False, "checksum"),
    "shifted_offsets": (_shift("offset_world", np.array([0.01, 0.0, 0.0])), True, "offset_world"),
    "shifted_local_offsets": (_shift("offset_constant", 0.01), True, "offset_constant"),
    "shifted_curvature_offsets": (_shift("offset_curvature", 0.01), True, "offset_curvature"),
    "negative_node_index": (_set("tri_nodes", (2, 0), -1), True, "node index -1"),
    "node_index_n": (_node_count_index, True, "node index"),
    "huge_node_index": (_set("tri_nodes", (0, 2), 2**30), True, "node index"),
    "weight_1e30": (_set("weights", (1, 1), 1e30), True, "weights"),
    "weight_negative": (_set("weights", (1, 1), -0.25), True, "weights"),
    "weights_not_summing_to_1": (_set("weights", (4,), [0.5, 0.25, 0.0]), True, "sum to 1"),
    "nan": (_set("normal_constant", (0, 0), np.nan), True, "non-finite"),
    "inf": (_set("distance", (0,), np.inf), True, "non-finite"),
    "wrong_dtype_weights": (_retype("weights", np.float32), True, "dtype"),
    "wrong_dtype_nodes": (_retype("tri_nodes", np.float64), True, "dtype"),
    "wrong_dtype_flags": (_retype("curvature_ok", np.uint8), True, "dtype"),
    "wrong_shape": (lambda a: a.update(weights=a["weights"][:-1]), True, "shape"),
    "wrong_columns": (lambda a: a.update(uv=a["uv"][:, :1]), True, "shape"),
    "missing_array": (_drop("normal_world"), True, "lacks"),
    "extra_array": (lambda a: a.update(extra=np.zeros(3)), True, "unexpected"),
    "missing_checksum": (_drop("checksum"), True, "lacks"),
    "wrong_checksum": (lambda a: a.update(checksum=np.asarray("0" * 64)), False, "checksum"),
    "wrong_key": (lambda a: a.update(key=np.asarray("f" * 64)), True, "key"),
    "old_version": (lambda a: a.update(version=np.asarray(2)), True, "version"),
    "no_version": (_drop("version"), True, "version"),
    "bad_handedness": (_set("tangent_world", (0, 3), 0.5), True, "handedness"),
    "report_index_out_of_range": (lambda a: a.update(report_far_vertices=np.array([10**6]),
                                                     report_far_distances=np.array([1.0])), True,
                                  "report_far_vertices outside"),
    "report_vertex_count": (lambda a: a.update(report_vertex_count=np.asarray(7)), True, "report_vertex_count"),
}


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _flip_file_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


def _npy_bytes() -> bytes:
    import io
    buf = io.BytesIO()
    np.save(buf, np.zeros(3))
    return buf.getvalue()


def _pickled(path: Path) -> None:
    with open(path, "wb") as fh:
        np.save(fh, np.array([{"a": 1}], dtype=object), allow_pickle=True)


#: (case, damage to the file)
FILE_DAMAGE = {
    "truncated": _truncate,
    "flipped_file_byte": _flip_file_byte,
    "not_a_zip": lambda p: p.write_bytes(b"not a zip file at all" * 10),
    "empty": lambda p: p.write_bytes(b""),
    "npy_not_npz": lambda p: p.write_bytes(_npy_bytes()),
    "pickle": _pickled,
}


@pytest.mark.parametrize("case", list(ARRAY_DAMAGE) + list(FILE_DAMAGE))
def test_a_damaged_entry_is_rebuilt_and_replaced_with_a_warning(scene, cache_folder, case):
    NODE_COUNT[0] = scene.grid.count
    quiet_get(scene)
    path = entry(cache_folder)
    if case in ARRAY_DAMAGE:
        change, fix, word = ARRAY_DAMAGE[case]
        rewrite(path, change, fix_checksum=fix)
    else:
        FILE_DAMAGE[case](path)
        word = ".npz"
    with pytest.warns(DeformglWarning) as record:
        got = get_binding(scene.mesh, scene.grid, scene.surface, use_cache=True, uv=None)
    assert len(record) == 1
    message = str(record[0].message)
    assert message.startswith(f"{path}: binding cache entry ") and message.endswith(": rebuilt")
    assert "\n" not in message and word in message
    assert_bindings_equal(got, scene.fresh)
    assert_valid(path, scene)
    assert sorted(os.listdir(cache_folder)) == [path.name]
    assert_bindings_equal(quiet_get(scene), scene.fresh)  # and the next run is a quiet hit


def test_load_binding_gives_none_for_damage_and_read_binding_says_why(scene, tmp_path):
    path = tmp_path / "b.npz"
    cache.save_binding(path, scene.fresh, "k")
    assert cache.load_binding(path, "k") is not None
    assert cache.read_binding(tmp_path / "absent.npz", "k") is None
    rewrite(path, _set("tri_nodes", (0, 0), scene.grid.count))
    assert cache.load_binding(path, "k") is not None  # without the node count only >= 0 is checked
    assert cache.load_binding(path, "k", node_count=scene.grid.count) is None
    with pytest.raises(cache.BadCacheEntry, match=f"node index {scene.grid.count} in tri_nodes, "
                                                  f"outside 0..{scene.grid.count - 1}"):
        cache.read_binding(path, "k", node_count=scene.grid.count)


def _check_caching_off(record, path: Path) -> None:
    assert len(record) == 1
    message = str(record[0].message)
    assert message.startswith(f"{path}: caching off for this run: ") and "\n" not in message


def test_a_directory_at_the_entry_path_turns_caching_off_with_a_warning(scene, cache_folder):
    quiet_get(scene)
    path = entry(cache_folder)
    path.unlink()
    path.mkdir()
    with pytest.warns(DeformglWarning) as record:
        got = get_binding(scene.mesh, scene.grid, scene.surface, use_cache=True, uv=None)
    _check_caching_off(record, path)
    assert_bindings_equal(got, scene.fresh)
    assert path.is_dir() and list(path.iterdir()) == []  # nobody's directory is removed


def test_a_file_where_the_cache_folder_goes_turns_caching_off_with_a_warning(scene, cache_folder):
    cache_folder.write_text("in the way")
    path = cache_folder / f"binding-{key_of(scene)[:24]}.npz"
    with pytest.warns(DeformglWarning) as record:
        got = get_binding(scene.mesh, scene.grid, scene.surface, use_cache=True, uv=None)
    _check_caching_off(record, path)
    assert_bindings_equal(got, scene.fresh)
    assert cache_folder.read_text() == "in the way"


def test_an_unwritable_cache_folder_turns_caching_off_with_a_warning(scene, cache_folder, monkeypatch):
    def refuse(path, write):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(cache, "write_atomic", refuse)
    path = cache_folder / f"binding-{key_of(scene)[:24]}.npz"
    with pytest.warns(DeformglWarning) as record:
        got = get_binding(scene.mesh, scene.grid, scene.surface, use_cache=True, uv=None)
    _check_caching_off(record, path)
    assert "Permission denied" in str(record[0].message)
    assert_bindings_equal(got, scene.fresh)


def test_a_cache_folder_nobody_can_write_turns_caching_off_with_a_warning(scene, monkeypatch):
    """A real refusal by the OS, even for root (CI runs as root, which writes into read-only
    folders): a cache folder under /proc cannot be created."""
    monkeypatch.setenv("DEFORMGL_CACHE_DIR", "/proc/deformgl-cache")
    with pytest.warns(DeformglWarning, match="caching off for this run"):
        got = get_binding(scene.mesh, scene.grid, scene.surface, use_cache=True, uv=None)
    assert_bindings_equal(got, scene.fresh)


def test_a_damaged_entry_in_a_read_only_folder_warns_twice_and_still_binds(scene, cache_folder, monkeypatch):
    quiet_get(scene)
    path = entry(cache_folder)
    rewrite(path, _set("weights", (0, 0), 1e30))
    monkeypatch.setattr(cache, "write_atomic", lambda p, w: (_ for _ in ()).throw(OSError(28, "No space left")))
    with pytest.warns(DeformglWarning) as record:
        got = get_binding(scene.mesh, scene.grid, scene.surface, use_cache=True, uv=None)
    assert [str(r.message).split(": ")[1] for r in record] == ["binding cache entry has weights outside [0, 1]",
                                                              "caching off for this run"]
    assert_bindings_equal(got, scene.fresh)


def test_use_cache_false_touches_nothing(scene, cache_folder):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = get_binding(scene.mesh, scene.grid, scene.surface, use_cache=False, uv=None)
    assert_bindings_equal(got, scene.fresh)
    assert not cache_folder.exists()


def test_cache_dir_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(mapped_setup.CACHE_ENV, str(tmp_path / "c"))
    assert mapped_setup.cache_dir() == tmp_path / "c"
    monkeypatch.delenv(mapped_setup.CACHE_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "x"))
    assert mapped_setup.cache_dir() == tmp_path / "x" / "deformgl"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative")  # ignored, as the XDG spec asks
    assert mapped_setup.cache_dir() == Path.home() / ".cache" / "deformgl"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert mapped_setup.cache_dir() == Path.home() / ".cache" / "deformgl"
