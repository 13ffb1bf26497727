"""The lattice's volumetric term: what central springs cannot give (any Poisson's ratio, no
inversion), per full grid cell, in float64 (the reference of every backend's cell forces).

The calibrated spring lattice (:mod:`deformgl.sim.materials`) has Lamé constants λ = μ = k/h:
Poisson's ratio 1/4 whatever the springs' constants (the Cauchy relation). A material of ratio
ν > 1/4 has λ > μ; the missing ``λ − μ`` is added as an energy of each full cell's volume ratio
J, and a barrier keeps every corner of every cell from inverting. Per full cell of rest volume
``V = h^3`` (8 corner nodes, corner ``c = dx + 2 dy + 4 dz`` at ``origin + h (dx, dy, dz)``):

* **Volumetric term, at the cell centre** (one-point quadrature of the volumetric part, the
  selective-reduced / Q1-P0 choice that does not lock as ν → 1/2; Hughes 1980, "Generalization of
  selective integration procedures to anisotropic and nonlinear media"):
  ``E_vol = V κ/2 (J − 1)^2``, ``κ = λ − μ`` (Pa), ``J = det F`` with
  ``F = Σ_c x_c ⊗ G_c`` the trilinear map's deformation gradient at the centre,
  ``G_c = s_c / (4h)``, ``s_c = (2dx − 1, 2dy − 1, 2dz − 1)``. Linearised, ``J − 1 = tr ε``, so the
  term adds exactly κ to λ: the lattice plus the term is the isotropic tensor of (E, ν) under any
  uniform strain (docs/EQUATIONS.md, "Any Poisson's ratio"). ``(J − 1)^2`` is the volumetric
  energy of the stable neo-Hookean material (Smith, de Goes & Kim 2018, eq. 14 with α = 1): finite
  at every J and restoring (dE/dJ < 0) at J ≤ 0, so an inverted cell is pushed back.
  The force on corner c is ``−V κ (J − 1) cof(F) G_c`` (``∂J/∂F = cof F``).
* **Inversion barrier, at the corners**: at corner c the trilinear map's Jacobian is the
  corner's own ``F_c = [e_0 e_1 e_2] / h``, ``e_k`` the cell edge from c along axis k oriented
  by ``−s_c[k]`` (``F_c = I`` at rest); a cell is *inverted* when ``det F_c <= 0`` at one of its
  corners (the census of :func:`inverted_cells`). Below ``J_b`` = :data:`BARRIER_J` each corner
  stores ``V/8 · κ_b/2 (J_b − J_c)^2``: zero and force-free above J_b (so small strains never see
  it), finite and restoring at J ≤ 0. A spring lattice alone cannot tell a cell from its mirror
  image (every spring keeps its length), so without it an inverted cell is a rest state of the
  springs; the barrier makes it a state of positive energy with a force back.
  ``κ_b = BARRIER_SCALE · μ``, μ the shear modulus the springs carry.

Only full cells (all 8 corners exist) carry either term, as only they carry full spring shares;
nodes in no full cell keep springs only. Neither term is damped (Rayleigh β damps the springs).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["BARRIER_J", "BARRIER_SCALE", "CORNER_SIGNS", "CellVolumes", "grid_cells", "cell_state",
           "centre_deformation", "volume_forces", "volume_energy", "corner_jacobians", "inverted_cells",
           "describe_inverted", "rest_product", "rest_stiffness_triplets", "frequency_terms",
           "corner_tets", "barrier_envelope_product", "barrier_envelope_triplets"]

#: J below which a corner's barrier acts (dimensionless; measured in docs/ACCURACY.md section 7).
BARRIER_J = 0.7
#: the barrier's modulus over the material's shear modulus μ (measured in docs/ACCURACY.md
#: section 7: the smallest multiple that leaves no cell of the hanging cantilevers inverted).
BARRIER_SCALE = 12.0

#: (8, 3) the sign vector s_c of corner c = dx + 2 dy + 4 dz.
CORNER_SIGNS = np.array([[2 * dx - 1, 2 * dy - 1, 2 * dz - 1]
                         for dz, dy, dx in product((0, 1), repeat=3)], dtype=np.float64)
#: (8, 3) corner c's neighbour along axis k inside the cell: c with bit k flipped.
_CORNER_NEIGHBOURS = np.array([[c ^ (1 << k) for k in range(3)] for c in range(8)], dtype=np.int64)
#: (8, 4) the tet of corner c: c, then its neighbours along x, y, z.
_CORNER_TETS = np.concatenate([np.arange(8)[:, None], _CORNER_NEIGHBOURS], axis=1)
_CORNER_TETS.setflags(write=False)  # (shared: corner_tets returns it, hessian.TET_CORNERS is it)


@dataclass(frozen=True, eq=False)
class CellVolumes:
    """The full cells of a grid body and their volumetric constants (immutable); as a physics term
    :class:`deformgl.sim.terms.volume.term.VolumeTerm`.

    Attributes:
        corners: (C, 8) int64 node numbers of each cell's corners, corner ``dx + 2 dy + 4 dz``.
        spacing: h in m (the cells are cubes of side h at rest).
        volume_modulus: κ = λ − μ in Pa (>= 0): the volumetric term's modulus.
        barrier_modulus: κ_b in Pa (>= 0): the corner barrier's modulus.
        barrier_j: J_b, the corner Jacobian below which the barrier acts (0 < J_b < 1).
    """

    corners: np.ndarray
    spacing: float
    volume_modulus: float
    barrier_modulus: float
    barrier_j: float = BARRIER_J

    def __post_init__(self) -> None:
        corners = np.array(self.corners, dtype=np.int64).reshape(-1, 8)
        corners.setflags(write=False)
        object.__setattr__(self, "corners", corners)
        for key in ("spacing", "volume_modulus", "barrier_modulus", "barrier_j"):
            value = float(getattr(self, key))
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"CellVolumes.{key} must be a finite number >= 0, got {value}")
            object.__setattr__(self, key, value)
        if not self.spacing > 0 or not 0 < self.barrier_j < 1:
            raise ValueError(f"CellVolumes: spacing {self.spacing} must be > 0 and barrier_j "
                             f"{self.barrier_j} in (0, 1)")

    @property
    def count(self) -> int:
        """Number of cells C."""
        return int(self.corners.shape[0])

    @property
    def volume(self) -> float:
        """Rest volume of a cell, h^3 in m^3."""
        return self.spacing ** 3


def grid_cells(occupied: np.ndarray, index: np.ndarray, among: np.ndarray | None = None) -> np.ndarray:
    """(C, 8) corner node numbers of every full cell of a node grid (``NodeGrid.occupied`` and
    ``NodeGrid.index``, -1 where no node), in C order of the cell's lower corner (a, b, c);
    ``among`` ((nx-1, ny-1, nz-1) bool), if given: only the full cells it marks."""
    nx, ny, nz = occupied.shape
    shape = (max(nx - 1, 0), max(ny - 1, 0), max(nz - 1, 0))
    full = np.ones(shape, bool) if among is None else np.array(among, bool)
    for dx, dy, dz in product((0, 1), repeat=3):
        full &= occupied[dx:nx - 1 + dx, dy:ny - 1 + dy, dz:nz - 1 + dz]
    a, b, c = np.nonzero(full)
    corners = np.empty((len(a), 8), np.int64)
    for corner, (dz, dy, dx) in enumerate(product((0, 1), repeat=3)):
        corners[:, corner] = index[a + dx, b + dy, c + dz]
    return corners


def _centre_gradient(spacing: float) -> np.ndarray:
    """(8, 3) G_c = s_c / (4h): the trilinear shape functions' gradients at the centre."""
    return CORNER_SIGNS / (4.0 * spacing)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.cross(a, b)


def centre_deformation(corners: np.ndarray, spacing: float, x: np.ndarray) -> np.ndarray:
    """(C, 3, 3) the trilinear map's deformation gradient at each cell's centre,
    ``F = Σ_c x_c ⊗ G_c`` over the cells' corners ((C, 8) node numbers) of side ``spacing``."""
    return np.einsum("cai,aj->cij", np.asarray(x)[corners], _centre_gradient(spacing))


def cell_state(cells: CellVolumes, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J at each cell's centre and cof(F) there: ((C,), (C, 3, 3))."""
    f = centre_deformation(cells.corners, cells.spacing, x)
    cols = f[:, :, 0], f[:, :, 1], f[:, :, 2]
    cof = np.stack([_cross(cols[1], cols[2]), _cross(cols[2], cols[0]), _cross(cols[0], cols[1])], axis=2)
    j = np.einsum("ci,ci->c", cols[0], cof[:, :, 0])
    return j, cof


def corner_jacobians(cells: CellVolumes, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """det F_c at every corner, (C, 8), and its gradients d det / d e_k, (C, 8, 3, 3) (axis 2: k)."""
    xc = x[cells.corners]                                     # (C, 8, 3)
    e = (xc[:, _CORNER_NEIGHBOURS, :] - xc[:, :, None, :]) * (-CORNER_SIGNS)[None, :, :, None]
    e /= cells.spacing                                        # (C, 8, 3 edges, 3)
    grads = np.stack([_cross(e[:, :, 1], e[:, :, 2]), _cross(e[:, :, 2], e[:, :, 0]),
                      _cross(e[:, :, 0], e[:, :, 1])], axis=2)
    det = np.einsum("cki,cki->ck", e[:, :, 0], grads[:, :, 0])
    return det, grads


def volume_forces(cells: CellVolumes, x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) force in N of both terms on every node (added to ``out`` when given, which must be
    (N, 3) float64; else a new array of len(x) rows)."""
    n = len(x)
    total = np.zeros((n, 3)) if out is None else out
    if cells.count == 0:
        return total
    v = cells.volume
    per_corner = np.zeros((cells.count, 8, 3))
    if cells.volume_modulus > 0:
        j, cof = cell_state(cells, x)
        p = -v * cells.volume_modulus * (j - 1.0)             # -V dPsi/dJ
        per_corner += p[:, None, None] * np.einsum("cij,aj->cai", cof, _centre_gradient(cells.spacing))
    if cells.barrier_modulus > 0:
        det, grads = corner_jacobians(cells, x)
        active = det < cells.barrier_j
        if active.any():
            # -V/8 dPsi_b/dJ = V/8 kappa_b (J_b - J) > 0 on active corners; dJ/dx by the chain rule
            q = np.where(active, v / 8.0 * cells.barrier_modulus * (cells.barrier_j - det), 0.0)
            dj_de = grads / cells.spacing                     # (C, 8, k, 3): d det / d (edge k vector)
            signed = dj_de * (-CORNER_SIGNS)[None, :, :, None]   # d det / d x of neighbour k
            contrib = q[:, :, None, None] * signed           # (C, 8, k, 3)
            per_corner -= contrib.sum(axis=2)                # the corner itself: minus the sum
            for k in range(3):  # flipping bit k is its own inverse: corner d gets what d ^ 2^k gives
                per_corner += contrib[:, _CORNER_NEIGHBOURS[:, k], k]
    flat = cells.corners.reshape(-1)
    forces = per_corner.reshape(-1, 3)
    for c in range(3):
        total[:, c] += np.bincount(flat, weights=forces[:, c], minlength=n)
    return total


def volume_energy(cells: CellVolumes, x: np.ndarray) -> float:
    """Stored energy of both terms in J (the forces are its negative gradient)."""
    if cells.count == 0:
        return 0.0
    j, _ = cell_state(cells, x)
    energy = cells.volume * cells.volume_modulus / 2.0 * float(np.sum((j - 1.0) ** 2))
    det, _ = corner_jacobians(cells, x)
    gap = np.maximum(cells.barrier_j - det, 0.0)
    return energy + cells.volume / 8.0 * cells.barrier_modulus / 2.0 * float(np.sum(gap ** 2))


def inverted_cells(corners: ArrayLike, spacing: float, x: np.ndarray) -> np.ndarray:
    """(C,) bool: cells whose trilinear map has a Jacobian determinant <= 0 at one of its corners
    (or a non-finite one): the inversion census."""
    cells = CellVolumes(np.asarray(corners), spacing, 0.0, 0.0)
    if cells.count == 0:
        return np.zeros(0, bool)
    det, _ = corner_jacobians(cells, np.asarray(x, dtype=np.float64))
    return ~np.all(det > 0, axis=1)


def describe_inverted(cells: CellVolumes, x: np.ndarray, ijk: np.ndarray | None = None) -> tuple[int, str]:
    """The inversion census of positions ``x``: how many cells are inverted (:func:`inverted_cells`)
    and a phrase naming the count and the first one, e.g. ``"3 of 640 cells inverted (first: the
    cell at grid (0, 4, 1))"`` (``ijk``: the nodes' grid indices, for the cell's lower corner);
    ``(0, "")`` when none is."""
    bad = inverted_cells(cells.corners, cells.spacing, x)
    count = int(bad.sum())
    if count == 0:
        return 0, ""
    first = int(np.argmax(bad))
    corner = int(cells.corners[first, 0])
    where = (f"the cell at grid {tuple(int(v) for v in ijk[corner])}" if ijk is not None
             else f"cell {first}, lower corner node {corner}")
    return count, f"{count} of {cells.count} cells inverted (first: {where})"


def rest_product(cells: CellVolumes, dx: np.ndarray) -> np.ndarray:
    """K_v dx: the centre term's stiffness at rest (``V kappa g g^T`` per cell, g the 24-vector of
    the G_c; the barrier is inactive at rest) times displacements ``dx`` (N, 3); (N, 3)."""
    out = np.zeros_like(np.asarray(dx, dtype=np.float64))
    if cells.count == 0 or cells.volume_modulus == 0:
        return out
    g = _centre_gradient(cells.spacing)
    div = np.einsum("cai,ai->c", dx[cells.corners], g)                 # g . dx = tr(grad u) per cell
    per_corner = (cells.volume * cells.volume_modulus * div)[:, None, None] * g[None, :, :]
    for c in range(3):
        out[:, c] += np.bincount(cells.corners.reshape(-1), weights=per_corner[:, :, c].reshape(-1),
                                 minlength=len(out))
    return out


def rest_stiffness_triplets(cells: CellVolumes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, cols, values) of the centre term's (3N, 3N) stiffness at rest (see
    :func:`rest_product`), for a scipy.sparse matrix (duplicates summed)."""
    if cells.count == 0 or cells.volume_modulus == 0:
        empty = np.zeros(0, np.int64)
        return empty, empty, np.zeros(0)
    g = _centre_gradient(cells.spacing).reshape(-1)                    # (24,)
    block = cells.volume * cells.volume_modulus * np.outer(g, g)       # (24, 24)
    dof = (3 * cells.corners[:, :, None] + np.arange(3)).reshape(cells.count, 24)
    rows = np.broadcast_to(dof[:, :, None], (cells.count, 24, 24)).reshape(-1)
    cols = np.broadcast_to(dof[:, None, :], (cells.count, 24, 24)).reshape(-1)
    values = np.broadcast_to(block, (cells.count, 24, 24)).reshape(-1)
    return rows, cols, values


def frequency_terms(cells: CellVolumes, count: int, *, barrier: bool = False) -> np.ndarray:
    """(N,) per node, the cells' share of a Gershgorin-type bound of ``x^T K x``; add it to
    ``2 sum_j k_ij`` before dividing by the mass.

    The centre term: ``1.5 kappa h`` per full cell at the node (``V kappa (g . x)^2 <= V kappa
    |g|^2 |x|^2`` with ``|g|^2 = 3 / (2 h^2)``). With ``barrier``, also the barrier's envelope
    (:func:`barrier_envelope_product`): a corner term ``w (sum_t g_t . x_t)^2`` is at most
    ``w (sum_u |g_u|) sum_t |g_t| |x_t|^2`` (Cauchy-Schwarz weighted by ``|g_t|``), ``|g_t| <=
    |D_t|`` at principal stretches <= 1, and each node of a cell is once the corner
    (``|D| = sqrt(3)/h``) and three times a neighbour (``1/h``) of its 8 terms:
    ``(sqrt(3) + 3)^2 / 8 kappa_b h`` per full cell at the node."""
    terms = np.zeros(count)
    if not cells.count:
        return terms
    per_cell = 1.5 * cells.volume_modulus * cells.spacing
    if barrier:
        per_cell += (np.sqrt(3.0) + 3.0) ** 2 / 8.0 * cells.barrier_modulus * cells.spacing
    if per_cell > 0:
        terms += per_cell * np.bincount(cells.corners.reshape(-1), minlength=count)
    return terms


def corner_tets(spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """The corners' barrier terms as maps of four nodes: (8, 4) the tet of corner c (c, then its
    neighbours c ^ 1, c ^ 2, c ^ 4 along x, y, z) and (8, 4, 3) the weights D_t in 1/m with
    ``F_c = sum_t x_t (x) D_t`` (``s_c / h`` on c, ``-s_c[k] / h e_k`` on the neighbour along k):
    ``dJ_c/dx_t = cof(F_c) D_t``, D_t itself at the rest geometry."""
    tets = _CORNER_TETS
    grads = np.zeros((8, 4, 3))
    grads[:, 0] = CORNER_SIGNS / spacing
    for k in range(3):
        grads[:, 1 + k, k] = -CORNER_SIGNS[:, k] / spacing
    return tets, grads


def barrier_envelope_product(cells: CellVolumes, dx: np.ndarray) -> np.ndarray:
    """K_b dx: the barrier's stiffness where it is strongest in compression, (N, 3).

    Every corner's barrier active (``J_c < J_b``, as when the body is crushed around a node)
    with the rest geometry's gradients (cof F_c = I: at principal stretches <= 1 no entry of
    ``dJ_c/dx`` is larger), the Gauss-Newton part ``V/8 kappa_b g g^T`` per corner. The
    explicit integrators' dt bound adds it to the rest stiffness (:mod:`deformgl.sim.limits`):
    a body driven towards inversion meets it, and a dt set by the rest stiffness alone blows
    up there (docs/ACCURACY.md section 7)."""
    out = np.zeros((len(dx), 3))
    if cells.count == 0 or cells.barrier_modulus == 0:
        return out
    tets, grads = corner_tets(cells.spacing)
    nodes = cells.corners[:, tets]                                     # (C, 8, 4)
    dj = np.einsum("ctk,tk->ct", np.asarray(dx, np.float64)[nodes].reshape(cells.count, 8, 12),
                   grads.reshape(8, 12))                               # g . dx per corner
    per_node = (cells.volume / 8.0 * cells.barrier_modulus * dj)[:, :, None, None] * grads[None]
    for c in range(3):
        out[:, c] += np.bincount(nodes.reshape(-1), weights=per_node[..., c].reshape(-1), minlength=len(out))
    return out


def barrier_envelope_triplets(cells: CellVolumes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, cols, values) of :func:`barrier_envelope_product`'s (3N, 3N) matrix, for a
    scipy.sparse or dense matrix (duplicates summed)."""
    if cells.count == 0 or cells.barrier_modulus == 0:
        empty = np.zeros(0, np.int64)
        return empty, empty, np.zeros(0)
    tets, grads = corner_tets(cells.spacing)
    g = grads.reshape(8, 12)
    block = cells.volume / 8.0 * cells.barrier_modulus * g[:, :, None] * g[:, None, :]   # (8, 12, 12)
    dof = (3 * cells.corners[:, tets][..., None] + np.arange(3)).reshape(cells.count, 8, 12)
    shape = (cells.count, 8, 12, 12)
    rows = np.broadcast_to(dof[:, :, :, None], shape).reshape(-1)
    cols = np.broadcast_to(dof[:, :, None, :], shape).reshape(-1)
    return rows, cols, np.broadcast_to(block, shape).reshape(-1)
