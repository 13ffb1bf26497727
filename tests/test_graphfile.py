"""Scene-graph files (docs/SCENEGRAPH.md): the format, its one-line errors, and load -> save ->
load as the identity; the shipped demos as files equal to the graphs built in Python."""

import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from deformgl.errors import SceneError
from test_scene_fuzz import _dump, _mutate  # the scene fuzzer's mutations
from deformgl.trilinear.graphbuild import build_graph
from deformgl.trilinear.graphfile import is_graph_file, load_graph, save_graph
from deformgl.trilinear.graphspec import (
    GraphBody, Deformation, Keyframe, GraphMesh, NodeSpec, SceneGraph, GraphTransform, GraphView,
)
from deformgl.trilinear.scenegraph import compose_scene
from deformgl.trilinear.graph_nodes import GeometryNode, TransformNode
from deformgl.trilinear.scenes import COLOURS, Z_UP_TO_Y_UP, helix_scene, tile_scene, tubes_scene
from deformgl.trilinear.grid import Trilinear

SCENES = Path(__file__).resolve().parent.parent / "scenes"
SHIPPED = ["trilinear_tubes.toml", "trilinear_tile.toml", "trilinear_helix.toml", "trilinear_helix_4617.toml",
           "graph_dragon_beads.toml", "graph_bend_twist.toml"]


def every_kind_graph(tmp_path: Path) -> SceneGraph:
    """A graph with every transform kind, keyframes, a lattice file and a mesh file."""
    lattice = Trilinear.from_function(Deformation("twist", {"rate": 0.5}).function(),
                                      __import__("deformgl.trilinear.cuboid", fromlist=["Box"]).Box(
                                          np.zeros(3), np.ones(3)), (2, 3, 4))
    np.save(tmp_path / "lattice.npy", lattice.points)
    import trimesh
    trimesh.creation.box().export(tmp_path / "box.ply")
    corners = np.array([[i & 1, i >> 1 & 1, i >> 2 & 1] for i in range(8)], float) * 2.0
    corners[7] += 0.25
    c = np.zeros((3, 8))
    c[:, 4:7] = np.identity(3)[:, ::-1]
    c[0, 0] = 0.125
    return SceneGraph(
        roots=["a"], description="every kind", output="x.png",
        meshes={"s": GraphMesh("sphere", {"radius": 0.5, "segments": 8, "rings": 5}), "f": GraphMesh(file="box.ply"),
                "t": GraphMesh("tube", {"length": 1.0, "radius": 0.25})},
        deformations={"tw": Deformation("twist", {"rate": 0.1}, [Keyframe(0.0, {"rate": 0.0}), Keyframe(1.5, {"rate": 0.8})]),
                      "b": Deformation("bend", {"angle": 0.3, "length": 2.0}),
                      "w": Deformation("torus", {"length": 4.0, "width": 2.0, "major": 3.0, "minor": 1.0})},
        nodes={"a": NodeSpec(GraphTransform("matrix", matrix=Z_UP_TO_Y_UP.copy()), ["b"], normals="tangent"),
               "b": NodeSpec(GraphTransform("trs", translate=(1.0, 2.0, 3.0), axis=(0.0, 1.0, 0.0), degrees=30.0,
                                       scale=(1.0, 2.0, 0.5)), ["c", "d", "e"]),
               "c": NodeSpec(GraphTransform("cuboid", corners=corners, box=((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))), ["g"]),
               "d": NodeSpec(GraphTransform("coefficients", coefficients=c, box=((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))), ["g"]),
               "e": NodeSpec(GraphTransform("grid", deformation="tw", cells=(3, 3, 3)), ["h"], colour=(0.1, 0.2, 0.3)),
               "g": NodeSpec(GraphTransform("grid", file="lattice.npy", box=((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))), ["i"]),
               "h": NodeSpec(GraphTransform("array", count=(2, 3, 1), step=(1.0, 1.0, 0.0), offset=(0.5, 0.0, 0.0),
                                       colours=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)), tangent_of="w",
                                       tangent_at=(0.5, 0.0, 0.0)), ["i", "j"]),
               "i": NodeSpec(mesh="s"), "j": NodeSpec(mesh="f", normals="direct")},
        view=GraphView(size=(200, 100), azimuth=5.0, elevation=10.0, distance=2.0, samples=0, background=(0.5, 0.5, 0.5)))


def test_load_save_load_is_the_identity(tmp_path):
    graph = every_kind_graph(tmp_path)
    first = save_graph(graph, tmp_path / "g.toml")
    loaded = load_graph(first)
    assert loaded == graph
    again = load_graph(save_graph(loaded, tmp_path / "h.toml"))
    assert again == loaded
    assert (tmp_path / "g.toml").read_text() == (tmp_path / "h.toml").read_text()
    for name in SHIPPED:
        g = load_graph(SCENES / name)
        assert load_graph(save_graph(g, tmp_path / name)) == g
    # an attach node round-trips too (with its body)
    g = load_graph(SCENES / "graph_dragon_beads.toml")
    assert g.body == GraphBody("dragon_bend_constant.toml") and g.nodes["back"].transform.kind == "attach"
    assert g.nodes["back"].transform.anchors == 16


def test_the_shipped_demo_files_build_the_graphs_of_the_python_builders():
    """Each demo file composes to the same leaves and transforms as the Python builder of the scene."""
    pairs = [("trilinear_tile.toml", [tile_scene().root]),
             ("trilinear_tubes.toml", [tubes_scene("linear").root, tubes_scene("trilinear").root]),
             ("trilinear_helix.toml", [helix_scene("trilinear", 600, turns=6.0).root]),
             ("trilinear_helix_4617.toml", [helix_scene("trilinear", 4617, segments=6, rings=4).root])]
    for name, roots in pairs:
        graph = load_graph(SCENES / name)
        built = build_graph(graph, SCENES)
        assert len(built) == len(roots)
        for a, b in zip(built, roots):
            ca, cb = compose_scene(a), compose_scene(b)
            assert ca.paths() == cb.paths() and ca.leaf_count == cb.leaf_count
            for x, y in zip(ca.batches, cb.batches):
                assert x.path == y.path and x.colour == y.colour and x.count == y.count
                for name_ in ("affine", "corners", "box_lo", "box_size"):
                    va, vb = getattr(x, name_), getattr(y, name_)
                    assert (va is None and vb is None) or np.array_equal(va, vb), (name, name_)
                assert all(np.array_equal(p, q) for p, q in zip(x.grids, y.grids))


def test_instancing_shares_nodes_and_arrays_colour_their_instances(tmp_path):
    graph = every_kind_graph(tmp_path)
    (root,) = build_graph(graph, tmp_path)
    leaves = [n for n in root.walk() if isinstance(n, GeometryNode)]
    # c and d share g -> i (one runtime node, two parents); e -> h: 6 instances x (i, j)
    assert len(leaves) == 2 + 12
    colours = [leaf.colour for leaf in leaves if leaf.name in ("i", "j")][2:]
    assert colours[:4] == [(1.0, 0.0, 0.0)] * 2 + [(0.0, 1.0, 0.0)] * 2  # (i + j) mod 2, x outer
    grids = [n for n in root.walk() if isinstance(n, TransformNode) and isinstance(n.transform, Trilinear)]
    assert {g.name for g in grids} == {"c", "d", "e", "g"}
    # the coefficient matrix C (Knuth, Kohlhammer & Kuijper, eq. 2-4) evaluates as v' = C v on the unit cube of its box
    d = next(g for g in grids if g.name == "d").transform
    u = np.array([[0.25, 0.5, 0.75]])
    x, y, z = u[0]
    want = np.array([x + 0.125 * x * y * z, y, z])  # columns z, y, x of C are e_z, e_y, e_x
    assert np.allclose(d(2.0 * u - 1.0)[0], want)


def test_keyframes_interpolate_and_at_gives_the_still(tmp_path):
    graph = every_kind_graph(tmp_path)
    tw = graph.deformations["tw"]
    assert tw.values_at(0.75)["rate"] == pytest.approx(0.4)
    assert tw.values_at(-1.0)["rate"] == 0.0 and tw.values_at(9.0)["rate"] == pytest.approx(0.8)
    assert graph.duration == 1.5
    still = graph.at(0.75)
    assert still.deformations["tw"].params["rate"] == pytest.approx(0.4) and still.deformations["tw"].keys == []
    assert still.nodes == graph.nodes


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    return path


GOOD = """
[graph]
roots = ["r"]
[meshes.m]
shape = "sphere"
radius = 1.0
[nodes.r]
translate = [0, 0, 1]
children = ["leaf"]
[nodes.leaf]
mesh = "m"
"""


@pytest.mark.parametrize("edit, message", [
    (("[graph]", "[graph]\nrooots = 1"), r"bad\.toml: graph\.rooots: unknown key \(did you mean 'roots'\?\)"),
    (("translate = [0, 0, 1]", "translate = [0, 0]"), r"nodes\.r\.translate: must be an array of shape \(3,\)"),
    (("translate = [0, 0, 1]", "translate = [0, 0, 1]\nmatrix = 3"), r"nodes\.r\.translate: a node has one transform; it already has .matrix."),
    (("radius = 1.0", "radius = -1.0"), r"meshes\.m\.radius: must be > 0"),
    (("shape = \"sphere\"", "shape = \"cone\""), r"meshes\.m\.shape: must be one of 'tube', 'sphere', 'tile'"),
    (('children = ["leaf"]', 'children = ["leaf", "nope"]'), r"nodes\.r\.children: no node named 'nope'"),
    (('children = ["leaf"]', 'children = ["r"]'), r"nodes\.r: the graph has a cycle"),
    (('mesh = "m"', 'mesh = "m"\nchildren = ["r"]'), r"nodes\.leaf\.children: a mesh node has no children"),
    (("translate = [0, 0, 1]", 'grid = { deformation = "d", cells = [1, 1, 1] }'),
     r"nodes\.r\.grid: no deformation named 'd'"),
    (("translate = [0, 0, 1]", 'grid = { deformation = "d", cells = [0, 1, 1] }'),
     r"nodes\.r\.grid\.cells\[0\]: must be an integer in \[1, 4096\]"),
    (("translate = [0, 0, 1]", "matrix = [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,1,1]]"),
     r"nodes\.r\.matrix: the last row must be \[0, 0, 0, 1\]"),
    (("translate = [0, 0, 1]", "attach = { start = [0, 0, 0], end = [1, 1, 1] }"),
     r"nodes\.r\.attach: needs a \[body\] to attach to"),
    (("[graph]", "[deformations.d]\nkind = \"twist\"\nrate = 1.0\nkeys = [{ t = 1.0, rate = 0.0 }, { t = 0.5, rate = 1.0 }]\n[graph]"),
     r"deformations\.d\.keys\[1\]\.t: keyframe times must increase"),
    (("[graph]", "[graph"), r"bad\.toml: invalid TOML"),
])
def test_bad_files_fail_in_one_line_naming_file_and_key(tmp_path, edit, message):
    path = _write(tmp_path, GOOD.replace(*edit, 1))
    with pytest.raises(SceneError, match=message) as info:
        load_graph(path)
    assert "\n" not in str(info.value) and str(info.value).startswith(str(path))


def test_a_good_file_is_a_graph_file_and_a_simulation_scene_is_not(tmp_path):
    path = _write(tmp_path, GOOD)
    assert is_graph_file(path) and load_graph(path).nodes["r"].transform.translate == (0.0, 0.0, 1.0)
    assert not is_graph_file(SCENES / "jelly.toml") and not is_graph_file(tmp_path / "missing.toml")


def test_a_missing_mesh_file_is_named_at_build_time(tmp_path):
    path = _write(tmp_path, GOOD.replace('shape = "sphere"\nradius = 1.0', 'file = "nowhere.ply"'))
    graph = load_graph(path)
    with pytest.raises(SceneError, match=r"bad\.toml: meshes\.m\.file: .*nowhere\.ply"):
        build_graph(graph, tmp_path, file=str(path))


def test_colours_of_the_demo_arrays_are_the_builders_colours():
    graph = load_graph(SCENES / "trilinear_tubes.toml")
    assert graph.nodes["tubes"].transform.colours == tuple(tuple(c) for c in COLOURS[:2])


@settings(max_examples=150, derandomize=True, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                 HealthCheck.data_too_large])
@given(data=st.data())
def test_mutated_graph_files_load_or_fail_in_one_line(tmp_path_factory, data):
    """The scene fuzzer's mutations (test_scene_fuzz.py) on the shipped scene-graph files: every
    outcome is a graph that checks, or one SceneError line naming the file."""
    base = data.draw(st.sampled_from(SHIPPED), label="graph")
    doc = _mutate(tomllib.loads((SCENES / base).read_text(encoding="utf-8")), data)
    path = tmp_path_factory.mktemp("fuzz") / base
    path.write_text(_dump(doc), encoding="utf-8")
    try:
        graph = load_graph(path)
    except SceneError as e:
        assert "\n" not in str(e) and str(e).startswith(f"{path}: "), str(e)
    else:
        assert graph.check() is graph


def test_depth_and_size_limits(tmp_path):
    """3,000 levels load, save and build (the nesting is in the names); too many instances or
    lattice points are refused up front, in one line."""
    n = 3000
    nodes = {f"n{i}": NodeSpec(GraphTransform("trs", translate=(0.001, 0.0, 0.0)), [f"n{i + 1}"]) for i in range(n)}
    nodes[f"n{n}"] = NodeSpec(mesh="m")
    g = SceneGraph(roots=["n0"], nodes=nodes, meshes={"m": GraphMesh("sphere", {"radius": 1.0})})
    loaded = load_graph(save_graph(g, tmp_path / "deep.toml"))
    assert loaded == g and loaded.depth == n + 1
    (root,) = build_graph(loaded)
    assert sum(1 for _ in root.walk()) == n + 1
    big = tmp_path / "big.toml"
    big.write_text(GOOD.replace("translate = [0, 0, 1]", "array = { count = [1024, 1024, 1] }")
                   .replace('children = ["leaf"]', 'children = ["leaf", "leaf", "leaf"]'))
    with pytest.raises(SceneError, match=r"big\.toml: graph\.roots: 'r' draws more than 2097152 mesh instances"):
        load_graph(big)
    big.write_text(GOOD.replace("translate = [0, 0, 1]", 'grid = { deformation = "d", cells = [400, 400, 400] }')
                   + '[deformations.d]\nkind = "twist"\nrate = 1.0\n')
    with pytest.raises(SceneError, match=r"nodes\.r\.grid\.cells: 64481201 lattice points, at most 4194304"):
        load_graph(big)



NESTED = """
[graph]
roots = ["r"]
[meshes.m]
shape = "sphere"
radius = 1.0
[nodes.r]
array = { count = [1024, 1024, 1], step = [1, 0, 0] }
children = ["a"]
[nodes.a]
array = { count = [1024, 1024, 1], step = [0, 1, 0] }
children = ["below"]
"""
#: What is below the two arrays: a subtree with no mesh (nothing to draw), or a mesh.
EMPTY_BELOW = '[nodes.below]\nchildren = ["none"]\n[nodes.none]\nchildren = []\n'
MESH_BELOW = '[nodes.below]\nmesh = "m"\n'


@pytest.mark.parametrize("below, message", [
    (EMPTY_BELOW, r"graph\.roots: 'r' expands to more than 8388608 node instances \(each node counted"),
    (MESH_BELOW, r"graph\.roots: 'r' draws more than 2097152 mesh instances$"),
], ids=["no-mesh", "mesh"])
def test_nested_arrays_are_refused_before_anything_is_expanded(tmp_path, monkeypatch, below, message):
    """Two nested 1024 x 1024 arrays (10^12 instances), with or without a mesh to draw, are
    counted on the file's nodes and refused in one line without building a node (over the
    subtree with no mesh this ran for more than 60 s before the expansion was counted)."""
    import time

    from deformgl.errors import InputError
    from deformgl.trilinear import graphbuild

    built: list[str] = []
    original = graphbuild._Builder.node

    def counting(self, name, colour):
        built.append(name)
        return original(self, name, colour)

    monkeypatch.setattr(graphbuild._Builder, "node", counting)
    path = tmp_path / "nested.toml"
    path.write_text(NESTED + below)
    start = time.perf_counter()
    with pytest.raises(SceneError, match=rf"^{re.escape(str(path))}: {message}") as err:
        load_graph(path)
    assert "\n" not in str(err.value)
    arrays = {name: NodeSpec(GraphTransform("array", count=(1024, 1024, 1)), [child])
              for name, child in (("r", "a"), ("a", "below"))}
    below_nodes = ({"below": NodeSpec(mesh="m")} if below == MESH_BELOW else
                   {"below": NodeSpec(None, ["none"]), "none": NodeSpec(None, [])})
    graph = SceneGraph(roots=["r"], meshes={"m": GraphMesh("sphere", {"radius": 1.0})}, nodes=arrays | below_nodes)
    with pytest.raises(InputError, match=message):  # the same graph in Python: refused before the builder runs
        graphbuild.compose_graph(graph, tmp_path)
    assert built == []
    assert time.perf_counter() - start < 5.0  # a hang guard, not a benchmark (about 10 ms)


def test_an_array_over_an_empty_group_within_the_limit_builds(tmp_path):
    """The count is of node instances, a mesh below or not: 1 + 4 x (1 + 2) fits, builds, draws nothing."""
    g = SceneGraph(roots=["r"], nodes={"r": NodeSpec(GraphTransform("array", count=(2, 2, 1)), ["g"]),
                                       "g": NodeSpec(None, ["e"]), "e": NodeSpec(None, [])})
    (root,) = build_graph(load_graph(save_graph(g, tmp_path / "empty.toml")))
    assert sum(1 for _ in root.walk()) == 1 + 4 * (1 + 2)
    assert compose_scene(root).batches == []


# ---- lattice files (issue 42, defect 5) --------------------------------------------------------------
LATTICE_GRAPH = """[graph]
roots = ["r"]
[view]
size = [64, 48]
samples = 0
[meshes.s]
shape = "sphere"
radius = 0.8
segments = 12
rings = 8
[nodes.r]
grid = { file = "lat.npy", box = { lo = [-1, -1, -1], hi = [1, 1, 1] } }
children = ["m"]
[nodes.m]
mesh = "s"
"""


def identity_lattice() -> np.ndarray:
    """The 3 x 3 x 3 identity lattice over the box [-1, 1]^3 of :data:`LATTICE_GRAPH`."""
    return np.stack(np.meshgrid(*[np.linspace(-1.0, 1.0, 3)] * 3, indexing="ij"), -1)


def _changed(value, dtype=np.float64, at=(2, 2, 2, 0)) -> np.ndarray:
    a = identity_lattice().astype(dtype)
    a[at] = value
    return a


def _npz_as_npy(path: Path) -> None:
    with open(path, "wb") as f:
        np.savez(f, a=identity_lattice())


def _bytes(data: bytes):
    return lambda path: path.write_bytes(data)


def _saved(array, **kw):
    return lambda path: np.save(path, array, **kw)


def _good_bytes() -> bytes:
    import io
    buf = io.BytesIO()
    np.save(buf, identity_lattice())
    return buf.getvalue()


BAD_LATTICES = {
    # the cases: beyond float32 (rendered blank), 1e300 and complex (rendered as no grid),
    # an .npz under a .npy name (an internal error), an object array (the prefix said twice)
    "beyond-float32": (_saved(_changed(1e39)), r"lattice point \[2, 2, 2\] has x = 1e\+39, beyond float32"),
    "1e300": (_saved(_changed(1e300)), r"lattice point \[2, 2, 2\] has x = 1e\+300, beyond float32"),
    "complex": (_saved(_changed(1 + 1j, complex)), r"must hold real numbers .*got dtype complex128"),
    "npz-as-npy": (_npz_as_npy, r"must be a \.npy array, got a \.npz archive"),
    "object": (_saved(identity_lattice().astype(object), allow_pickle=True), r"got dtype object"),
    "too-far": (_saved(_changed(3e6)), r"lattice point \[2, 2, 2\] has x = 3e\+06, more than 1e\+06 box sizes"),
    "nan": (_saved(_changed(np.nan, at=(0, 1, 2, 1))), r"lattice point \[0, 1, 2\] has a non-finite y \(nan\)"),
    "inf-float16": (_saved(_changed(np.inf, np.float16)), r"lattice point \[2, 2, 2\] has a non-finite x \(inf\)"),
    "bool": (_saved(identity_lattice() > 0), r"got dtype bool"),
    "strings": (_saved(identity_lattice().astype(str)), r"got dtype <U32"),
    "records": (_saved(np.zeros((3, 3, 3, 3), dtype=[("a", "f8")])), r"must hold real numbers"),
    "flat": (_saved(identity_lattice()[:, :, :1]), r"shape \(nx\+1, ny\+1, nz\+1, 3\) .*got \(3, 3, 1, 3\)"),
    "2d": (_saved(np.zeros((4, 3))), r"got \(4, 3\)"),
    "xy-only": (_saved(identity_lattice()[..., :2]), r"got \(3, 3, 3, 2\)"),
    "empty": (_bytes(b""), r"must be a \.npy array, got an empty file"),
    "text": (_bytes(b"1 2 3\n4 5 6\n"), r"must be a \.npy array, got something else"),
    "truncated": (_bytes(_good_bytes()[:-5]), r"truncated: its header declares \(3, 3, 3, 3\) float64 \(648 bytes\), the file holds 643"),
    "header-only": (_bytes(_good_bytes()[:20]), r"not a valid \.npy file"),
    "two-arrays": (_bytes(_good_bytes() * 2), r"bytes after its \(3, 3, 3, 3\) float64 array"),
}


@pytest.mark.parametrize("name", BAD_LATTICES)
def test_a_bad_lattice_file_is_one_line_naming_the_file_key_and_lattice(tmp_path, name):
    """Refused when the graph is built (before any GL work), one line, the prefix said once."""
    write, message = BAD_LATTICES[name]
    write(tmp_path / "lat.npy")
    path = _write(tmp_path, LATTICE_GRAPH)
    with pytest.raises(SceneError, match=rf"^{re.escape(str(path))}: nodes\.r\.grid\.file: 'lat\.npy': .*{message}") as e:
        build_graph(load_graph(path), tmp_path, file=str(path))
    text = str(e.value)
    assert "\n" not in text and text.count(str(path)) == 1, text


@pytest.mark.parametrize("where, message", [("lat.npy/", "a directory"), ("none.npy", "file not found")])
def test_a_lattice_that_is_not_a_file_is_named(tmp_path, where, message):
    (tmp_path / "lat.npy").mkdir()
    path = _write(tmp_path, LATTICE_GRAPH.replace('"lat.npy"', f'"{where}"'))
    with pytest.raises(SceneError, match=rf"nodes\.r\.grid\.file: cannot read '{re.escape(where)}': {message}"):
        build_graph(load_graph(path), tmp_path, file=str(path))


@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.float16, np.int32, np.uint8, ">f8"])
def test_a_lattice_of_any_real_dtype_is_its_float64_values(tmp_path, dtype):
    lattice = identity_lattice() + 1.0  # (>= 0, for uint8)
    lattice[2, 2, 2, 0] = 5.0
    np.save(tmp_path / "lat.npy", lattice.astype(dtype))
    path = _write(tmp_path, LATTICE_GRAPH)
    (root,) = build_graph(load_graph(path), tmp_path, file=str(path))
    assert np.array_equal(root.transform.points, lattice)


def test_a_far_lattice_point_is_not_judged_linear_away():
    """1e300 overflowed the linearity test's norms to inf (inf <= inf: 'linear'), so the grid was
    drawn as the affine map of three edges, without the changed corner: now refused as beyond
    float32, as every value that would be infinite on the GPU."""
    from deformgl.errors import InputError
    from deformgl.trilinear.cuboid import Box

    box = Box(-np.ones(3), np.ones(3))
    with pytest.raises(InputError, match=r"within float32 .*got 1e\+300"):
        Trilinear(box, _changed(1e300))
    grid = Trilinear(box, _changed(1e30))  # within float32: the changed corner keeps the grid trilinear
    assert not grid.is_linear()
    from deformgl.trilinear.shapes import uv_sphere

    (scene_batch,) = compose_scene(TransformNode(grid, [GeometryNode(uv_sphere(0.8, 12, 8, "s"))])).batches
    assert scene_batch.path == "grid"


def test_a_grid_over_its_content_with_no_children_is_named(tmp_path):
    """Found by tests/test_fuzz_graph.py (a mutation deleted a grid node's children): the box
    "content" spanned nothing, an internal ValueError; now one line naming the node."""
    text = LATTICE_GRAPH.replace('grid = { file = "lat.npy", box = { lo = [-1, -1, -1], hi = [1, 1, 1] } }\nchildren = ["m"]',
                                 'grid = { deformation = "d", cells = [2, 2, 2] }')
    path = _write(tmp_path, text + '[deformations.d]\nkind = "twist"\nrate = 1.0\n')
    with pytest.raises(SceneError, match=rf"^{re.escape(str(path))}: nodes\.r: has no content \(no mesh below it\)"):
        build_graph(load_graph(path), tmp_path, file=str(path))
