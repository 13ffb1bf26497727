"""Node grid, 18-neighbour connectivity, the compact layout and the drawable surface. No GL needed."""

import numpy as np
import pytest
import trimesh

from deformgl.grid.nodes import NEIGHBOUR_OFFSETS, REST_LENGTH_UNITS, CompactLayout, NodeGrid
from deformgl.grid.surface import grid_surface


def make_grid(occ, spacing=0.5):
    return NodeGrid(np.array([1.0, 2.0, 3.0]), spacing, np.asarray(occ, bool))


def test_offsets_are_six_unit_and_twelve_face_diagonals():
    assert len({tuple(o) for o in NEIGHBOUR_OFFSETS}) == 18
    assert np.allclose(REST_LENGTH_UNITS[:6], 1.0) and np.allclose(REST_LENGTH_UNITS[6:], np.sqrt(2))
    assert not np.any(np.all(np.abs(NEIGHBOUR_OFFSETS) == 1, axis=1))  # no body diagonals


def test_interior_node_has_all_18_and_corner_has_6():
    g = make_grid(np.ones((3, 3, 3)))
    centre = g.index[1, 1, 1]
    corner = g.index[0, 0, 0]
    assert g.neighbour_mask[centre] == (1 << 18) - 1
    assert bin(int(g.neighbour_mask[corner])).count("1") == 6  # 3 structural + 3 shear


def test_neighbours_exist_only_where_nodes_exist():
    rng = np.random.default_rng(0)
    occ = rng.random((5, 4, 6)) < 0.6
    g = make_grid(occ)
    for j, off in enumerate(NEIGHBOUR_OFFSETS):
        nb = g.neighbours[:, j]
        has = nb >= 0
        assert np.array_equal(g.ijk[has] + off, g.ijk[nb[has]])
        q = g.ijk[~has] + off
        inside = np.all((q >= 0) & (q < occ.shape), axis=1)
        assert not np.any(occ[tuple(q[inside].T)])
        assert np.array_equal((g.neighbour_mask >> j) & 1, has.astype(np.uint32))


def test_springs_counted_once_with_rest_lengths():
    g = make_grid(np.ones((2, 2, 2)))
    # a 2x2x2 block: 12 structural edges + 12 face diagonals
    assert len(g.springs) == 24
    d = np.linalg.norm(g.rest_positions[g.springs[:, 0]] - g.rest_positions[g.springs[:, 1]], axis=1)
    assert np.isclose(d, 0.5).sum() == 12 and np.isclose(d, 0.5 * np.sqrt(2)).sum() == 12


def test_rest_positions_scale_with_spacing():
    g = make_grid(np.ones((2, 3, 4)), spacing=0.25)
    assert np.allclose(g.rest_positions[-1], [1.25, 2.5, 3.75])


def test_grid_data_is_immutable():
    g = make_grid(np.ones((2, 2, 2)))
    with pytest.raises(ValueError):
        g.occupied[0, 0, 0] = False


@pytest.mark.parametrize("shape", [(1, 1, 1), (5, 3, 7), (64, 64, 32), (200, 3, 1)])
def test_compact_layout_round_trip(shape):
    """Node n at texel (n % width, n // width), every node its own texel, values scattered and
    gathered back unchanged."""
    g = make_grid(np.ones(shape))
    layout = CompactLayout.for_grid(g, 16384)
    w, h = layout.size
    t = layout.texel(g.ijk)
    n = np.arange(g.count)
    np.testing.assert_array_equal(t, np.stack([n % w, n // w], axis=1))
    assert t[:, 1].max() < h and len(np.unique(t[:, 0] * h + t[:, 1])) == g.count
    values = np.arange(g.count * 4, dtype=np.float32).reshape(-1, 4)
    assert np.array_equal(layout.gather(g.ijk, layout.scatter(g.ijk, values)), values)


def test_compact_layout_too_large_is_an_error():
    with pytest.raises(ValueError, match="texture limit"):
        CompactLayout.for_grid(make_grid(np.ones((20, 20, 1))), 16)


def test_surface_of_block_is_closed_outward_box():
    g = make_grid(np.ones((4, 3, 5)), spacing=1.0)
    s = grid_surface(g)
    m = trimesh.Trimesh(g.rest_positions[s.nodes], s.triangles, process=False)
    assert m.is_watertight and m.is_winding_consistent
    assert np.isclose(m.volume, 3 * 2 * 4)  # positive: outward winding
    assert not s.sheet.any()
    assert len(s.nodes) == 4 * 3 * 5 - 2 * 1 * 3  # all but the interior nodes


def test_surface_of_sheet_and_of_l_shape():
    sheet = grid_surface(make_grid(np.ones((4, 1, 3))))
    assert sheet.sheet.all() and len(sheet.triangles) == 2 * 3 * 2
    occ = np.zeros((3, 3, 2), bool)
    occ[:, 0, :] = True
    occ[0, :, :] = True
    g = make_grid(occ, spacing=1.0)
    s = grid_surface(g)
    assert len(s.nodes) == g.count  # every node of an L of sheets is drawn
