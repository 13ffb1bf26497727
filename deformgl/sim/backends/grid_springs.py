"""The springs of a grid system as the fragment backend stores them: neighbour columns (the 18
of Mosegaard & Sørensen 2005, section 3.1, then the 6 flexion neighbours of Movania & Feng 2012,
section 3), one stiffness, rest length and damping per class, and per-spring weights of the
class's stiffness where the springs of a class differ (the calibrated lattice of
:mod:`deformgl.sim.materials`)."""

from __future__ import annotations

import numpy as np

from deformgl.errors import GLError
from deformgl.grid.neighbours import grid_neighbours
from deformgl.grid.nodes import CompactLayout, NodeGrid
from deformgl.sim.springs import FLEXION, SHEAR, STRUCTURAL, SpringSystem

__all__ = ["check_topology", "class_values", "compact_layout", "grid_springs",
           "spring_weights", "weight_layers", "weight_levels"]

def class_values(system: SpringSystem, cls: int, name: str) -> tuple[float, float, float]:
    """(k, rest length, damping) of a class: the largest stiffness of the class, its one rest
    length, and the damping that goes with k (a spring of weight w = k_s / k must have the
    damping w c: the ratio c_s / k_s is one value per class); zeros if absent."""
    sel = system.spring_class == cls
    if not np.any(sel):
        return 0.0, 0.0, 0.0
    rest = system.rest_length[sel]
    if np.ptp(rest) > 1e-9 * max(abs(float(rest.mean())), 1e-300):
        raise ValueError(f"FragmentIntegrator: {name} springs need one rest_length "
                         f"(a springs.from_grid system)")
    stiffness, damping = system.stiffness[sel], system.damping[sel]
    k = float(stiffness.max())
    if k > 0:
        c = float(damping[np.argmax(stiffness)])
        expected = c * stiffness / k
    else:
        c, expected = float(damping.mean()), np.full(len(damping), float(damping.mean()))
    if np.any(np.abs(damping - expected) > 1e-9 * max(float(np.abs(damping).max()), 1e-300)):
        raise ValueError(f"FragmentIntegrator: {name} springs need spring damping in proportion "
                         f"to their stiffness (one c_s / k_s per class)")
    return k, float(rest.mean()), c


def spring_weights(system: SpringSystem, nb: np.ndarray, class_k: list[float]) -> np.ndarray | None:
    """(N, columns of ``nb``) float64 weight of the spring to each neighbour (its stiffness over
    its class's k; 0 where no spring), or None when every spring has its class's k."""
    col_class = np.array([STRUCTURAL] * 6 + [SHEAR] * 12 + [FLEXION] * (nb.shape[1] - 18))
    k_of = np.asarray(class_k, np.float64)
    k_spring = k_of[system.spring_class]
    w_spring = np.divide(system.stiffness, k_spring, out=np.zeros(system.spring_count), where=k_spring > 0)
    if np.all(w_spring == 1.0):
        return None
    n = system.count
    rows, cols = np.nonzero(nb >= 0)
    keys = rows.astype(np.int64) * n + nb[rows, cols].astype(np.int64) + \
        col_class[cols].astype(np.int64) * n * n  # (node, other, class): flexion and edges differ
    order = np.argsort(keys)
    keys = keys[order]
    weights = np.zeros(nb.shape, np.float64)
    cls = system.spring_class.astype(np.int64)
    for a, b in ((system.i, system.j), (system.j, system.i)):
        want = a * n + b + cls * n * n
        at = np.searchsorted(keys, want)
        if np.any(at >= len(keys)) or np.any(keys[np.minimum(at, len(keys) - 1)] != want):
            raise ValueError("FragmentIntegrator: the system's springs are not those of the grid")
        weights[rows[order[at]], cols[order[at]]] = w_spring
    return weights


def check_topology(system: SpringSystem, grid: NodeGrid, nb: np.ndarray) -> None:
    """The system's springs must be exactly the grid's springs of the classes it has."""
    n = grid.count
    if system.count != n:
        raise ValueError(f"FragmentIntegrator: system has {system.count} nodes, grid {n}")
    own = np.arange(n)[:, None]
    col_class = np.array([STRUCTURAL] * 6 + [SHEAR] * 12 + [FLEXION] * (nb.shape[1] - 18))
    for cls in (STRUCTURAL, SHEAR, FLEXION):
        rows, cols = np.nonzero((nb > own) & (col_class[None, :] == cls))
        expected = np.sort(rows * n + nb[rows, cols])
        sel = system.spring_class == cls
        if not np.any(sel):
            continue
        a, b = np.minimum(system.i[sel], system.j[sel]), np.maximum(system.i[sel], system.j[sel])
        if not np.array_equal(np.sort(a * n + b), expected):
            raise ValueError("FragmentIntegrator: the system's springs are not those of the grid "
                             "(build it with springs.from_grid or springs.cloth on this grid)")


def grid_springs(system: SpringSystem, grid: NodeGrid) -> tuple[bool, np.ndarray, list[tuple[float, float, float]]]:
    """(flexion, neighbour table, class values) of a system on its grid, as every fragment-pass
    solver reads them: whether it has flexion springs, :func:`grid_neighbours` (checked against
    the system's springs by :func:`check_topology`) and :func:`class_values` of the structural,
    shear and flexion classes. A physics term that reads the 24 neighbours (``Term.neighbours``) puts the flexion neighbours in the table too."""
    flexion = bool(np.any(system.spring_class == FLEXION)) or any(t.neighbours == 24 for t in system.terms)
    nb = grid_neighbours(grid, flexion)
    check_topology(system, grid, nb)
    classes = [class_values(system, c, name) for c, name in
               ((STRUCTURAL, "structural"), (SHEAR, "shear"), (FLEXION, "flexion"))]
    return flexion, nb, classes


def compact_layout(grid: NodeGrid, max_texture_size: int) -> CompactLayout:
    """The grid's compact layout, or a GLError when it does not fit a texture."""
    try:
        return CompactLayout.for_grid(grid, max_texture_size)
    except ValueError as exc:
        raise GLError(f"{exc}; use a coarser grid") from None


def weight_levels(weights: np.ndarray, mask: np.ndarray) -> np.ndarray | None:
    """(N,) int64 levels code of ``weights`` (N, 18) when every spring's weight is a cell share of
    the calibrated lattice (:func:`deformgl.sim.materials.lattice_system`): an edge (columns 0-5)
    1, 2, 3 or 4 quarters, a face diagonal (6-17) 1 or 2 halves, and 0 exactly where ``mask``
    (the grid's neighbour bits) has no neighbour; else None. Edge j's quarters - 1 go to bits
    2j..2j+1, diagonal j's halves - 1 to bit 6 + j: 24 bits, exact in the float32 alpha of the node
    texture, decoded by SPRING_WEIGHT_LEVELS (shaders/lib/springs.glsl) in place of five fetches of
    a weight texture per node."""
    # (in float32, as the weight texture would hold them: a share of 3 k / 4 over k can be an ulp
    # off 0.75 in float64)
    w = np.asarray(weights, np.float64).astype(np.float32).astype(np.float64)
    present = ((np.asarray(mask, np.int64)[:, None] >> np.arange(18)) & 1).astype(bool)
    units = np.where(np.arange(18) < 6, 4.0, 2.0)
    shares = w * units
    steps = np.rint(shares)
    if np.any(w[~present] != 0.0) or np.any(steps != shares) or \
            np.any(present & ((steps < 1) | (steps > units))):
        return None
    code = np.where(present, steps - 1, 0).astype(np.int64)
    shift = np.where(np.arange(18) < 6, 2 * np.arange(18), 6 + np.arange(18))
    return np.bitwise_or.reduce(code << shift, axis=1)


def weight_layers(weights: np.ndarray) -> list[np.ndarray]:
    """The 5 layers of a weight texture: (N, 4) each, the weights (N, 18) of neighbours 4l .. 4l + 3
    (neighbours 18, 19 of the last layer 0)."""
    padded = np.zeros((len(weights), 20))
    padded[:, :18] = weights
    return [padded[:, 4 * i: 4 * i + 4] for i in range(5)]
