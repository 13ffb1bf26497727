"""The cells' volumetric term (:mod:`deformgl.sim.terms.volume.energy`) as XPBD constraints (Macklin, Müller &
Chentanez 2016): the term's XPBD form in float64 (:class:`CellConstraints`, a
:class:`~deformgl.sim.terms.constraints.TermConstraints`), the reference of its GPU passes
(:class:`~deformgl.sim.terms.volume.cell_xpbd.XpbdCells`: the cell pass
``shaders/terms/cell_xpbd.frag`` and the node sweep's chunk ``shaders/terms/cell_xpbd.glsl``).

Per full cell of rest volume ``V = h^3`` (:class:`~deformgl.sim.terms.volume.energy.CellVolumes`):

* **volume constraint** (only where ``kappa > 0``): ``C = J - 1``, J = det F at the cell centre,
  compliance ``alpha = 1 / (kappa V)``; its potential ``1/2 alpha^-1 C^2`` (Macklin, Müller &
  Chentanez 2016, eq. 2) is the centre term ``V kappa/2 (J - 1)^2``. ``grad_a C = cof(F) G_a``,
  ``G_a = s_a / (4h)`` (1/m);
* **barrier constraint** per cell corner c (only where ``kappa_b > 0``): the inequality
  ``C = J_c - J_b >= 0`` on the corner's tet (the corner c and its neighbours c ^ 1, c ^ 2,
  c ^ 4 in the cell), compliance ``alpha = 1 / (kappa_b V / 8)``. Its multiplier is kept
  ``>= 0`` (projected Jacobi): at convergence ``lambda = max(0, -C / alpha~)``, so the constraint
  stores ``V/8 kappa_b/2 (J_b - J_c)^2`` exactly where ``J_c < J_b`` and nothing elsewhere, the
  corner barrier of :func:`~deformgl.sim.terms.volume.energy.volume_energy`.

Together with the spring constraints of :mod:`deformgl.sim.xpbd` the constraint potential is the
energy whose negative gradient :func:`deformgl.sim.springs.forces` evaluates, so XPBD's fixed
point is the same static equilibrium. Neither term is damped (as in :mod:`deformgl.sim.terms.volume.energy`).

The Jacobi step of each constraint is that of the springs (Macklin, Müller & Chentanez 2016,
eq. 17-18, ``alpha~ = alpha / h^2`` of eq. 4), relaxed by omega and by ``n_s``, the largest
constraint count of its nodes::

    d_lambda = -omega (C + alpha~ lambda) / (n_s sum_a w_a |grad_a C|^2 + alpha~)
    x_a += w_a grad_a C d_lambda

(barrier: ``lambda' = max(lambda + d_lambda, 0)`` and ``d_lambda = lambda' - lambda``). With
``n_s`` at least the number of constraints at every node of the constraint, Cauchy-Schwarz gives
``y^T J W J^T y <= sum_s y_s^2 n_s sum_a w_a |grad_a C_s|^2`` for gradients of any size, so the
relaxed diagonal bounds the linearised system and the sweep converges for 0 < omega < 2, as for
the springs alone. A node's count is its springs and drags, its volume constraints (8 per
interior node where kappa > 0) and its *active* barriers: the corner tets at the node whose
multiplier is > 0 after the previous sweep (:meth:`CellConstraints.barrier_counts`; none at a
substep's start). Counting every potential barrier (up to 32 per node) instead would slow every
sweep about threefold for a term that acts only near inversion. The price: a barrier that
switches on during a sweep is counted only from the next one, so for that one sweep the bound
above may not hold at its nodes (the sweep may overshoot there; the next is bounded again). The
tests' inverted blocks recover (tests/test_cells_xpbd.py); the convergence claim holds for sweeps
whose active set does not change.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from deformgl.grid.nodes import NodeGrid
from deformgl.sim.terms.constraints import TermConstraints, XpbdChunk
from deformgl.sim.terms.volume.energy import CORNER_SIGNS, CellVolumes, cell_state

if TYPE_CHECKING:
    import moderngl

    from deformgl.grid.nodes import CompactLayout
    from deformgl.sim.terms.volume.cell_xpbd import XpbdCells

__all__ = ["CellConstraints", "TET_NODES", "XPBD", "chunk"]


def chunk(volume: bool, barrier: bool) -> XpbdChunk:
    """The term's XPBD chunk and cell pass with these constraints (kappa > 0, kappa_b > 0)."""
    return XpbdChunk("cell", "terms/cell_xpbd.glsl", ("terms/cell_xpbd.frag",),
                     {"CELL_VOLUME": volume, "CELL_BARRIER": barrier},
                     ({"CELL_VOLUME": False, "CELL_BARRIER": True}, {"CELL_VOLUME": True, "CELL_BARRIER": False},
                      {"CELL_VOLUME": True, "CELL_BARRIER": True}))


#: The XPBD chunk without instance data (the shipped list; ``variants``: the (volume, barrier)
#: combinations a system's cells can have; not neither, then there are no cell constraints).
XPBD = chunk(True, True)

#: (8, 4) the tet of corner c: the corner, then its neighbours along x, y, z (c ^ 1, c ^ 2, c ^ 4).
TET_NODES = np.array([[c, c ^ 1, c ^ 2, c ^ 4] for c in range(8)], dtype=np.int64)


class CellConstraints(TermConstraints):
    """The volume and barrier constraints of a system's full cells in the XPBD Jacobi sweep. Its
    multipliers: ((C,) volume, (C, 8) barrier).

    Args:
        cells: the cells (``SpringSystem.cells``).
        inverse_mass: (N,) 1/kg, 0 at fixed nodes.

    Attributes:
        volume: whether the volume constraints exist (kappa > 0).
        barrier: whether the barrier constraints exist (kappa_b > 0).
    """

    def __init__(self, cells: CellVolumes, inverse_mass: np.ndarray) -> None:
        self.cells = cells
        self.w = np.asarray(inverse_mass, np.float64)
        self.count = len(self.w)
        self.volume = cells.volume_modulus > 0 and cells.count > 0
        self.barrier = cells.barrier_modulus > 0 and cells.count > 0
        self._g = CORNER_SIGNS / (4.0 * cells.spacing)           # (8, 3) G_a, 1/m
        self._tets = cells.corners[:, TET_NODES]                  # (C, 8, 4) node numbers
        self._edge_scale = -CORNER_SIGNS / cells.spacing          # (8, 3): edge k of corner c is -s_c[k] / h

    def static_counts(self) -> np.ndarray:
        """:meth:`volume_counts`."""
        return self.volume_counts()

    def start(self) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`zeros`."""
        return self.zeros()

    def dynamic_counts(self, multipliers: object) -> np.ndarray | None:
        """The active barriers (:meth:`barrier_counts`), or None without barriers."""
        if not self.barrier:
            return None
        _, lam_barrier = _pair(multipliers)
        return self.barrier_counts(lam_barrier)

    def gpu(self, ctx: moderngl.Context, grid: NodeGrid, layout: CompactLayout, omega: float,
            first_unit: int) -> XpbdCells:
        """:class:`~deformgl.sim.terms.volume.cell_xpbd.XpbdCells` (imported here: the float64 form
        needs no GL)."""
        from deformgl.sim.terms.volume.cell_xpbd import XpbdCells

        return XpbdCells(ctx, grid, layout, self.cells, chunk(self.volume, self.barrier), omega, first_unit)

    def volume_counts(self) -> np.ndarray:
        """(N,) float64 volume constraints at each node (0 everywhere where kappa = 0)."""
        if not self.volume:
            return np.zeros(self.count)
        return np.bincount(self.cells.corners.reshape(-1), minlength=self.count).astype(np.float64)

    def barrier_counts(self, lam_barrier: np.ndarray) -> np.ndarray:
        """(N,) float64 active barriers at each node: corner tets at it with lambda > 0."""
        if not self.barrier:
            return np.zeros(self.count)
        active = np.broadcast_to((lam_barrier > 0)[:, :, None], self._tets.shape)
        return np.bincount(self._tets[active], minlength=self.count).astype(np.float64)

    def zeros(self) -> tuple[np.ndarray, np.ndarray]:
        """Multipliers at a substep's start: ((C,) volume, (C, 8) barrier), all 0."""
        return np.zeros(self.cells.count), np.zeros((self.cells.count, 8))

    def compliances(self, h: float) -> tuple[float, float]:
        """alpha~ = alpha / h^2 of a volume and of a barrier constraint (inf where absent), for
        a substep of h seconds."""
        v = self.cells.volume
        at_v = 1.0 / (self.cells.volume_modulus * v * h * h) if self.volume else np.inf
        at_b = 1.0 / (self.cells.barrier_modulus * v / 8.0 * h * h) if self.barrier else np.inf
        return float(at_v), float(at_b)

    def _edges(self, p: np.ndarray) -> np.ndarray:
        """(C, 3 axes, 4, 3) the cells' edges over h, along +x, +y, +z: corner c's edge e_k of
        :func:`~deformgl.sim.terms.volume.energy.corner_jacobians` (``(x_(c ^ 2^k) - x_c) (-s_c[k]) / h``)
        is edge ``_EDGE_OF[c, k]`` of axis k, the same vector for c and c ^ 2^k."""
        xc = p[self.cells.corners]                                               # (C, 8, 3)
        e = np.empty((len(xc), 3, 4, 3))
        for k in range(3):
            e[:, k] = xc[:, _UPPER[k]] - xc[:, _LOWER[k]]
        e *= 1.0 / self.cells.spacing
        return e

    def corner_dets(self, p: np.ndarray) -> np.ndarray:
        """(C, 8) J_c = det F_c at every corner (:func:`~deformgl.sim.terms.volume.energy.corner_jacobians`'
        det, without its gradients)."""
        e = self._edges(p)
        return _det(e[:, 0, _EDGE_OF[:, 0]], e[:, 1, _EDGE_OF[:, 1]], e[:, 2, _EDGE_OF[:, 2]])

    def _barrier_gradients(self, p: np.ndarray, rows: tuple[np.ndarray, ...]) -> np.ndarray:
        """dJ_c/dx of the 4 nodes of the tets ``rows`` (K, 4, 3), in the order of TET_NODES."""
        cell, corner = rows
        e = self._edges(p)[cell]                                                 # (K, 3, 4, 3)
        k = np.arange(len(cell))
        e0, e1, e2 = (e[k, axis, _EDGE_OF[corner, axis]] for axis in range(3))
        g = np.stack([np.cross(e1, e2), np.cross(e2, e0), np.cross(e0, e1)], axis=1)  # d det / d e_k
        g *= self._edge_scale[corner][:, :, None]                                # d det / d x of c ^ 2^k
        tet = np.empty((len(g), 4, 3))
        tet[:, 0] = -g.sum(axis=1)
        tet[:, 1:] = g
        return tet

    def sweep(self, p: np.ndarray, multipliers: object, counts: np.ndarray, h: float, omega: float) -> np.ndarray:
        """One Jacobi sweep of every cell constraint at the iterate ``p`` (N, 3): updates the
        multipliers in place and returns the (N, 3) position corrections.

        Args:
            p: the iterate, m.
            multipliers: ((C,) the volume multipliers, (C, 8) the barrier multipliers (>= 0)).
            counts: (N,) the constraint count n_a of every node in this sweep.
            h: the substep, s.
            omega: the relaxation.
        """
        lam_volume, lam_barrier = _pair(multipliers)
        dx = np.zeros((self.count, 3))
        corners = self.cells.corners
        at_v, at_b = self.compliances(h)
        if self.volume:
            j, cof = cell_state(self.cells, p)
            grad = np.einsum("cij,aj->cai", cof, self._g)                       # (C, 8, 3)
            mass = np.einsum("ca,cai,cai->c", self.w[corners], grad, grad)
            n_s = counts[corners].max(axis=1)
            dl = -omega * (j - 1.0 + at_v * lam_volume) / (n_s * mass + at_v)
            lam_volume += dl
            _scatter(dx, corners, (self.w[corners] * dl[:, None])[:, :, None] * grad)
        if self.barrier:
            det = self.corner_dets(p)
            # only a violated or a loaded barrier can change: elsewhere lambda = 0 stays 0
            live = (det < self.cells.barrier_j) | (lam_barrier > 0)
            if live.any():
                rows = np.nonzero(live)
                grad = self._barrier_gradients(p, rows)                          # (K, 4, 3)
                nodes = self._tets[rows]                                         # (K, 4)
                w = self.w[nodes]
                mass = np.einsum("kt,kti,kti->k", w, grad, grad)
                n_s = counts[nodes].max(axis=1)
                lam = lam_barrier[rows]
                dl = -omega * (det[rows] - self.cells.barrier_j + at_b * lam) / (n_s * mass + at_b)
                new = np.maximum(lam + dl, 0.0)
                lam_barrier[rows] = new
                _scatter(dx, nodes, (w * (new - lam)[:, None])[:, :, None] * grad)
        return dx

    def residual_terms(self, p: np.ndarray, multipliers: object, h: float) -> tuple[np.ndarray, np.ndarray]:
        """(C, alpha~ lambda) of every cell constraint at ``p``, in metres (times the spacing h,
        so they join the springs' ``|C + alpha~ lambda| / |C|``): the volume constraints', and
        the barriers' where active (lambda > 0) or violated (C < 0), 0 elsewhere."""
        lam_volume, lam_barrier = _pair(multipliers)
        s = self.cells.spacing
        at_v, at_b = self.compliances(h)
        c_parts, l_parts = [np.zeros(0)], [np.zeros(0)]
        if self.volume:
            j, _ = cell_state(self.cells, p)
            c_parts.append(s * (j - 1.0))
            l_parts.append(s * at_v * lam_volume)
        if self.barrier:
            c = self.corner_dets(p) - self.cells.barrier_j
            counted = (lam_barrier > 0) | (c < 0)
            c_parts.append(s * np.where(counted, c, 0.0).reshape(-1))
            l_parts.append(s * at_b * lam_barrier.reshape(-1))
        return np.concatenate(c_parts), np.concatenate(l_parts)


#: per axis k, the cell's 4 edges along +k: from corner _LOWER[k][m] (bit k 0) to _UPPER[k][m].
_LOWER = [np.array([c for c in range(8) if not c >> k & 1]) for k in range(3)]
_UPPER = [lower | (1 << k) for k, lower in enumerate(_LOWER)]
#: (8, 3) the edge of axis k at corner c: the m with c in (_LOWER[k][m], _UPPER[k][m]).
_EDGE_OF = np.array([[int(np.nonzero(_LOWER[k] == (c & ~(1 << k)))[0][0]) for k in range(3)]
                     for c in range(8)])


def _pair(multipliers: object) -> tuple[np.ndarray, np.ndarray]:
    """The (volume, barrier) multiplier arrays of :meth:`CellConstraints.start`."""
    if not (isinstance(multipliers, tuple) and len(multipliers) == 2):
        raise TypeError("CellConstraints: multipliers must be the (volume, barrier) pair of start()")
    return multipliers[0], multipliers[1]


def _det(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """a . (b x c) over the last axis."""
    return (a[..., 0] * (b[..., 1] * c[..., 2] - b[..., 2] * c[..., 1])
            + a[..., 1] * (b[..., 2] * c[..., 0] - b[..., 0] * c[..., 2])
            + a[..., 2] * (b[..., 0] * c[..., 1] - b[..., 1] * c[..., 0]))


def _scatter(out: np.ndarray, nodes: np.ndarray, values: np.ndarray) -> None:
    """out[nodes] += values, summed over repeated nodes (``values``: nodes.shape + (3,))."""
    flat = nodes.reshape(-1)
    vals = values.reshape(-1, 3)
    for k in range(3):
        out[:, k] += np.bincount(flat, weights=vals[:, k], minlength=len(out))
