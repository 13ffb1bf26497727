"""Trilinear transformations and grids of them, float64 NumPy (Knuth, Kohlhammer & Kuijper).

A trilinear transformation maps the unit cube onto a cuboid given by eight corner points
``p0 ... p7`` (section 3.1). Corner ``i`` sits at unit-cube position ``(i & 1, i >> 1 & 1,
i >> 2 & 1)``, the order of eq. 1. Two equal forms:

* eq. 1: ``T(u) = sum_i w_i(u) p_i`` with the eight product weights :func:`corner_weights`;
* eq. 2-4: ``T(u) = C v(u)`` with the 3x8 coefficient matrix ``C`` (:func:`coefficient_matrix`)
  and the parameter vector ``v = (xyz, yz, xz, xy, z, y, x, 1)`` (:func:`parameter_vector`).

The right half of ``C`` is an affine 3x4 matrix; the left half is zero exactly when the cuboid
is a parallelepiped, i.e. the transformation is linear (3.2, :func:`is_linear_coefficients`).

:class:`Trilinear` is a uniform grid of such cells (3.3) over a bounding box of its content
(section 4): ``(nx + 1, ny + 1, nz + 1)`` lattice points, one cell = one cuboid of eq. 1. It is
built from corners, from an affine 4x4 matrix, or by sampling any Python function; composition
(4.1) transforms the child's lattice points by the parent at the higher of the two resolutions.
The GLSL twins are ``shaders/trilinear/cuboid.glsl`` and ``shaders/trilinear/grid.glsl``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from deformgl.errors import InputError

#: (8, 3) unit-cube position of corner i = x + 2y + 4z, the order of eq. 1.
CORNERS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64)

#: Rows of eq. 2: C^T = EQ2 @ (p0 ... p7), one row per entry of v (eq. 3).
EQ2 = np.array([
    [-1, 1, 1, -1, 1, -1, -1, 1],   # xyz: p7 - p6 - p5 + p4 - p3 + p2 + p1 - p0
    [1, 0, -1, 0, -1, 0, 1, 0],     # yz:  p6 - p4 - p2 + p0
    [1, -1, 0, 0, -1, 1, 0, 0],     # xz:  p5 - p4 - p1 + p0
    [1, -1, -1, 1, 0, 0, 0, 0],     # xy:  p3 - p2 - p1 + p0
    [-1, 0, 0, 0, 1, 0, 0, 0],      # z:   p4 - p0
    [-1, 0, 1, 0, 0, 0, 0, 0],      # y:   p2 - p0
    [-1, 1, 0, 0, 0, 0, 0, 0],      # x:   p1 - p0
    [1, 0, 0, 0, 0, 0, 0, 0],       # 1:   p0
], dtype=np.float64)

#: Default tolerance of the linearity test, relative to the size of the cuboid.
LINEAR_RTOL = 1e-9

#: Largest cell count per axis that composition refines to (section 4.1 resampling).
MAX_COMPOSED_CELLS = 256

Function = Callable[[np.ndarray], np.ndarray]


def corner_weights(u: np.ndarray) -> np.ndarray:
    """Eq. 1 weights ``(1-x)(1-y)(1-z), x(1-y)(1-z), ..., xyz``.

    Args:
        u: (..., 3) unit-cube coordinates.

    Returns:
        (..., 8) weights, one per corner in eq. 1 order.
    """
    u = np.asarray(u, dtype=np.float64)
    x, y, z = u[..., 0], u[..., 1], u[..., 2]
    ox, oy, oz = 1.0 - x, 1.0 - y, 1.0 - z
    xy = (ox * oy, x * oy, ox * y, x * y)
    w = np.empty((*u.shape[:-1], 8))
    for i in range(4):
        w[..., i] = xy[i] * oz
        w[..., 4 + i] = xy[i] * z
    return w


def corner_weight_gradients(u: np.ndarray) -> np.ndarray:
    """Derivatives of the eq. 1 weights: (..., 3, 8), row a = d w / d u_a."""
    u = np.asarray(u, dtype=np.float64)
    x, y, z = u[..., 0], u[..., 1], u[..., 2]
    ox, oy, oz = 1.0 - x, 1.0 - y, 1.0 - z
    out = np.empty((*u.shape[:-1], 3, 8))
    dx = (-oy, oy, -y, y)               # d/dx of the x-y factor of corners 0-3
    dy = (-ox, -x, ox, x)
    xy = (ox * oy, x * oy, ox * y, x * y)
    for i in range(4):
        out[..., 0, i], out[..., 0, 4 + i] = dx[i] * oz, dx[i] * z
        out[..., 1, i], out[..., 1, 4 + i] = dy[i] * oz, dy[i] * z
        out[..., 2, i], out[..., 2, 4 + i] = -xy[i], xy[i]
    return out


def trilinear_corners(corners: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Eq. 1: transform unit-cube points by the cuboid ``corners``.

    Args:
        corners: (8, 3) or (k, 8, 3) corner points in eq. 1 order.
        u: (N, 3) unit-cube points (for stacked corners: (k, N, 3) or shared (N, 3)).

    Returns:
        (N, 3) or (k, N, 3) transformed points.
    """
    return corner_weights(u) @ np.asarray(corners, dtype=np.float64)


def coefficient_matrix(corners: np.ndarray) -> np.ndarray:
    """Eq. 2: the 3x8 coefficient matrix ``C`` of a cuboid (vectorized over leading axes).

    Args:
        corners: (..., 8, 3) corner points in eq. 1 order.

    Returns:
        (..., 3, 8): column j multiplies entry j of the parameter vector (eq. 3).
    """
    return np.swapaxes(EQ2 @ np.asarray(corners, dtype=np.float64), -1, -2)


def parameter_vector(u: np.ndarray) -> np.ndarray:
    """Eq. 3: ``v = (xyz, yz, xz, xy, z, y, x, 1)`` for (..., 3) points, shape (..., 8)."""
    u = np.asarray(u, dtype=np.float64)
    x, y, z = u[..., 0], u[..., 1], u[..., 2]
    return np.stack([x * y * z, y * z, x * z, x * y, z, y, x, np.ones_like(x)], -1)


def apply_coefficients(coefficients: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Eq. 4: ``v' = C v`` for (N, 3) unit-cube points and a (3, 8) matrix; returns (N, 3)."""
    return parameter_vector(u) @ np.asarray(coefficients, dtype=np.float64).T


def is_linear_coefficients(coefficients: np.ndarray, rtol: float = LINEAR_RTOL) -> np.ndarray:
    """The section 3.2 test: is the left half of ``C`` zero within ``rtol`` times the size?

    The size is the largest edge column of the right half (|p1-p0|, |p2-p0|, |p4-p0|) together
    with the left half itself, so a cuboid collapsed to a point is linear and a bent one is not.
    A floor of a few float64 roundings of the coordinates' magnitude (|p0| + the columns) keeps a
    tiny parallelepiped far from the origin linear.

    Args:
        coefficients: (..., 3, 8) coefficient matrices (eq. 2).
        rtol: tolerance relative to the size.

    Returns:
        bool array of the leading shape (a 0-d array for one matrix).
    """
    c = np.asarray(coefficients, dtype=np.float64)
    norms = np.linalg.norm(c, axis=-2)                    # (..., 8) column lengths
    left = norms[..., :4].max(-1)
    size = np.maximum(norms[..., 4:7].max(-1), left)
    rounding = 32.0 * np.finfo(np.float64).eps * norms.sum(-1)
    return left <= rtol * size + rounding


@dataclass(frozen=True, eq=False)
class Box:
    """An axis-aligned bounding box mapped to the unit cube (section 4).

    Attributes:
        lo: (3,) float64 minimum corner.
        hi: (3,) float64 maximum corner, ``hi > lo`` on every axis.
    """

    lo: np.ndarray
    hi: np.ndarray

    def __post_init__(self) -> None:
        lo = np.asarray(self.lo, dtype=np.float64).reshape(3)
        hi = np.asarray(self.hi, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
            raise InputError(f"box needs finite lo < hi on every axis, got lo={lo}, hi={hi}")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    @classmethod
    def of_points(cls, points: np.ndarray, min_fraction: float = 1e-3) -> Box:
        """Bounding box of (N, 3) points; flat axes are widened to ``min_fraction`` of the diagonal."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(p) == 0 or not np.all(np.isfinite(p)):
            raise InputError("bounding box of an empty or non-finite point set")
        lo, hi = p.min(0), p.max(0)
        pad = np.maximum(min_fraction * max(float(np.linalg.norm(hi - lo)), 1e-12) - (hi - lo), 0.0) / 2
        return cls(lo - pad, hi + pad)

    @property
    def size(self) -> np.ndarray:
        """(3,) edge lengths."""
        return self.hi - self.lo

    def to_unit(self, points: np.ndarray) -> np.ndarray:
        """Map (..., 3) points of the box to unit-cube coordinates."""
        return (np.asarray(points, dtype=np.float64) - self.lo) / self.size

    def from_unit(self, u: np.ndarray) -> np.ndarray:
        """Map (..., 3) unit-cube coordinates to points of the box."""
        return self.lo + np.asarray(u, dtype=np.float64) * self.size

    def corners(self) -> np.ndarray:
        """(8, 3) corners in eq. 1 order."""
        return self.from_unit(CORNERS)


def unit_lattice(cells: tuple[int, int, int]) -> np.ndarray:
    """(nx + 1, ny + 1, nz + 1, 3) unit-cube coordinates of the lattice points of a grid."""
    axes = [np.linspace(0.0, 1.0, n + 1) for n in cells]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1)


def grid_corners(points: np.ndarray) -> np.ndarray:
    """(..., 8, 3) outer corners, in eq. 1 order, of (..., nx+1, ny+1, nz+1, 3) lattices."""
    p = np.asarray(points)
    return np.stack([p[..., -(i & 1), -((i >> 1) & 1), -((i >> 2) & 1), :] for i in range(8)], -2)


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
        InputError: a shape with fewer than 2 points on an axis, or non-finite points.
    """

    __slots__ = ("box", "points", "error")

    def __init__(self, box: Box, points: np.ndarray, error: float = 0.0) -> None:
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 4 or p.shape[-1] != 3 or min(p.shape[:3]) < 2:
            raise InputError(f"grid points must have shape (nx+1, ny+1, nz+1, 3) with n >= 1, got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise InputError("grid points must be finite")
        self.box = box
        self.points = p
        self.error = float(error)

    # ---- construction -------------------------------------------------------------------------
    @classmethod
    def from_corners(cls, box: Box, corners: np.ndarray) -> Trilinear:
        """One cell from its (8, 3) corners in eq. 1 order."""
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
        """(8, 3) outer corners of the grid in eq. 1 order."""
        return grid_corners(self.points)

    def coefficients(self) -> np.ndarray:
        """Eq. 2 for every cell: (nx, ny, nz, 3, 8)."""
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
        """Evaluate at (N, 3) unit-cube coordinates: eq. 1 in the containing cell. Points outside
        the box use the polynomial of the nearest boundary cell (eq. 4 extrapolates likewise)."""
        u = np.asarray(u, dtype=np.float64).reshape(-1, 3)
        cell, f = self._locate(u)
        if self.points.shape[:3] == (2, 2, 2):  # one cuboid: eq. 4 with C of eq. 2
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
    return out  # type: ignore[return-value]


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
        estimate_error: also state the error of ``C`` (see :func:`composition_error`).

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
        out.error = composition_error(parent, child, out, between=a)
    return out


def composition_error(parent: Trilinear, child: Trilinear, composed: Trilinear, *,
                      between: np.ndarray | None = None, samples_per_cell: int = 3) -> float:
    """Stated error of ``composed`` against the exact functions behind parent and child:
    ``parent.error + lip(parent) * child.error + max |C - G(L)|`` on sample points, with the
    parent's Jacobian norm along the child's image as the Lipschitz factor."""
    a = np.identity(4) if between is None else check_affine(between)
    u = sample_lattice(composed.cells, samples_per_cell)
    inner = child.at_unit(u) @ a[:3, :3].T + a[:3, 3]
    exact_chain = parent(inner)
    sampling = float(np.linalg.norm(composed.at_unit(u) - exact_chain, axis=1).max())
    lip = parent.lipschitz(inner) * float(np.linalg.norm(a[:3, :3], 2))
    return parent.error + lip * child.error + sampling


# ---- normals (section 4.2) -----------------------------------------------------------------------
NORMAL_MODES = ("direct", "tangent")


def tangent_frame(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A tangent and bitangent with ``t x b = n`` for (N, 3) unit normals (GLSL twin in cuboid.glsl)."""
    n = np.asarray(normals, dtype=np.float64)
    helper = np.where((np.abs(n[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    t = np.cross(helper, n)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return t, np.cross(n, t)


def transform_normals(jacobians: np.ndarray, normals: np.ndarray, mode: str) -> np.ndarray:
    """Transform (N, 3) normals by the Jacobians (N, 3, 3) at their vertices (4.2).

    ``"direct"`` transforms the normal like a direction: ``J n`` (smooth across cells, not
    necessarily orthogonal to the surface). ``"tangent"`` transforms the tangent frame and takes
    ``sign(det J) (J t) x (J b)``: orthogonal to the deformed surface, with seams at cell borders.

    Returns:
        (N, 3) unit normals.
    """
    if mode not in NORMAL_MODES:
        raise InputError(f"normal mode must be one of {NORMAL_MODES}, got {mode!r}")
    n = np.asarray(normals, dtype=np.float64)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    if mode == "direct":
        out = np.einsum("nij,nj->ni", jacobians, n)
    else:
        t, b = tangent_frame(n)
        out = np.cross(np.einsum("nij,nj->ni", jacobians, t), np.einsum("nij,nj->ni", jacobians, b))
        out *= np.sign(np.linalg.det(jacobians))[:, None]
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def finite_difference_jacobian(f: Function, points: np.ndarray, step: float) -> np.ndarray:
    """Central-difference Jacobian of ``f`` at (N, 3) points: (N, 3, 3)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    cols = []
    for a in range(3):
        e = np.zeros(3)
        e[a] = step
        cols.append((f(p + e) - f(p - e)) / (2.0 * step))
    return np.stack(cols, -1)


# ---- deformations to approximate (section 3.3 examples) -------------------------------------------
@dataclass(frozen=True)
class TorusWrap:
    """Wraps the box ``[0, length] x [0, width] x z`` around a torus (figures 1 and 9): x goes
    around the major circle (radius ``major``), y around the tube, z outwards from the surface
    of minor radius ``minor``; the torus axis is z."""

    length: float
    width: float
    major: float
    minor: float

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        theta = 2.0 * np.pi * p[:, 0] / self.length
        phi = 2.0 * np.pi * p[:, 1] / self.width
        r = self.minor + p[:, 2]
        ring = self.major + r * np.cos(phi)
        return np.stack([ring * np.cos(theta), ring * np.sin(theta), r * np.sin(phi)], 1)


@dataclass(frozen=True)
class Twist:
    """Rotation about the z axis by ``rate * z`` radians (Barr 1984)."""

    rate: float

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        a = self.rate * p[:, 2]
        c, s = np.cos(a), np.sin(a)
        return np.stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1], p[:, 2]], 1)


@dataclass(frozen=True)
class Taper:
    """Scales x and y by ``1 + rate * z``."""

    rate: float

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        s = 1.0 + self.rate * p[:, 2]
        return np.stack([s * p[:, 0], s * p[:, 1], p[:, 2]], 1)


@dataclass(frozen=True)
class Bend:
    """Bends the x axis around a circle of ``radius`` in the x-z plane (centre at z = radius):
    a point at height z keeps its distance ``radius - z`` from the centre."""

    radius: float

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        a = p[:, 0] / self.radius
        r = self.radius - p[:, 2]
        return np.stack([r * np.sin(a), p[:, 1], self.radius - r * np.cos(a)], 1)


@dataclass(frozen=True)
class Helix:
    """Carries the x axis along a helix of ``radius`` and ``pitch`` (rise per turn), x being
    the arc length; y and z follow the principal normal and binormal of the curve."""

    radius: float
    pitch: float

    def frame(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centre, normal and binormal at arc lengths ``s`` (N,)."""
        b = self.pitch / (2.0 * np.pi)
        c = np.hypot(self.radius, b)
        t = s / c
        centre = np.stack([self.radius * np.cos(t), self.radius * np.sin(t), b * t], 1)
        normal = np.stack([-np.cos(t), -np.sin(t), np.zeros_like(t)], 1)
        binormal = np.stack([b * np.sin(t), -b * np.cos(t), np.full_like(t, self.radius)], 1) / c
        return centre, normal, binormal

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        centre, normal, binormal = self.frame(p[:, 0])
        return centre + p[:, 1:2] * normal + p[:, 2:3] * binormal


def tangent_affine(f: Function, point: np.ndarray, step: float = 1e-5) -> np.ndarray:
    """First-order (linear) approximation of ``f`` at ``point``: the 4x4 affine matrix a linear
    scene graph would use to place an object there."""
    p = np.asarray(point, dtype=np.float64).reshape(1, 3)
    m = np.identity(4)
    m[:3, :3] = finite_difference_jacobian(f, p, step)[0]
    m[:3, 3] = f(p)[0] - m[:3, :3] @ p[0]
    return m
