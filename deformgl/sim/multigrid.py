"""Geometric multigrid on the node grid: the V-cycle preconditioner of the implicit step's CG.

The step's matrix A (:func:`deformgl.sim.implicit.assemble`, over the free nodes) is the fine
level. Each coarser level has the grid nodes at twice the spacing (fine grid index 2I along every
axis with more than one node; a sheet stays one node thick), down to a grid of at most
:data:`COARSEST_NODES` nodes, which is solved exactly (its dense inverse):

* **Transfers.** Prolongation P_l is trilinear interpolation from the coarse nodes to the fine
  ones (a fine node at an odd index takes half of each coarse neighbour along that axis), the
  same weights on x, y and z; restriction is its transpose, R = P^T. A coarse node exists where
  some free fine node takes a share of it: the coarse grids cover the coarsened occupancy of
  any body (a mesh's filled cells, a ragged sheet), and a fixed node, which has no row in A,
  has no row in P either, so every level honours it (the coarse correction never moves it).
* **Coarse operators.** Galerkin products ``A_{l+1} = P^T A_l P`` of the start state's step
  matrix, kept for the run (:class:`Hierarchy`; every step smooths its finest level with its own
  matrix, so the cycle follows the body where it matters most, and a GPU step needs no
  assembly): on a 27-point node stencil
  with trilinear transfers the coarse operator is again a 27-point stencil (3x3 blocks), and it
  holds every term of A whatever it is (springs with their geometric part, the volumetric
  cells of tissue at any Poisson's ratio, the physics terms, drags, the mass and damping). We
  measured it against rediscretising the lattice at 2h (the issue's prototype), which needs a
  coarse body (fill, regions, per-spring weights) for every level and misses on thin parts.
* **Smoother.** Damped block-Jacobi (the inverse of each node's 3x3 diagonal block, the
  x y z coupling of elasticity), ``x += w D^-1 (b - A x)`` with ``w = 4 / (3 lambda)`` and
  lambda the Gershgorin bound of ``D^-1 A`` (largest block-row sum of ``|D^-1 A|``), so
  ``w lambda_max(D^-1 A) <= 4/3 < 2`` on every level: the smoother converges without an
  eigenvalue solve, and damps the upper two thirds of the spectrum.
* **Cycle.** A V-cycle from a zero guess with :data:`SWEEPS` pre- and as many post-smoothing
  sweeps, the same smoother both ways: the cycle is a symmetric positive definite operator
  (tested on random vectors, tests/test_multigrid.py), so preconditioned CG stays CG.

Zhu, Sifakis, Teran & Brandt 2010 (geometric multigrid for elastic solids on a lattice) and
Dick, Georgii & Westermann 2011 (GPU multigrid for deformable bodies) are the anchors; measured
iteration counts are in docs/PERFORMANCE.md ("Multigrid").
"""

from __future__ import annotations

from dataclasses import dataclass

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp

__all__ = ["COARSEST_NODES", "SWEEPS", "DAMPING", "Level", "Hierarchy", "CoarseLevels", "prolongation", "grid_levels",
           "block_inverse", "diagonal_blocks"]

#: The coarsest level has at most this many nodes; it is solved exactly.
COARSEST_NODES = 64
#: Smoothing sweeps before and after the coarse correction on every level.
SWEEPS = 2
#: The smoother's damping times the Gershgorin bound of D^-1 A.
DAMPING = 4.0 / 3.0


def _coarse_axis(n: int) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One axis of ``n`` nodes: the coarse count, and for each fine index its two coarse indices
    and weights (an axis of one node stays one node)."""
    f = np.arange(n)
    if n == 1:
        return 1, f, f, np.ones(1), np.zeros(1)
    lo = f // 2
    odd = (f % 2).astype(bool)
    hi = np.where(odd, lo + 1, lo)
    return int(hi.max()) + 1, lo, hi, np.where(odd, 0.5, 1.0), np.where(odd, 0.5, 0.0)


def prolongation(occupied: np.ndarray, fine_nodes: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Trilinear interpolation from the grid at twice the spacing.

    Args:
        occupied: (nx, ny, nz) bool, the fine grid's box.
        fine_nodes: (F, 3) grid index of the fine unknowns (free nodes), in row order.

    Returns:
        (P, coarse): P (F, C) CSR, the weights of the C coarse nodes that some fine unknown takes a
        share of, and ``coarse`` (nx', ny', nz') bool, which coarse positions exist.
    """
    axes = [_coarse_axis(n) for n in occupied.shape]
    shape = tuple(a[0] for a in axes)
    rows, cols, vals = [], [], []
    fi = np.asarray(fine_nodes, np.int64)
    for corner in range(8):
        pick = [(corner >> a) & 1 for a in range(3)]
        w = np.ones(len(fi))
        idx = []
        for a in range(3):
            _, lo, hi, wl, wh = axes[a]
            i = fi[:, a]
            idx.append(hi[i] if pick[a] else lo[i])
            w = w * (wh[i] if pick[a] else wl[i])
        keep = w > 0
        rows.append(np.nonzero(keep)[0])
        cols.append(np.ravel_multi_index(tuple(c[keep] for c in idx), shape))
        vals.append(w[keep])
    r, c, v = (np.concatenate(x) for x in (rows, cols, vals))
    present = np.zeros(int(np.prod(shape)), bool)
    present[c] = True
    number = np.cumsum(present) - 1
    p = sp.csr_matrix((v, (r, number[c])), shape=(len(fi), int(present.sum())))
    return p, present.reshape(shape)


def grid_levels(occupied: np.ndarray, free_ijk: np.ndarray, coarsest: int = COARSEST_NODES) -> list[sp.csr_matrix]:
    """The node prolongations (F_l, F_{l+1}) from the fine unknowns down to at most ``coarsest``
    nodes (at least one level below the finest where the grid has 3 nodes along some axis; none
    on a grid of at most 2 along every axis)."""
    out: list[sp.csr_matrix] = []
    box, nodes = occupied, np.asarray(free_ijk)
    while (len(nodes) > coarsest or not out) and max(box.shape) > 2:
        p, coarse = prolongation(box, nodes)
        out.append(p)
        box, nodes = coarse, np.argwhere(coarse)
    return out


@dataclass(frozen=True)
class Level:
    """One level's operator, its damped block-Jacobi smoother and its prolongation to the level above."""

    matrix: sp.csr_matrix           # A_l, (3 F_l, 3 F_l)
    omega: float                    # the smoother's damping w = DAMPING / (Gershgorin bound of D^-1 A)
    smoother: sp.csr_matrix         # w D_l^-1 (block diagonal)
    prolong: sp.csr_matrix | None   # P_l kron I3, (3 F_{l-1}, 3 F_l); None on the finest level


def diagonal_blocks(a: sp.csr_matrix) -> np.ndarray:
    """(F, 3, 3) the diagonal 3x3 block of each node of ``a`` (x y z per node)."""
    nodes = a.shape[0] // 3
    base = 3 * np.arange(nodes)
    blocks = np.empty((nodes, 3, 3))
    for r in range(3):
        for c in range(3):
            blocks[:, r, c] = np.asarray(a[base + r, base + c]).ravel()
    return blocks


def block_inverse(a: sp.csr_matrix) -> sp.csr_matrix:
    """The inverses of the 3x3 diagonal blocks of ``a`` (x y z per node), as a sparse matrix."""
    nodes = a.shape[0] // 3
    return sp.bsr_matrix((np.linalg.inv(diagonal_blocks(a)), np.arange(nodes), np.arange(nodes + 1)),
                         shape=a.shape).tocsr()


def _level(a: sp.csr_matrix, prolong: sp.csr_matrix | None) -> Level:
    inv = block_inverse(a)
    bound = float(np.max(np.asarray(abs(inv @ a).sum(axis=1)).ravel())) if a.shape[0] else 1.0
    omega = DAMPING / bound
    return Level(a, omega, omega * inv, prolong)


class Hierarchy:
    """The V-cycle (module docstring) built from one matrix ``a0``: its coarse levels and every
    level's damping are fixed at ``a0`` (the start state's step matrix), and each step's cycle
    (:meth:`cycle`) smooths the finest level with that step's own matrix. The cycle is symmetric
    positive definite for any SPD step matrix whose ``D^-1 A`` keeps its Gershgorin bound under
    1.5 times that of ``a0`` (the smoother then still converges: ``w lambda < 2``).

    Args:
        a0: (3F, 3F) a step's matrix over the free nodes.
        prolongations: the node prolongations of :func:`grid_levels` (rows: the free nodes in
            the matrix's order).
    """

    def __init__(self, a0: sp.csr_matrix, prolongations: list[sp.csr_matrix]) -> None:
        self.levels: list[Level] = [_level(a0.tocsr(), None)]
        for p in prolongations:
            p3 = sp.kron(p, sp.identity(3), format="csr")
            coarse = (p3.T @ self.levels[-1].matrix @ p3).tocsr()
            self.levels.append(_level(coarse, p3))
        last = self.levels[-1].matrix.toarray()
        self.coarse_inverse = np.linalg.inv(last) if last.size else last

    @property
    def depth(self) -> int:
        return len(self.levels)

    def _cycle(self, levels: list[Level], level: int, b: np.ndarray) -> np.ndarray:
        if level == len(levels) - 1:
            return self.coarse_inverse @ b
        lv = levels[level]
        x = lv.smoother @ b
        for _ in range(SWEEPS - 1):
            x += lv.smoother @ (b - lv.matrix @ x)
        below = levels[level + 1]
        assert below.prolong is not None
        x += below.prolong @ self._cycle(levels, level + 1, below.prolong.T @ (b - lv.matrix @ x))
        for _ in range(SWEEPS):
            x += lv.smoother @ (b - lv.matrix @ x)
        return x

    def cycle(self, a: sp.csr_matrix) -> Callable[[np.ndarray], np.ndarray]:
        """``r -> M^-1 r``, one V-cycle from zero whose finest level is ``a`` (this step's matrix,
        smoothed with its own block inverse at ``a0``'s damping)."""
        fine = Level(a, self.levels[0].omega, self.levels[0].omega * block_inverse(a), None)
        levels = [fine, *self.levels[1:]]
        return lambda r: self._cycle(levels, 0, np.asarray(r, np.float64))


class CoarseLevels:
    """A simulation's multigrid: the grid's prolongations, and the :class:`Hierarchy` built from
    the first step matrix it is given (the start state's), reused for every later step."""

    def __init__(self, prolongations: list[sp.csr_matrix]) -> None:
        self.prolongations = prolongations
        self.hierarchy: Hierarchy | None = None

    def cycle(self, a: sp.csr_matrix) -> Callable[[np.ndarray], np.ndarray]:
        if self.hierarchy is None:
            self.hierarchy = Hierarchy(a, self.prolongations)
        return self.hierarchy.cycle(a)
