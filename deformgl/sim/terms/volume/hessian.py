"""The cells' blocks of the backward-Euler matrix (:mod:`deformgl.sim.implicit`): the Hessian of
the volumetric term and of the corner barriers of :mod:`deformgl.sim.terms.volume.energy`, float64.

Both terms are ``w/2 (J - J0)^2`` of a determinant ``J = det E``, ``E = sum_t x_t (x) D_t`` a linear
map of T nodes' positions (the weights D_t (3,) per node):

* the centre term: the cell's 8 corners, ``D_a = G_a = s_a / (4h)``, ``w = V kappa``, ``J0 = 1``;
* the barrier of corner c (only where ``J_c < J_b``): the tet of c and its three neighbours
  c ^ 1, c ^ 2, c ^ 4 inside the cell, ``D_c = s_c / h``, ``D_(c ^ 2^k) = -s_c[k] / h e_k``,
  ``w = V/8 kappa_b``, ``J0 = J_b`` (then ``det E`` is :func:`~deformgl.sim.terms.volume.energy.corner_jacobians`' det F_c).

With ``dJ/dx_t = cof(E) D_t =: g_t`` (``dJ/dE = cof E``), the Hessian of one term is::

    H_tu = w g_t g_u^T + w (J - J0) S_tu,   S_tu = d^2 J / dx_t dx_u = -[E (D_t x D_u)]_x

(``[a]_x`` the cross-product matrix: ``d^2 det E / dE_ij dE_kl = eps_ikm eps_jln E_mn``). The
first part is the Gauss-Newton part, positive semidefinite (rank 1). The second, the "geometric"
(stress) part, is never positive semidefinite where it is not zero: in the frame of E's singular
value decomposition ``E = U diag(sigma) V^T`` a *twist* ``dE = U T_k V^T`` (T_k the rotation
generator about axis k) and a *flip* ``dE = U L_k V^T`` (L_k its symmetric counterpart, the
same two entries of equal sign) change J at second order by ``+sigma_k`` and ``-sigma_k`` times
``|dE|^2 / 2``: ``det diag(sigma) + eps T_0 = sigma_0 (sigma_1 sigma_2 + eps^2)``, with L_0
``sigma_0 (sigma_1 sigma_2 - eps^2)``. Both directions are orthogonal to ``cof E`` (the
Gauss-Newton direction, diagonal in that frame), so for every ``J != J0`` and ``sigma_k > 0``
the term's block has the eigenvalue ``-w |J - J0| sigma_k`` times the map's scale whatever the
Gauss-Newton part: no clamp of the coefficient (the springs' ``max(0, g)``) keeps any of it PSD.

So the cells' part of H follows the springs' ``geometric`` option (:data:`CELL_HESSIAN`):
"projected" (default) and "none" keep the Gauss-Newton part (the geometric part is dropped where
it would make the block indefinite, which is everywhere); "full" keeps both (the exact
Hessian, indefinite in compression and tension alike); "eigen" (NumPy only) is the eigenvalue
projection of each cell's 24x24 block (centre and active barriers together), negative
eigenvalues set to 0: what clamping g is for a spring, at the cost of a 24x24 eigendecomposition
per cell and step, which the GPU's matrix-free product does not do. :func:`cell_product` is the
matrix-free Gauss-Newton product, the twin of the GPU's ``shaders/terms/cell_implicit.glsl``.

Measured (with the barrier's first J_b = 0.5) with direct solves at dt = 1/30 s
(tests/test_cells_implicit.py: the 5x3x3-node block clamped at one end under gravity, and the
4x4x4-node block clamped at its bottom, half its top pushed down by F per node, E = 3 kPa): the
static residual (max free-node force over the largest node weight) after 20 / 40 / 80 steps,
and the squash's lowest corner Jacobian over 30 steps (below 0: a cell inverted on the way; at
nu = 0.45 and 0.4 N two were, for a few steps):

======  ========================  ========================  ========================
nu      projected (Gauss-Newton)  eigen                     full
======  ========================  ========================  ========================
0.25    3.6e-2 / 6.7e-4 / 1.4e-6  3.5e-2 / 6.8e-4 / 1.4e-6  3.6e-2 / 6.7e-4 / 1.4e-6
0.45    2.7e-2 / 9.1e-4 / 7.5e-7  1.1e-2 / 2.0e-4 / 1.4e-7  1.3e-2 / 3.7e-4 / 4.1e-7
0.49    4.0e-2 / 7.3e-4 / 5.5e-7  3.3e-3 / 7.6e-5 / 3.4e-8  4.3e-3 / 1.5e-4 / 1.2e-7
squash  nu 0.25, F 0.2 N: 0.168   0.168                     blows up (all 27 inverted)
squash  nu 0.45, F 0.4 N: -0.015  0.044                     blows up
======  ========================  ========================  ========================

"eigen" takes 40-60 % more time per step on that block; projecting only the centre term gives
all of its gain, projecting only the barriers none. CG iterations per step are the same for the
three (they change A little): the conditioning comes from kappa, not from this choice.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from deformgl.sim.terms.volume.energy import CORNER_SIGNS, CellVolumes, corner_tets

__all__ = ["CELL_HESSIANS", "CELL_HESSIAN", "DeterminantTerms", "centre_terms", "barrier_terms",
           "term_blocks", "cell_matrix", "cell_product"]

#: The forms of the cells' Hessian: Gauss-Newton, exact, eigenvalue-projected per cell.
CELL_HESSIANS = ("gauss-newton", "full", "eigen")
#: The cells' Hessian that goes with each of the springs' ``geometric`` options.
CELL_HESSIAN = {"projected": "gauss-newton", "none": "gauss-newton", "full": "full", "eigen": "eigen"}

#: (3, 3, 3) the Levi-Civita symbol.
_EPS = np.zeros((3, 3, 3))
for _i, _j, _k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
    _EPS[_i, _j, _k], _EPS[_i, _k, _j] = 1.0, -1.0
#: (8, 4) the tet of corner c: c, c ^ 1, c ^ 2, c ^ 4.
TET_CORNERS = corner_tets(1.0)[0]


class DeterminantTerms:
    """Terms ``w/2 (J - J0)^2``, ``J = det(sum_t x_t (x) D_t)``, over T nodes each (module docstring).

    Attributes:
        nodes: (K, T) int64 node numbers.
        weights: (K, T, 3) D_t in 1/m.
        e: (K, 3, 3) E.
        det: (K,) J.
        grad: (K, T, 3) dJ/dx_t in 1/m.
        modulus: (K,) w in N m (J/1: the energy is w/2 (J - J0)^2 in J).
        stress: (K,) w (J - J0) in N m, the geometric part's coefficient.
    """

    def __init__(self, nodes: np.ndarray, weights: np.ndarray, x: np.ndarray, modulus: float | np.ndarray,
                 rest: float) -> None:
        self.nodes, self.weights = nodes, weights
        xs = x[nodes]
        # positions relative to the first node: E is translation invariant (sum_t D_t = 0)
        e = np.einsum("kti,ktj->kij", xs - xs[:, :1], weights)
        cols = e[:, :, 0], e[:, :, 1], e[:, :, 2]
        cof = np.stack([np.cross(cols[1], cols[2]), np.cross(cols[2], cols[0]), np.cross(cols[0], cols[1])], axis=2)
        self.e = e
        self.det = np.einsum("ki,ki->k", cols[0], cof[:, :, 0])
        self.grad = np.einsum("kij,ktj->kti", cof, weights)
        self.modulus = np.asarray(modulus, np.float64) * np.ones(len(nodes))
        self.stress = self.modulus * (self.det - rest)

    def __len__(self) -> int:
        return len(self.nodes)

    def second_derivative(self) -> np.ndarray:
        """(K, T, 3, T, 3) ``d^2 J / dx_t dx_u = -[E (D_t x D_u)]_x``."""
        d = self.weights
        t = d.shape[1]
        pair = np.cross(d[:, :, None, :], d[:, None, :, :])              # (K, T, T, 3)
        w = np.einsum("kmn,ktun->ktum", self.e, pair)
        s = np.einsum("ijm,ktum->ktiuj", _EPS, w)                        # s[t,i,u,j] = eps_ijm w_m
        return s.reshape(len(self), t, 3, t, 3)


def centre_terms(cells: CellVolumes, x: np.ndarray) -> DeterminantTerms:
    """The centre term of every cell (:mod:`deformgl.sim.terms.volume.energy`), T = 8."""
    weights = np.broadcast_to(CORNER_SIGNS / (4.0 * cells.spacing), (cells.count, 8, 3))
    return DeterminantTerms(cells.corners, weights, x, cells.volume * cells.volume_modulus, 1.0)


def barrier_terms(cells: CellVolumes, x: np.ndarray) -> tuple[DeterminantTerms, np.ndarray]:
    """The barriers of the corners inside the barrier (``J_c < J_b``), T = 4 (the corner's tet),
    and the (A,) ``8 cell + corner`` of each."""
    tets, weights = corner_tets(cells.spacing)
    nodes = cells.corners[:, tets].reshape(-1, 4)                      # (C * 8, 4)
    terms = DeterminantTerms(nodes, np.broadcast_to(weights, (cells.count, 8, 4, 3)).reshape(-1, 4, 3), x,
                             cells.volume / 8.0 * cells.barrier_modulus, cells.barrier_j)
    active = np.flatnonzero(terms.det < cells.barrier_j) if cells.barrier_modulus > 0 else np.zeros(0, np.int64)
    picked = DeterminantTerms(nodes[active], terms.weights[active], x, terms.modulus[active], cells.barrier_j)
    return picked, active


def term_blocks(terms: DeterminantTerms, kind: str) -> np.ndarray:
    """(K, 3T, 3T) Hessian blocks of the terms: "gauss-newton" ``w g g^T`` or "full" (+ ``w (J - J0) S``)."""
    g = terms.grad.reshape(len(terms), -1)
    blocks = terms.modulus[:, None, None] * g[:, :, None] * g[:, None, :]
    if kind == "full":
        t = terms.grad.shape[1]
        blocks = blocks + terms.stress[:, None, None] * terms.second_derivative().reshape(len(terms), 3 * t, 3 * t)
    return blocks


def _check(kind: str) -> None:
    if kind not in CELL_HESSIANS:
        raise ValueError(f"cell Hessian must be one of {', '.join(CELL_HESSIANS)}, got {kind!r}")


def _triplets(nodes: np.ndarray, blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    dof = (3 * nodes[:, :, None] + np.arange(3)).reshape(len(nodes), -1)   # (K, 3T)
    rows = np.broadcast_to(dof[:, :, None], blocks.shape)
    cols = np.broadcast_to(dof[:, None, :], blocks.shape)
    return rows.ravel(), cols.ravel(), blocks.ravel()


def cell_matrix(cells: CellVolumes, x: np.ndarray, count: int, kind: str = "gauss-newton") -> sp.csr_matrix:
    """(3N, 3N) CSR: the cells' part of H = -df/dx at positions ``x`` (N = ``count``), of the
    form ``kind`` (:data:`CELL_HESSIANS`; module docstring)."""
    _check(kind)
    shape = (3 * count, 3 * count)
    if cells.count == 0:
        return sp.csr_matrix(shape)
    barrier, active = barrier_terms(cells, x)
    parts = []
    if kind == "eigen":
        # the cell's 24 x 24 block: its centre term and its active barriers, then projected
        blocks = (term_blocks(centre_terms(cells, x), "full") if cells.volume_modulus > 0
                  else np.zeros((cells.count, 24, 24)))
        if len(barrier):
            local = (3 * TET_CORNERS[active % 8][:, :, None] + np.arange(3)).reshape(len(barrier), 12)
            np.add.at(blocks, (active[:, None, None] // 8, local[:, :, None], local[:, None, :]),
                      term_blocks(barrier, "full"))
        values, vectors = np.linalg.eigh(blocks)
        parts.append(_triplets(cells.corners, np.einsum("kij,kj,klj->kil", vectors, np.maximum(values, 0.0), vectors)))
    else:
        if cells.volume_modulus > 0:
            parts.append(_triplets(cells.corners, term_blocks(centre_terms(cells, x), kind)))
        if len(barrier):
            parts.append(_triplets(barrier.nodes, term_blocks(barrier, kind)))
    if not parts:
        return sp.csr_matrix(shape)
    rows, cols, vals = (np.concatenate(p) for p in zip(*parts))
    return sp.coo_matrix((vals, (rows, cols)), shape=shape).tocsr()


def cell_product(cells: CellVolumes, x: np.ndarray, y: np.ndarray, kind: str = "gauss-newton") -> np.ndarray:
    """(N, 3) ``H_cells y`` without assembling: per term ``w (g . y) g`` ("gauss-newton"), and
    for "full" ``+ w (J - J0) S y`` (the GPU's matrix-free product, ``cells.glsl``)."""
    if kind not in ("gauss-newton", "full"):
        raise ValueError(f"cell_product: kind must be 'gauss-newton' or 'full', got {kind!r}")
    out = np.zeros((len(x), 3))
    if cells.count == 0:
        return out
    terms = [barrier_terms(cells, x)[0]]
    if cells.volume_modulus > 0:
        terms.append(centre_terms(cells, x))
    for term in terms:
        if not len(term):
            continue
        ys = y[term.nodes]                                                # (K, T, 3)
        dj = np.einsum("kti,kti->k", term.grad, ys)
        per_node = (term.modulus * dj)[:, None, None] * term.grad
        if kind == "full":
            per_node += term.stress[:, None, None] * np.einsum("ktiuj,kuj->kti", term.second_derivative(), ys)
        for c in range(3):
            out[:, c] += np.bincount(term.nodes.ravel(), weights=per_node[:, :, c].ravel(), minlength=len(x))
    return out
