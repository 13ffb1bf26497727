"""The bending energy of a flat sheet (cloth) on its node grid: a plate's bending stiffness D in
N·m, linear in the node positions.

A membrane lattice (:func:`deformgl.sim.materials.sheet_system`) resists stretch only: a flat sheet
of springs has no first-order stiffness out of its plane, and flexion springs give one only
through the geometry, so their ``flexion_ratio`` is a shape knob. This term is the discrete
Kirchhoff plate energy, the quadratic bending model of Bergou, Wardetzky, Harmon, Zorin &
Grinspun 2006 ("A quadratic bending model for inextensible surfaces"): for a sheet that is flat
at rest, ``E = 1/2 sum_s k_s |sum_i g_si x_i|^2`` over stencils s of second differences, so the
force ``f = -B x`` is linear in x with one constant matrix B (``B = sum_s k_s g_s g_s^T``, the
same for x, y and z). B is symmetric positive semi-definite, its rows sum to zero, and the flat
rest shape and every rigid motion of it lie in its null space (each ``g_s`` sums to zero and
annihilates the grid's affine fields), so a sheet that only stretches in its plane, translates
or rotates stores no bending energy.

The continuum energy density of an isotropic plate (Timoshenko & Woinowsky-Krieger 1959,
"Theory of plates and shells", section 12, eq. 118) is

    W = D/2 [(k_xx + k_yy)^2 - 2 (1 - nu) (k_xx k_yy - k_xy^2)]

with curvatures k of the out-of-plane displacement. On the grid (spacing h, in-plane axes a and
b, node weight ``w_n`` = its full square cells / 4, its share of area ``w_n h^2``):

* per node n whose two axis triplets exist (n -+ a and n -+ b present), with
  ``s_a = x_{n-a} - 2 x_n + x_{n+a} ~ h^2 k_aa`` and ``s_b`` likewise, ``k_0 = w_n D / h^2``:
  ``(1 - nu) k_0 / 2 (|s_a|^2 + |s_b|^2) + nu k_0 / 2 |s_a + s_b|^2`` (the second is the
  five-point Laplacian); a node with one triplet (a straight border) gets ``(1 - nu^2) k_0 / 2
  |s|^2``: a free edge carries no moment across it, so the curvature across is ``-nu`` times the
  curvature along, the energy ``(1 - nu^2) D/2 k^2`` (a narrow strip's rigidity ``D (1 - nu^2)``,
  ``E t^3 / 12``);
* per full square cell (corners c00, c10, c01, c11), the twist
  ``q = x_11 - x_10 - x_01 + x_00 ~ h^2 k_ab`` with ``(1 - nu) D / h^2 |q|^2``.

Under any quadratic displacement field these sum to W times the area exactly at interior nodes
and cells (tests/test_bending.py checks cylinder, saddle and twist), with ``nu = 1/3``
(:data:`SHEET_BENDING_POISSON`), the membrane lattice's own Poisson's ratio. Calibrated against
the analytic plate (docs/ACCURACY.md, "Cloth bending"; ``python -m studies.cloth_bending``): the
simply supported square plate under uniform pressure (Navier's series; Timoshenko &
Woinowsky-Krieger 1959, section 30), the twisted plate, the cantilever strip ``q L^4 / (8 D)``
and, at large deflection, the heavy elastica.

The largest angular frequency it adds (the dt check): B's Gershgorin row sum ``sum_j |B_nj|``
over the node's mass (:meth:`SheetBending.frequency_terms`), 64 D / h^2 at an interior node, so
``w^2 <= (2 sum k + 64 D / h^2) / (rho_A h^2)``: a bending-dominated sheet's explicit dt falls
as h^2, the plate's dispersion (docs/EQUATIONS.md, "Cloth bending").
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from deformgl.grid.neighbours import grid_neighbours
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.terms.base import GlslTerm, NodeTable, Term, TermNeeds

__all__ = ["BENDING_REFUSAL", "NEEDS", "SHEET_BENDING_POISSON", "SheetBending", "node_weights", "sheet_bending"]

#: the plate Poisson's ratio of the bending term: the membrane lattice's (2D Lamé lambda = mu)
SHEET_BENDING_POISSON = 1.0 / 3.0


#: Why XPBD refuses a sheet's bending stiffness, and what to do (every refusal says it). (The plate
#: stencils couple 3 to 5 nodes each, about 15 per node; the Jacobi sweep keeps one multiplier per
#: constraint end, so the GPU sweep would store 45 more floats per node.)
BENDING_REFUSAL = ("has no XPBD constraint: run it with an explicit integrator or implicit-euler, or use "
                   "flexion_ratio with xpbd")

#: What the term costs and refuses, from the scene alone (:class:`~deformgl.sim.terms.TermNeeds`):
#: on the host its stencils and B being assembled (1.37 kB per node measured at the peak on 250k
#: nodes, 270 B kept; 1,600 with a margin); the 24-neighbour table; on the fragment backends its
#: 6 coefficient layers (one per neighbour); on transform feedback B's off-diagonal entries (12 at
#: an interior node: 4 at h, 4 at 2h, 4 diagonals); no XPBD form.
NEEDS = TermNeeds("material.bending_stiffness", host_bytes_per_node=1600, neighbours=24, node_layers=6,
                  feedback_entries=12, refused=(("xpbd", BENDING_REFUSAL),))

#: The term's GLSL form (``shaders/terms/bending.glsl``): ``f -= c_j (x_i - x_j)`` over the 24 grid
#: neighbours, c_j from its table (:meth:`SheetBending.neighbour_coefficients`).
GLSL = GlslTerm("bending", file="terms/bending.glsl", implicit=True, neighbours=24)


@dataclass(frozen=True, eq=False)
class SheetBending(Term):
    """The bending term of a sheet: ``E = 1/2 sum_c x_c^T B x_c`` over the coordinates c.

    Attributes:
        matrix: (N, N) float64 CSR, B in N/m: symmetric positive semi-definite, rows summing to 0.
        bending_stiffness: the plate's D in N·m.
        stencils: the count of stencils of each kind ("triplet", "laplacian", "twist").
    """

    matrix: sp.csr_matrix
    bending_stiffness: float
    stencils: dict[str, int] = field(default_factory=dict)

    name = "a sheet's bending"
    neighbours = 24

    @property
    def count(self) -> int:
        """Number of nodes N."""
        return int(self.matrix.shape[0])

    def forces(self, x: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Add ``f = -B x`` (N, 3) in N to ``out``; returns out."""
        out -= self.matrix @ x
        return out

    def add_forces(self, x: np.ndarray, v: np.ndarray, t: float, out: np.ndarray) -> None:
        """``f = -B x`` (:meth:`forces`)."""
        self.forces(x, out)

    def energy(self, x: np.ndarray) -> float:
        """The bending energy in J at positions x (N, 3)."""
        return 0.5 * float(np.einsum("nc,nc->", x, self.matrix @ x))

    def stiffness(self, x: np.ndarray) -> sp.csr_matrix:
        """B on each coordinate (the blocks ``B_ij I``), the same at every x."""
        return sp.kron(self.matrix, sp.identity(3), format="csr")

    def dt_product(self, x_rest: np.ndarray, dx: np.ndarray, *, barrier: bool = False) -> np.ndarray:
        """``B dx`` (linear: the same B at any state)."""
        return self.matrix @ np.asarray(dx, np.float64)

    def frequency_terms(self, x_rest: np.ndarray | None = None, *, barrier: bool = False) -> np.ndarray:
        """(N,) ``sum_j |B_nj|`` in N/m: its bound on the node's ``m w^2`` (Gershgorin)."""
        return np.asarray(abs(self.matrix).sum(axis=1)).ravel()

    def describe(self) -> str:
        return f"a sheet's bending, D = {self.bending_stiffness:.4g} N*m"

    def feedback_pairs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """B's off-diagonal entries as ``f_i = -sum_j c_ij (x_i - x_j)``, ``c_ij = -B_ij`` (rows sum to 0)."""
        b = self.matrix.tocoo()
        off = b.row != b.col
        return b.row[off], b.col[off], -b.data[off]

    def refusal(self, backend: str) -> str | None:
        why = NEEDS.refusal(backend)  # (the scene checks refuse the same, from NEEDS)
        return f"a sheet's bending_stiffness {why}" if why is not None else super().refusal(backend)

    def glsl(self, grid: NodeGrid | None) -> GlslTerm:
        """:data:`GLSL` with the coefficients of ``grid``'s 24-neighbour table as its node table."""
        if grid is None:
            raise ValueError("a sheet's bending needs the sheet's node grid on the GPU")
        coefficients = self.neighbour_coefficients(grid_neighbours(grid, True))
        return dataclasses.replace(GLSL, tables=(NodeTable("u_bending_c", coefficients),))

    def neighbour_coefficients(self, neighbours: np.ndarray) -> np.ndarray:
        """(N, K) float64 ``c_nj = -B[n, neighbours[n, j]]`` (0 where the neighbour is absent,
        -1), so that ``(B y)_n = sum_j c_nj (y_n - y_j)`` (rows sum to zero): the GPU's gather.
        Raises ValueError when B couples a node to one that is not in its row of ``neighbours``
        (the fragment backends read B through the 24-neighbour table: axis neighbours at h and
        2h, face diagonals)."""
        n, k = neighbours.shape
        rows = np.repeat(np.arange(n), k)
        cols = neighbours.ravel()
        present = cols >= 0
        coeff = np.zeros(n * k)
        coeff[present] = -np.asarray(self.matrix[rows[present], cols[present]]).ravel()
        # every off-diagonal entry of B must be read through the table (each once)
        off = self.matrix.tocoo()
        off_pairs = set(zip(off.row[off.row != off.col].tolist(), off.col[off.row != off.col].tolist()))
        read = set(zip(rows[present].tolist(), cols[present].tolist()))
        missing = off_pairs - read
        if missing:
            node, other = min(missing)
            raise ValueError(f"SheetBending: node {node} is coupled to node {other}, which is not in its neighbour table")
        return coeff.reshape(n, k)


def node_weights(grid: NodeGrid, axes: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(N,) full square cells at each node / 4, and (C, 4) corner nodes (c00, c10, c01, c11) of
    the full cells, for a one-node-thick grid whose plane holds ``axes``."""
    a, b = axes
    index = grid.index
    thin = 3 - a - b
    plane = np.take(index, 0, axis=thin)  # (n_a, n_b) node numbers, -1 empty (a < b kept in order)
    c00, c10 = plane[:-1, :-1], plane[1:, :-1]
    c01, c11 = plane[:-1, 1:], plane[1:, 1:]
    full = (c00 >= 0) & (c10 >= 0) & (c01 >= 0) & (c11 >= 0)
    corners = np.stack([c00[full], c10[full], c01[full], c11[full]], axis=1).astype(np.int64)
    weights = np.bincount(corners.ravel(), minlength=grid.count) / 4.0
    return weights, corners


def _stencil_matrix(nodes: np.ndarray, g: np.ndarray, k: np.ndarray, n: int) -> sp.csr_matrix:
    """``sum_s k_s g_s g_s^T`` for stencils of the same size m: nodes (S, m), g (m,), k (S,)."""
    if len(nodes) == 0:
        return sp.csr_matrix((n, n))
    rows = np.repeat(nodes[:, :, None], nodes.shape[1], axis=2)
    cols = np.repeat(nodes[:, None, :], nodes.shape[1], axis=1)
    vals = k[:, None, None] * (g[:, None] * g[None, :])[None]
    return sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(n, n))


def sheet_bending(grid: NodeGrid, bending_stiffness: float, *,
                  poissons_ratio: float = SHEET_BENDING_POISSON) -> SheetBending:
    """The bending term (module docstring) of a one-node-thick grid with plate stiffness
    ``bending_stiffness`` D in N·m."""
    if not (np.isfinite(bending_stiffness) and bending_stiffness > 0):
        raise ValueError(f"bending_stiffness must be a finite number > 0 (N·m), got {bending_stiffness}")
    if not 0.0 <= poissons_ratio < 1.0:
        raise ValueError(f"sheet bending: poissons_ratio must be in [0, 1) (B positive semi-definite), got {poissons_ratio}")
    shape = grid.shape
    thin = [ax for ax in range(3) if shape[ax] == 1]
    if not thin:
        raise ValueError("sheet bending: the grid is not one node thick (a cloth)")
    axes = tuple(ax for ax in range(3) if ax != thin[0])
    a, b = axes[0], axes[1]
    n = grid.count
    h = float(grid.spacing)
    nu = float(poissons_ratio)
    weights, corners = node_weights(grid, (a, b))
    plane = np.take(grid.index, 0, axis=thin[0])
    padded = np.pad(plane, 1, constant_values=-1)
    ij = np.delete(grid.ijk.astype(np.int64), thin[0], axis=1) + 1
    centre = np.arange(n)

    def at(di: int, dj: int) -> np.ndarray:
        return padded[ij[:, 0] + di, ij[:, 1] + dj]

    xm, xp, ym, yp = at(-1, 0), at(1, 0), at(0, -1), at(0, 1)
    k0 = weights * bending_stiffness / h ** 2
    has_a = (xm >= 0) & (xp >= 0) & (k0 > 0)
    has_b = (ym >= 0) & (yp >= 0) & (k0 > 0)
    both = has_a & has_b
    triplet = np.array([1.0, -2.0, 1.0])
    # an axis triplet: (1 - nu) k0 where the node has both (the rest in the Laplacian); alone (a
    # free straight border, where the curvature across is free: k_nn = -nu k_tt) (1 - nu^2) k0
    ka = np.where(both, (1.0 - nu) * k0, (1.0 - nu * nu) * k0)
    matrix = (_stencil_matrix(np.stack([xm, centre, xp], 1)[has_a], triplet, ka[has_a], n)
              + _stencil_matrix(np.stack([ym, centre, yp], 1)[has_b], triplet, ka[has_b], n))
    if nu > 0:
        laplacian = np.array([1.0, 1.0, -4.0, 1.0, 1.0])
        matrix = matrix + _stencil_matrix(np.stack([xm, xp, centre, ym, yp], 1)[both], laplacian,
                                          nu * k0[both], n)
    twist = np.array([1.0, -1.0, -1.0, 1.0])
    matrix = matrix + _stencil_matrix(corners, twist, np.full(len(corners), 2.0 * (1.0 - nu) * bending_stiffness
                                                              / h ** 2), n)
    matrix = matrix.tocsr()
    matrix.sum_duplicates()
    matrix.eliminate_zeros()
    stencils = {"triplet": int(has_a.sum() + has_b.sum()), "laplacian": int(both.sum()) if nu > 0 else 0,
                "twist": int(len(corners))}
    return SheetBending(matrix, float(bending_stiffness), stencils)
