"""Grids of trilinear cells, float64 NumPy (Knuth, Kohlhammer & Kuijper, sections 3.3 and 4.1).

:class:`Trilinear` is a uniform grid of cells over a bounding box of its content (section 4):
``(nx + 1, ny + 1, nz + 1)`` lattice points, one cell = one cuboid of Knuth, Kohlhammer &
Kuijper, eq. 1. It is built from corners, from an affine 4x4 matrix, or by sampling any Python
function; composition (:func:`compose`, section 4.1) transforms the child's lattice points by
the parent at the higher of the two resolutions. The GLSL twin is ``shaders/trilinear/grid.glsl``.
"""

from __future__ import annotations

import numpy as np

from deformgl.errors import InputError
from deformgl.trilinear.cuboid import (
    CORNERS, LINEAR_RTOL, MAX_COMPOSED_CELLS, Box, Function, apply_coefficients, coefficient_matrix,
    corner_weight_gradients, corner_weights, grid_corners, is_linear_coefficients, unit_lattice,
)


_FLOAT32_MAX = float(np.finfo(np.float32).max)


def _check_function_output(name: str, out: np.ndarray, n: int) -> np.ndarray:
    out = np.asarray(out, dtype=np.float64)
    if out.shape != (n, 3):
        raise InputError(f"{name}: expected ({n}, 3) points, got shape {out.shape}")
    if not np.all(np.isfinite(out)):
        raise InputError(f"{name}: returned non-finite points")
    return out


class Trilinear:
    """A grid of trilinear cells over a box: a trilinear transformation (one cell) or an
    approximated deformation (section 3.3). Immutable by convention.

    Args:
        box: the domain; its content is mapped to the unit cube (section 4).
        points: (nx + 1, ny + 1, nz + 1, 3) float64 image of the lattice points, axis order
            x, y, z; cell (i, j, k) is the cuboid with corners ``points[i:i+2, j:j+2, k:k+2]``.
        error: stated largest distance to the function the grid approximates (0 = exact).

    Raises:
        InputError: a shape with fewer than 2 points on an axis, or non-finite points or points
            beyond float32 (drawn in float32, they would be infinite).
    """

    __slots__ = ("box", "points", "error")

    def __init__(self, box: Box, points: np.ndarray, error: float = 0.0) -> None:
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 4 or p.shape[-1] != 3 or min(p.shape[:3]) < 2:
            raise InputError(f"grid points must have shape (nx+1, ny+1, nz+1, 3) with n >= 1, got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise InputError("grid points must be finite")
        if np.abs(p).max() > _FLOAT32_MAX:  # infinite on the GPU (and the linearity test's norms overflow)
            raise InputError(f"grid points must be within float32 (|v| <= {_FLOAT32_MAX:.6g}), got {np.abs(p).max():.6g}")
        self.box = box
        self.points = p
        self.error = float(error)

    # ---- construction -------------------------------------------------------------------------
    @classmethod
    def from_corners(cls, box: Box, corners: np.ndarray) -> Trilinear:
        """One cell from its (8, 3) corners in Knuth, Kohlhammer & Kuijper, eq. 1 order."""
        c = np.asarray(corners, dtype=np.float64)
        if c.shape != (8, 3):
            raise InputError(f"a cuboid needs (8, 3) corners, got {c.shape}")
        return cls(box, c.reshape(2, 2, 2, 3).transpose(2, 1, 0, 3))

    @classmethod
    def identity(cls, box: Box, cells: tuple[int, int, int] = (1, 1, 1)) -> Trilinear:
        """The identity over ``box``."""
        return cls(box, box.from_unit(unit_lattice(cells)))

    @classmethod
    def from_affine(cls, matrix: np.ndarray, box: Box, cells: tuple[int, int, int] = (1, 1, 1)) -> Trilinear:
        """Any affine 4x4 matrix over ``box`` as a trilinear transform (exact: a parallelepiped).

        Raises:
            InputError: not a finite 4x4 matrix with last row (0, 0, 0, 1).
        """
        m = check_affine(matrix)
        lattice = box.from_unit(unit_lattice(cells))
        return cls(box, lattice @ m[:3, :3].T + m[:3, 3])

    @classmethod
    def from_function(cls, f: Function, box: Box, cells: tuple[int, int, int], *,
                      samples_per_cell: int = 3, name: str = "deformation") -> Trilinear:
        """Sample any function ``f((N, 3)) -> (N, 3)`` at the lattice points (section 3.3).

        The approximation error against ``f`` is measured on ``samples_per_cell``^3 points per
        cell (cell centres included when odd) and stored as :attr:`error`.
        """
        cells = _check_cells(cells)
        lattice = box.from_unit(unit_lattice(cells)).reshape(-1, 3)
        pts = _check_function_output(name, f(lattice), len(lattice))
        grid = cls(box, pts.reshape(*(n + 1 for n in cells), 3))
        grid.error = approximation_error(grid, f, samples_per_cell=samples_per_cell)
        return grid

    # ---- properties ---------------------------------------------------------------------------
    @property
    def cells(self) -> tuple[int, int, int]:
        """(nx, ny, nz) cell counts."""
        nx, ny, nz = self.points.shape[:3]
        return nx - 1, ny - 1, nz - 1

    @property
    def corners(self) -> np.ndarray:
        """(8, 3) outer corners of the grid in Knuth, Kohlhammer & Kuijper, eq. 1 order."""
        return grid_corners(self.points)

    def coefficients(self) -> np.ndarray:
        """Knuth, Kohlhammer & Kuijper, Eq. 2 for every cell: (nx, ny, nz, 3, 8)."""
        p = self.points
        cell = np.stack([p[(i & 1):p.shape[0] - 1 + (i & 1), ((i >> 1) & 1):p.shape[1] - 1 + ((i >> 1) & 1),
                           ((i >> 2) & 1):p.shape[2] - 1 + ((i >> 2) & 1)] for i in range(8)], -2)
        return coefficient_matrix(cell)

    def is_linear(self, rtol: float = LINEAR_RTOL) -> bool:
        """Whether the whole grid is one affine map (3.2): for one cell, the left half of ``C``
        is zero; for a grid, additionally every lattice point lies on that parallelepiped."""
        corners = self.corners
        c = coefficient_matrix(corners)
        if not bool(is_linear_coefficients(c, rtol)):
            return False
        if self.cells == (1, 1, 1):
            return True
        fit = apply_coefficients(c, unit_lattice(self.cells).reshape(-1, 3)).reshape(self.points.shape)
        return bool(np.all(lattice_matches(fit[None], self.points[None], rtol)))

    def affine_matrix(self) -> np.ndarray:
        """The 4x4 affine map of the box's input coordinates given by the outer corners' right
        half of ``C`` (the transform itself when :meth:`is_linear`)."""
        c = coefficient_matrix(self.corners)
        m = np.identity(4)
        lin = np.stack([c[:, 6], c[:, 5], c[:, 4]], 1) / self.box.size  # columns x, y, z
        m[:3, :3] = lin
        m[:3, 3] = c[:, 7] - lin @ self.box.lo
        return m

    # ---- evaluation ---------------------------------------------------------------------------
    def _locate(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Containing cell (N, 3) int (boundary cells extended outwards) and the position in it."""
        n = np.array(self.cells, dtype=np.float64)
        g = u * n
        cell = np.minimum(np.maximum(np.floor(g), 0.0), n - 1.0)
        return cell.astype(np.intp), g - cell

    def _cell_corners(self, cell: np.ndarray) -> np.ndarray:
        """(N, 8, 3) corners of the cells (N, 3), gathered through flat indices."""
        _, sy, sz = self.points.shape[:3]
        flat = (cell[:, 0] * sy + cell[:, 1]) * sz + cell[:, 2]
        offsets = (CORNERS[:, 0] * sy + CORNERS[:, 1]) * sz + CORNERS[:, 2]
        return np.take(self.points.reshape(-1, 3), flat[:, None] + offsets.astype(np.intp), axis=0)

    def at_unit(self, u: np.ndarray) -> np.ndarray:
        """Evaluate at (N, 3) unit-cube coordinates: Knuth, Kohlhammer & Kuijper, eq. 1 in the containing cell. Points outside
        the box use the polynomial of the nearest boundary cell (eq. 4 extrapolates likewise)."""
        u = np.asarray(u, dtype=np.float64).reshape(-1, 3)
        cell, f = self._locate(u)
        if self.points.shape[:3] == (2, 2, 2):  # one cuboid: Knuth, Kohlhammer & Kuijper, eq. 4 with C of eq. 2
            return apply_coefficients(coefficient_matrix(self.corners), f)
        return (corner_weights(f)[:, None, :] @ self._cell_corners(cell))[:, 0]

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Transform (N, 3) points of the box (float64)."""
        return self.at_unit(self.box.to_unit(np.asarray(points, dtype=np.float64).reshape(-1, 3)))

    def jacobian(self, points: np.ndarray) -> np.ndarray:
        """Analytic Jacobian d T / d p of the containing cell at (N, 3) points: (N, 3, 3)."""
        u = self.box.to_unit(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        cell, f = self._locate(u)
        dw = corner_weight_gradients(f)                       # (N, 3, 8)
        d = np.einsum("nac,ncd->nda", dw, self._cell_corners(cell))  # (N, 3 out, 3 in) per grid unit
        return d * (np.array(self.cells) / self.box.size)[None, None, :]

    def resample(self, cells: tuple[int, int, int]) -> Trilinear:
        """The same transform sampled on another lattice (exact when ``cells`` are multiples)."""
        cells = _check_cells(cells)
        if cells == self.cells:
            return self
        pts = self.at_unit(unit_lattice(cells).reshape(-1, 3)).reshape(*(n + 1 for n in cells), 3)
        return Trilinear(self.box, pts, self.error)

    def lipschitz(self, points: np.ndarray) -> float:
        """Largest Frobenius norm of the Jacobian at (N, 3) points: a local Lipschitz bound."""
        return float(np.linalg.norm(self.jacobian(points), axis=(1, 2)).max())

    def image_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) of the image: trilinear cells lie in the hull of their corners."""
        p = self.points.reshape(-1, 3)
        return p.min(0), p.max(0)


def lattice_matches(fit: np.ndarray, points: np.ndarray, rtol: float = LINEAR_RTOL) -> np.ndarray:
    """Whether stacked lattices (k, nx+1, ny+1, nz+1, 3) equal ``fit`` within ``rtol`` times
    their size plus a few float64 roundings of their coordinates' magnitude; (k,) bool."""
    k = len(points)
    flat = points.reshape(k, -1, 3)
    size = np.linalg.norm(flat - flat[:, :1], axis=2).max(1)
    rounding = 64.0 * np.finfo(np.float64).eps * np.abs(flat).max((1, 2))
    return np.abs(fit - points).reshape(k, -1).max(1) <= rtol * size + rounding


def check_affine(matrix: np.ndarray) -> np.ndarray:
    """Validate a 4x4 affine matrix; returns it as float64.

    Raises:
        InputError: wrong shape, non-finite entries, or a projective last row.
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise InputError(f"an affine transform needs a finite 4x4 matrix, got shape {m.shape}")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=1e-12):
        raise InputError(f"affine matrix has a projective last row {m[3].tolist()}; must be (0, 0, 0, 1)")
    return m


def _check_cells(cells: tuple[int, int, int]) -> tuple[int, int, int]:
    out = tuple(int(n) for n in cells)
    if len(out) != 3 or min(out) < 1:
        raise InputError(f"a grid needs three cell counts >= 1, got {cells}")
    return out


def sample_lattice(cells: tuple[int, int, int], samples_per_cell: int) -> np.ndarray:
    """(M, 3) unit-cube points, ``samples_per_cell``^3 evenly inside every cell (centres when odd)."""
    s = int(samples_per_cell)
    axes = [((np.arange(n)[:, None] + (np.arange(s)[None, :] + 0.5) / s) / n).ravel() for n in cells]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def approximation_error(grid: Trilinear, f: Function, *, samples_per_cell: int = 3) -> float:
    """Largest distance between the grid and the exact function ``f`` on sample points."""
    u = sample_lattice(grid.cells, samples_per_cell)
    p = grid.box.from_unit(u)
    exact = _check_function_output("deformation", f(p), len(p))
    return float(np.linalg.norm(grid.at_unit(u) - exact, axis=1).max())


# ---- composition (section 4.1) -------------------------------------------------------------------
def crossed_cells(parent: Trilinear, image: np.ndarray) -> np.ndarray:
    """How many of the parent's cells each lattice axis of ``image`` crosses.

    Args:
        parent: the transform that will be applied to ``image``.
        image: (nx+1, ny+1, nz+1, 3) lattice points in the parent's input space.

    Returns:
        (3,) float: for axis a, the largest sum over a lattice line along a of the L-infinity
        length of its segments measured in parent cells.
    """
    q = (image - parent.box.lo) / parent.box.size * np.array(parent.cells)
    out = np.zeros(3)
    for a in range(3):
        seg = np.abs(np.diff(q, axis=a)).max(-1)
        out[a] = seg.sum(axis=a).max()
    return out


def composition_cells(parent: Trilinear, child_cells: tuple[int, int, int], image: np.ndarray) -> tuple[int, int, int]:
    """Resolution of ``parent * child`` (4.1): the higher of the two, measured over the child.

    Per axis, the number of parent cells the child's image crosses (at most the parent's finest
    axis) is rounded up to a multiple of the child's cell count, so that the child's own cells
    stay exactly represented; the result is capped at :data:`MAX_COMPOSED_CELLS`.
    """
    crossed = crossed_cells(parent, image)
    finest = max(parent.cells)
    out = []
    for a in range(3):
        n = child_cells[a]
        need = min(int(np.ceil(crossed[a] - 1e-6)), finest)
        out.append(min(n * max(1, -(-need // n)), max(MAX_COMPOSED_CELLS, n)))
    return tuple(out)  # type: ignore[return-value]


def compose(parent: Trilinear, child: Trilinear, *, between: np.ndarray | None = None,
            estimate_error: bool = False) -> Trilinear:
    """``C = G * L`` (section 4.1): the child's lattice transformed by the parent.

    The child is resampled to the higher resolution first (:func:`composition_cells`); a parent
    of one cell (linear or not) keeps the child's resolution.

    Args:
        parent: ``G``, the more global transform.
        child: ``L``, the more local one; the result has its box.
        between: optional 4x4 affine applied between them: ``C = G * between * L``.
        estimate_error: also state the error of ``C``: a bound that holds
            (:func:`composition_bound`, :mod:`deformgl.trilinear.errorbound`), not a sampled estimate.

    Returns:
        The composed transform over ``child.box``.
    """
    a = np.identity(4) if between is None else check_affine(between)

    def image_of(grid: Trilinear) -> np.ndarray:
        return grid.points @ a[:3, :3].T + a[:3, 3]

    cells = composition_cells(parent, child.cells, image_of(child))
    fine = child.resample(cells)
    pts = parent(image_of(fine).reshape(-1, 3)).reshape(fine.points.shape)
    out = Trilinear(child.box, pts, error=parent.error + child.error)
    if estimate_error:
        out.error = composition_bound(parent, child, out, between=a)
    return out


def composition_error(parent: Trilinear, child: Trilinear, composed: Trilinear, *,
                      between: np.ndarray | None = None, samples_per_cell: int = 3) -> float:
    """An estimate (not a bound) of the error of ``composed`` against the exact functions behind
    parent and child: ``parent.error + lip(parent) * child.error + max |C - G(L)|`` on
    ``samples_per_cell``^3 points per cell, with the parent's Jacobian norm along the child's image
    as the Lipschitz factor. It can be low (issue 17: 25 % below the true maximum for two stacked
    random lattices); :func:`composition_bound` is the bound that holds."""
    a = np.identity(4) if between is None else check_affine(between)
    u = sample_lattice(composed.cells, samples_per_cell)
    inner = child.at_unit(u) @ a[:3, :3].T + a[:3, 3]
    exact_chain = parent(inner)
    sampling = float(np.linalg.norm(composed.at_unit(u) - exact_chain, axis=1).max())
    lip = parent.lipschitz(inner) * float(np.linalg.norm(a[:3, :3], 2))
    return parent.error + lip * child.error + sampling


# ---- the bound of composition (deformgl.trilinear.errorbound explains it) -------------------------
#: Fine cells handled per vectorized chunk.
_CHUNK = 4096


def lipschitz_bound(grid: Trilinear) -> float:
    """An upper bound of the Jacobian's spectral norm over every cell of ``grid`` (input units):
    per cell, the root sum of squares over axes of the longest of the 4 edges along that axis
    divided by the cell's width."""
    p = grid.points
    width = grid.box.size / np.array(grid.cells)
    total = np.zeros(np.array(grid.cells))
    for a in range(3):
        d = np.diff(p, axis=a)
        length = np.linalg.norm(d, axis=-1) / width[a]
        # the 4 edges of a cell along axis a: the 2 x 2 neighbours across the other axes
        others = [b for b in range(3) if b != a]
        m = length
        for b in others:
            m = np.maximum(np.take(m, range(m.shape[b] - 1), axis=b), np.take(m, range(1, m.shape[b]), axis=b))
        total += m ** 2
    return float(np.sqrt(total.max()))


def _interpolation_bound(parent: Trilinear, corners: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Per fine cell: the bound of the module docstring. ``corners`` (k, 8, 3) are the cells'
    corners mapped by ``A L`` into the parent's input space, ``centres`` (k, 3) their centres."""
    n = np.array(parent.cells)
    lo, size = parent.box.lo, parent.box.size
    q = (corners - lo) / size * n                                # parent grid units
    qlo, qhi = q.min(1), q.max(1)
    # interior lattice planes crossed by each box, padded per axis to the chunk's largest count
    first = np.clip(np.floor(qlo) + 1, 1, n - 1)
    last = np.clip(np.ceil(qhi) - 1, 1, n - 1)
    count = np.where((last >= first) & (n > 1), last - first + 1, 0).astype(int)
    axes = []
    for a in range(3):
        m = int(count[:, a].max())
        planes = first[:, a:a + 1] + np.arange(m)[None, :]
        planes = np.where(np.arange(m)[None, :] < count[:, a:a + 1], planes, qhi[:, a:a + 1])
        planes = np.clip(planes, qlo[:, a:a + 1], qhi[:, a:a + 1])
        axes.append(np.concatenate([qlo[:, a:a + 1], planes, qhi[:, a:a + 1]], axis=1))
    k = len(q)
    vx, vy, vz = axes
    verts = np.stack(np.broadcast_arrays(vx[:, :, None, None], vy[:, None, :, None], vz[:, None, None, :]), -1)
    verts = verts.reshape(k, -1, 3) / n * size + lo              # back to input units
    # l: the affine map fitted to G at the pieces' corners (least squares; any l gives a bound)
    gv = parent(verts.reshape(-1, 3)).reshape(verts.shape)
    design = np.concatenate([verts - centres[:, None, :], np.ones(verts.shape[:2] + (1,))], axis=2)  # (k, P, 4)
    dt = design.transpose(0, 2, 1)
    coef = np.linalg.solve(dt @ design + 1e-12 * np.identity(4), dt @ gv)                 # (k, 4, 3)

    def residual(y: np.ndarray, gy: np.ndarray | None = None) -> np.ndarray:
        gy = parent(y.reshape(-1, 3)).reshape(y.shape) if gy is None else gy
        d = np.concatenate([y - centres[:, None, :], np.ones(y.shape[:2] + (1,))], axis=2)
        return np.linalg.norm(gy - d @ coef, axis=-1).max(1)

    bound = residual(verts, gv) + residual(corners)
    smooth = ~count.any(axis=1)
    if smooth.any():
        bound[smooth] = np.minimum(bound[smooth], _smooth_bound(parent, q[smooth], qlo[smooth], qhi[smooth]))
    return bound


def _smooth_bound(parent: Trilinear, q: np.ndarray, qlo: np.ndarray, qhi: np.ndarray) -> np.ndarray:
    """Per fine cell whose image lies in one parent cell (corners ``q`` (k, 8, 3) in parent grid
    units): the tensor-product interpolation bound ``1/8 sum_a sup |g_aa|`` with
    ``g_aa = D^2 G[M_a, M_a]`` (``M`` is linear along each axis, so ``M_aa = 0``; ``G``'s own
    second derivatives along an axis vanish), each factor bounded over the cell."""
    n = np.array(parent.cells)
    cell = np.clip(np.floor(qlo), 0, n - 1).astype(np.intp)
    c = parent.coefficients()[cell[:, 0], cell[:, 1], cell[:, 2]]          # (k, 3, 8)
    reach = np.maximum(np.abs(qlo - cell), np.abs(qhi - cell))               # sup |t_r| over the box
    # d2 G / d t_p d t_q = c_pq + c_xyz t_r; columns of v: 0 xyz, 1 yz, 2 xz, 3 xy
    pairs = ((0, 1, 3, 2), (0, 2, 2, 1), (1, 2, 1, 0))                       # (p, q, column, r)
    d = {(p_, q_): np.abs(c[:, :, col]) + np.abs(c[:, :, 0]) * reach[:, r, None] for p_, q_, col, r in pairs}
    total = np.zeros((len(q), 3))
    for a in range(3):
        lo_idx = np.flatnonzero(((np.arange(8) >> a) & 1) == 0)
        edge = np.abs(q[:, lo_idx + (1 << a)] - q[:, lo_idx]).max(1)          # (k, 3): sup |M_a^p|
        for (p_, q_), dpq in d.items():
            total += 2.0 * dpq * (edge[:, p_] * edge[:, q_])[:, None]
    return np.linalg.norm(total / 8.0, axis=1)


def _lattice_bound(parent: Trilinear, child: Trilinear, a: np.ndarray, fine: np.ndarray) -> float:
    """Largest per-cell bound (:func:`_interpolation_bound`) of the grid of ``fine`` cells that
    interpolates ``G(A(L))`` at its lattice points over the child's box."""
    lattice = unit_lattice((int(fine[0]), int(fine[1]), int(fine[2])))         # (nx+1, ny+1, nz+1, 3)
    image = child.at_unit(lattice.reshape(-1, 3)).reshape(lattice.shape) @ a[:3, :3].T + a[:3, 3]
    index = np.stack(np.meshgrid(*(np.arange(n) for n in fine), indexing="ij"), -1).reshape(-1, 3)
    worst = 0.0
    for s in range(0, len(index), _CHUNK):
        idx = index[s:s + _CHUNK]
        c = idx[:, None, :] + CORNERS.astype(np.intp)[None]      # (k, 8, 3)
        corners = image[c[..., 0], c[..., 1], c[..., 2]]
        centres = child.at_unit((idx + 0.5) / fine) @ a[:3, :3].T + a[:3, 3]
        worst = max(worst, float(_interpolation_bound(parent, corners, centres).max()))
    return worst


def composition_bound(parent: Trilinear, child: Trilinear, composed: Trilinear, *,
                      between: np.ndarray | None = None, subdivide: int = 3) -> float:
    """A bound on ``max |composed - G(A(L))|`` over ``composed.box``, plus the carried errors
    ``parent.error + lip(G) |A| child.error`` (:mod:`deformgl.trilinear.errorbound`).

    Each composed cell is split into ``subdivide``^3 sub-cells: ``composed - g`` is at most its
    largest value at the sub-lattice points (computed exactly) plus the bound of interpolating
    ``g`` on the sub-cells (the difference of the two interpolants is trilinear per sub-cell, so
    largest at sub-lattice points), which shrinks with the sub-cells. The cost grows with the
    sub-cells; grids of more than 8M / ``subdivide``^3 cells get fewer sub-cells (still a bound).

    Raises:
        InputError: ``composed`` is not over the child's box, or its cells are not whole
            multiples of the child's (a fine cell must lie inside one child cell).
    """
    a = np.identity(4) if between is None else check_affine(between)
    fine, base = np.array(composed.cells), np.array(child.cells)
    if np.any(fine % base) or not (np.array_equal(composed.box.lo, child.box.lo)
                                   and np.array_equal(composed.box.hi, child.box.hi)):
        raise InputError(f"composition_bound: the composed grid {tuple(fine)} over its box must refine the "
                         f"child's {tuple(base)} cells by whole multiples over the same box")
    # at most ~8M sub-cells: coarser sub-cells (a looser bound, still a bound) for huge grids
    s_ = max(1, min(int(subdivide), int((8e6 / float(np.prod(fine))) ** (1.0 / 3.0))))
    sub = fine * s_
    u = unit_lattice((int(sub[0]), int(sub[1]), int(sub[2]))).reshape(-1, 3)
    exact = parent(child.at_unit(u) @ a[:3, :3].T + a[:3, 3])
    sampled = float(np.linalg.norm(composed.at_unit(u) - exact, axis=1).max())
    stretch = lipschitz_bound(parent) * float(np.linalg.norm(a[:3, :3], 2))
    return parent.error + stretch * child.error + sampled + _lattice_bound(parent, child, a, sub)
