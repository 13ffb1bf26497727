"""Tubes attached to the deforming detailed mesh (Knuth et al. section 5 on Mosegaard's mapping)."""

from pathlib import Path

import numpy as np
import pytest

from deformgl.trilinear.attachments import TubeAttachment
from deformgl.errors import SceneError
from deformgl.mapping.node_drivers import Motion, rotate
from deformgl.scene.schema import load_scene
from deformgl.trilinear.renderer import TrilinearRenderer

SCENES = Path(__file__).resolve().parent.parent / "scenes"


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DEFORMGL_CACHE_DIR", str(tmp_path / "cache"))


@pytest.fixture
def setup(ctx):
    import sys
    sys.path.insert(0, str(Path(__file__).parent))
    from test_mapping import Mapped

    m = Mapped(ctx, SCENES / "dragon_bend_auto.toml", "constant", 8)
    lo, hi = m.built.bbox
    tube = TubeAttachment.along(m.built.mesh.vertices, m.built.mesh.faces, lo + (hi - lo) * [0.4, 0.8, 0.5],
                                lo + (hi - lo) * [0.8, 0.7, 0.5], count=10, radius=0.004)
    renderer = TrilinearRenderer(ctx)
    yield m, tube, renderer
    renderer.release()
    m.release()


def tube_vertices(renderer, tube, mesh_vertices, faces):
    batches = renderer.capture(tube.compose(mesh_vertices, faces))
    return np.concatenate([p.reshape(-1, 3) for p, _ in batches]).astype(np.float64)


def test_tube_lies_on_the_rest_mesh(setup):
    m, tube, renderer = setup
    verts = tube_vertices(renderer, tube, m.built.mesh.vertices, m.built.mesh.faces)
    from scipy.spatial import cKDTree
    distance, _ = cKDTree(m.built.mesh.vertices).query(verts)
    # every tube vertex is within a tube diameter plus the anchor spacing's sag of the surface
    assert distance.max() < 4 * tube.radius + 0.02 * m.diag


def test_tube_follows_a_rigid_motion_of_the_deformed_mesh(setup):
    m, tube, renderer = setup
    motion = Motion("rigid", 50.0, axis=1, translate=(0.01, 0.02, -0.01))
    deformed, _ = m.gpu(motion.apply(m.rest, 1.0, m.bounds))   # the mapped mesh, from the GPU
    moved = tube_vertices(renderer, tube, deformed.astype(np.float64), m.built.mesh.faces)
    rest = tube_vertices(renderer, tube, m.built.mesh.vertices, m.built.mesh.faces)
    assert np.abs(moved - motion.apply(rest, 1.0, m.bounds)).max() <= 1e-4 * m.diag


@pytest.mark.parametrize("angle", [30.0, 60.0])
def test_tube_bends_with_the_mesh(ctx, setup, angle):
    m, _, renderer = setup
    lo, hi = m.built.bbox
    tube = TubeAttachment.along(m.built.mesh.vertices, m.built.mesh.faces, lo + (hi - lo) * [0.65, 0.7, 0.5],
                                lo + (hi - lo) * [0.95, 0.6, 0.5], count=10, radius=0.004)
    bend = Motion("bend", angle, along=0, towards=1)
    rest = tube_vertices(renderer, tube, m.built.mesh.vertices, m.built.mesh.faces)
    expected = bend.apply(rest, 1.0, m.bounds)
    displacement = np.abs(expected - rest).max()
    # on the exactly bent mesh the anchors carry the tube within 10 % of its displacement
    exact_mesh = bend.apply(m.built.mesh.vertices, 1.0, m.bounds)
    on_exact = tube_vertices(renderer, tube, exact_mesh, m.built.mesh.faces)
    assert np.abs(on_exact - expected).max() < 0.10 * displacement
    # on the mesh the GPU mapped from bent nodes, the mapping's own error adds (constant basis, 8 nodes)
    deformed, _ = m.gpu(bend.apply(m.rest, 1.0, m.bounds))
    on_mapped = tube_vertices(renderer, tube, deformed.astype(np.float64), m.built.mesh.faces)
    assert np.abs(on_mapped - expected).max() < 0.25 * displacement


def test_attach_needs_a_detailed_mapping(tmp_path):
    text = (SCENES / "jelly.toml").read_text().replace('path = "assets/', f'path = "{SCENES}/assets/')
    text += '\n[[attach]]\nfrom = [0.1, 1.0, 0.5]\nto = [0.9, 1.0, 0.5]\n'
    path = tmp_path / "j.toml"
    path.write_text(text)
    with pytest.raises(SceneError, match="attach: needs a detailed mesh"):
        load_scene(path)


def test_mapping_override_to_one_to_one_is_refused_with_attachments():
    scene = load_scene(SCENES / "dragon_heart_scale.toml")
    with pytest.raises(SceneError, match="--mapping: one-to-one draws no detailed mesh"):
        scene.with_overrides(mapping="one-to-one")


def test_anchors_ignore_zero_area_faces():
    import trimesh

    from deformgl.trilinear.anchors import locate_on_mesh

    box = trimesh.creation.box()
    faces = np.vstack([box.faces, [[0, 0, 1]]])  # one degenerate face anywhere in the mesh
    tri, bary = locate_on_mesh(box.vertices, faces, np.array([[0.5, 0.1, 0.2]]))
    assert tri[0] < len(box.faces) and np.isclose(bary.sum(), 1.0)
