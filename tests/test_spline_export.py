"""A spline scene's exports show the body (issue 44, item 4): ``--export-grid`` writes its knot
spans where the field puts them, ``--export-mesh`` the detailed mesh as drawn with the field's
velocity and strain; ``--pack-inputs`` (the lattice's mappings) stays refused in one line."""

from __future__ import annotations

import numpy as np
import pytest

from deformgl.render.bspline_premap import vertex_spans
from deformgl.scene.animation import frame_plan, render_frames
from deformgl.scene.schema import load_scene
from deformgl.scene.spline_fields import body_series, span_gradients, span_hexahedra, spline_mesh_series
from deformgl.sim.terms.spline.basis import span_basis
from test_spline_scene import cli, dragon


@pytest.fixture(scope="module")
def done(ctx, tmp_path_factory):
    """The spline dragon (12 along) falling under its held base: 3 frames 5 steps apart, its
    meshes and node states."""
    folder = tmp_path_factory.mktemp("spline_export")
    scene = load_scene(dragon(folder))
    plan = frame_plan(scene, frames=3, steps_per_frame=5)
    return plan, render_frames(ctx, scene, plan, mesh=True, nodes=True)


def test_the_body_is_its_spans_where_the_field_puts_them(done):
    plan, frames = done
    body = frames.model.spline
    series = body_series(frames, plan.fps)
    cells, rest, owner = span_hexahedra(body)
    assert series.cell_type == "hexahedron" and len(series.cells) == len(body.span_nodes)
    # every corner is one point: 8 per span, shared between spans
    assert len(rest) < 8 * len(body.span_nodes) and len(np.unique(cells)) == len(rest)
    h = body.spacing
    centres = body.grid.rest_positions[body.span_nodes[:, 13]]
    assert np.allclose(rest[cells].mean(axis=1), centres, atol=1e-12)  # a cube of side h about its node
    assert np.allclose(np.ptp(rest[cells], axis=1), h, atol=1e-12)
    for k, sample in enumerate(frames.nodes):
        # the field at each corner, from every span it is a corner of (C0: all agree)
        x = sample.x
        values = span_basis(np.array([[dx, dy, dz] for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)]) - 0.5, h)[0]
        at_corners = np.einsum("ja,sad->sjd", values, x[body.span_nodes])
        assert np.allclose(at_corners, (series.points[k] - frames.model.centre)[cells], atol=1e-9)
        assert np.allclose(series.point_data[k]["displacement"], series.points[k] - series.rest, atol=1e-12)
        f = span_gradients(body, x)
        assert np.allclose(series.cell_data[k]["volume_ratio"], np.linalg.det(f), rtol=1e-12)
        assert "velocity" in series.point_data[k]
    assert np.allclose(series.cell_data[0]["fill"], body.span_volume / h ** 3)
    assert np.all((series.cell_data[0]["fill"] > 0) & (series.cell_data[0]["fill"] <= 1 + 1e-9))
    assert np.allclose(series.cell_data[0]["volume_ratio"], 1.0, atol=1e-4)  # at rest (float32 positions)
    assert np.abs(series.point_data[-1]["displacement"]).max() > 1e-6  # it moves


def test_the_mesh_is_what_was_drawn_with_the_fields_velocity(done):
    plan, frames = done
    body = frames.model.spline
    series = spline_mesh_series(frames, plan.fps)
    rest = np.asarray(frames.model.mesh.vertices, np.float64)
    nodes, s = vertex_spans(body, rest)
    assert series.cell_type == "triangle" and len(series.points[0]) == len(rest)
    for k, ((v, _, _), sample) in enumerate(zip(frames.meshes, frames.nodes)):
        assert np.array_equal(series.points[k], np.asarray(v, np.float64))
        # the drawn vertices are the float64 field at the rest vertices (float32 on the GPU)
        values = span_basis(s, body.spacing)[0]
        field = np.einsum("va,vad->vd", values, sample.x[nodes]) + frames.model.centre
        assert np.abs(series.points[k] - field).max() < 1e-5 * np.ptp(rest, axis=0).max()
        assert np.allclose(series.point_data[k]["velocity"], np.einsum("va,vad->vd", values, sample.v[nodes]),
                           atol=1e-12)
        assert np.allclose(series.point_data[k]["displacement"], series.points[k] - rest - frames.model.centre)
        assert series.point_data[k]["green_strain"].shape == (len(rest), 9)


@pytest.mark.io
def test_the_cli_writes_the_body_and_the_mesh_and_refuses_pack_inputs(ctx, tmp_path, capsys):
    import meshio

    scene = dragon(tmp_path)
    code, _, err = cli(capsys, "render", scene, "-o", tmp_path / "x.png", "--export-grid", tmp_path / "g.vtu",
                       "--export-mesh", tmp_path / "m.vtu")
    assert code == 0, err
    grid = meshio.read(tmp_path / "g.vtu")
    assert grid.cells[0].type == "hexahedron" and {"volume_ratio", "green_strain", "fill"} <= set(grid.cell_data)
    mesh = meshio.read(tmp_path / "m.vtu")
    assert mesh.cells[0].type == "triangle" and {"displacement", "volume_ratio"} <= set(mesh.point_data)
    code, _, err = cli(capsys, "render", scene, "-o", tmp_path / "y.png", "--pack-inputs", tmp_path / "p.npz")
    assert code != 0 and err.count("\n") == 1 and '--pack-inputs is not written for material.model = "spline"' in err
    assert not (tmp_path / "y.png").exists()
