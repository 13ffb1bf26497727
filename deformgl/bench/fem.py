"""Finite-element references for the calibrated lattice (issue 12, item 3) and the static
equilibrium of a spring system.

Three workloads on boxes (metres, y up, gravity -y), each the same geometry for the lattice and
for the FEM body (:data:`WORKLOADS`):

* ``cantilever``: 1 x 0.1 x 0.1 m, clamped at x = 0, under its own weight. Measured: the mean
  downward displacement of the free end face (x = 1 m), area-weighted.
* ``block``: a 0.1 m cube, bottom face (y = 0) clamped, a uniform pressure on its top face.
  Measured: the mean downward displacement of the top face.
* ``twist``: 0.5 x 0.1 x 0.1 m, clamped at x = 0, a torque about the bar's axis on its end
  face, as the shear traction ``t = T / J_p * e_x x r`` (``J_p = a^4/6``, r from the face's
  centre). Measured: the end face's mean rotation ``int (r x u)_x dA / int |r|^2 dA`` in rad.

FEM (:func:`fem_value`): linear elasticity with scikit-fem, triquadratic hexahedra
(``ElementHex2``) on a uniform box mesh with ``n`` elements across the thickness (0.1 m), any
Poisson's ratio (the lattice's is 1/4). Body force ``rho g``, surface tractions as
``LinearForm`` s on the loaded face, the measured quantity as a ``Functional`` on the measured
face. :func:`fem_reference` refines ``n`` and takes the finest value, with the change from the
previous mesh as its error estimate.

Lattice (:func:`lattice_case`): the workload's :class:`~deformgl.grid.nodes.NodeGrid` with
``across`` nodes across the 0.1 m thickness (h = 0.1 / (across - 1)), nodes on the faces of the
box, the calibrated :func:`~deformgl.sim.materials.lattice_system`, and consistent loads:
gravity ``m_i g`` per node (the cell-assembled masses), a face traction distributed over the
face's nodes by their share of the lattice cells' face areas (h^2/4 per cell face at the node:
the trapezoidal weights; the torque's weights are then rescaled so that the nodal moments sum to
exactly T). The same quantities are measured with the same area weights.

Static equilibrium (:func:`static_displacement`): the stiffness matrix of the springs linearised
at rest, ``K = sum_s k_s n n^T`` in 3x3 blocks (+ on the diagonal blocks of i and j, - off it;
``n`` the unit vector along the spring), with the constrained degrees of freedom removed, solved
with SciPy's sparse direct solver: the exact equilibrium of the same springs under small loads,
what a damped dynamic run converges to (``tests/test_fem.py`` checks that too).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from deformgl.errors import DeformglError
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.materials import ElasticMaterial, lattice_system
from deformgl.sim.springs import SpringSystem
from deformgl.sim.terms.volume.energy import rest_stiffness_triplets

__all__ = ["Workload", "WORKLOADS", "MATERIAL", "LatticeCase", "FemResult", "lattice_case",
           "static_displacement", "stiffness_matrix", "lattice_value", "face_weights",
           "fem_value", "fem_reference", "observed_order", "beam_theory", "twist_theory", "require_skfem"]

#: The workloads' material: E in Pa, rho in kg/m^3 (a stiff polymer; the comparisons are linear,
#: so ratios do not depend on it). Poisson's ratio is the lattice's 1/4 unless a study says.
MATERIAL = ElasticMaterial(1.0e8, 1000.0, name="bench", source="deformgl.bench.fem")
G = 9.81


@dataclass(frozen=True)
class Workload:
    """A box body, how it is held and loaded, and the one number measured on it.

    Attributes:
        name: "cantilever", "block" or "twist".
        size: (Lx, Ly, Lz) in m; the thickness is the smallest (nodes are counted across it).
        load: "gravity" (magnitude: g in m/s^2, along -y), "pressure" (on the y = Ly face,
            downward, magnitude in Pa) or "torque" (about +x on the x = Lx face, N m).
        magnitude: see ``load``.
        clamped: (axis, side): the clamped face, side 0 (coordinate 0) or 1 (the far face).
        measured: (axis, side) of the face whose mean displacement or rotation is measured.
        across: the lattice resolutions (nodes across the thickness) of the accuracy study.
        unit: the measured quantity's unit ("m" or "rad").
    """

    name: str
    size: tuple[float, float, float]
    load: str
    magnitude: float
    clamped: tuple[int, int]
    measured: tuple[int, int]
    across: tuple[int, ...]
    unit: str

    @property
    def thickness(self) -> float:
        """The smallest side in m."""
        return min(self.size)

    def spacing(self, across: int) -> float:
        """Grid spacing h in m for ``across`` nodes across the thickness."""
        if across < 2:
            raise ValueError(f"{self.name}: at least 2 nodes across the thickness, got {across}")
        return self.thickness / (across - 1)

    def cells(self, per_thickness: int) -> tuple[int, int, int]:
        """Cells (or elements) along x, y, z for ``per_thickness`` across the thickness."""
        return tuple(int(round(s / self.thickness * per_thickness)) for s in self.size)  # type: ignore[return-value]


WORKLOADS: dict[str, Workload] = {
    "cantilever": Workload("cantilever", (1.0, 0.1, 0.1), "gravity", G, (0, 0), (0, 1),
                           (2, 3, 4, 5, 8, 9, 17), "m"),
    "block": Workload("block", (0.1, 0.1, 0.1), "pressure", 1.0e4, (1, 0), (1, 1),
                      (2, 3, 5, 9, 17), "m"),
    "twist": Workload("twist", (0.5, 0.1, 0.1), "torque", 10.0, (0, 0), (0, 1),
                      (2, 3, 5, 9, 17), "rad"),
}


def _trapezoid(n: int, h: float) -> np.ndarray:
    """1D weights of n nodes spaced h: h/2 at the ends, h inside (the cells' shares)."""
    w = np.full(n, h)
    w[0] = w[-1] = h / 2.0
    return w


def face_weights(grid: NodeGrid, axis: int, side: int) -> tuple[np.ndarray, np.ndarray]:
    """The nodes of a box grid's face and their areas in m^2: each lattice cell face on the
    boundary gives h^2/4 to each of its 4 corners.

    Returns:
        (node numbers, areas), both (M,).
    """
    shape = grid.shape
    layer = 0 if side == 0 else shape[axis] - 1
    ijk = grid.ijk.astype(np.int64)
    nodes = np.flatnonzero(ijk[:, axis] == layer)
    others = [a for a in range(3) if a != axis]
    h = float(grid.spacing)
    area = np.ones(len(nodes))
    for a in others:
        area *= _trapezoid(shape[a], h)[ijk[nodes, a]]
    return nodes, area


@dataclass(frozen=True, eq=False)
class LatticeCase:
    """A workload on the lattice: the calibrated system (clamped face fixed, gravity as the
    workload says), its grid, the static external forces (N, 3) in N, and the measured face."""

    workload: Workload
    across: int
    grid: NodeGrid
    system: SpringSystem
    forces: np.ndarray
    measured_nodes: np.ndarray
    measured_area: np.ndarray

    @property
    def spacing(self) -> float:
        """h in m."""
        return float(self.grid.spacing)


def _centre(w: Workload, axis: int) -> np.ndarray:
    c = np.array(w.size) / 2.0
    c[axis] = 0.0
    return c


def lattice_case(w: Workload, across: int, material: ElasticMaterial = MATERIAL, *,
                 build: Callable[..., SpringSystem] | None = None, scale: float = 1.0) -> LatticeCase:
    """The workload on the lattice with ``across`` nodes across the thickness.

    Args:
        w: the workload.
        across: nodes across the thickness (>= 2).
        material: E and rho.
        build: ``build(grid, fixed, gravity) -> SpringSystem`` instead of the calibrated
            :func:`~deformgl.sim.materials.lattice_system` (to test another calibration).
        scale: all lengths times this (the scaling test); the load magnitude stays.
    """
    h = w.spacing(across) * scale
    shape = tuple(c + 1 for c in w.cells(across - 1))
    grid = NodeGrid(np.zeros(3), h, np.ones(shape, bool))
    ijk = grid.ijk.astype(np.int64)
    axis, side = w.clamped
    fixed = ijk[:, axis] == (0 if side == 0 else shape[axis] - 1)
    gravity = (0.0, -w.magnitude, 0.0) if w.load == "gravity" else (0.0, 0.0, 0.0)
    if build is None:
        system, _ = lattice_system(grid, material, fixed=fixed, gravity=gravity)
    else:
        system = build(grid, fixed, gravity)
    f = np.zeros((grid.count, 3))
    if w.load == "gravity":
        f += system.mass[:, None] * np.asarray(gravity)
    elif w.load == "pressure":
        nodes, area = face_weights(grid, 1, 1)
        f[nodes, 1] -= w.magnitude * area
    elif w.load == "torque":
        nodes, area = face_weights(grid, 0, 1)
        r = grid.rest_positions[nodes] - _centre(w, 0) * scale
        r[:, 0] = 0.0
        moment_arm = area * (r[:, 1] ** 2 + r[:, 2] ** 2)
        tangential = np.stack([np.zeros(len(nodes)), -r[:, 2], r[:, 1]], axis=1)  # e_x x r
        f[nodes] += w.magnitude / moment_arm.sum() * area[:, None] * tangential
    else:
        raise ValueError(f"{w.name}: unknown load {w.load!r}")
    f[system.fixed] = 0.0
    m_axis, m_side = w.measured
    nodes, area = face_weights(grid, m_axis, m_side)
    return LatticeCase(w, across, grid, system, f, nodes, area)


def stiffness_matrix(system: SpringSystem) -> sp.csr_matrix:
    """The (3N, 3N) stiffness matrix of the springs linearised at their rest positions:
    ``K = sum_s k_s n_s n_s^T`` in 3x3 blocks (the rest state is force-free, so there is no
    geometric term), plus the cells' centre term (:mod:`deformgl.sim.terms.volume.energy`)."""
    x = system.rest_positions
    d = x[system.j] - x[system.i]
    n = d / np.linalg.norm(d, axis=1)[:, None]
    block = system.stiffness[:, None, None] * n[:, :, None] * n[:, None, :]  # (S, 3, 3)
    a = np.arange(3)
    shape = (system.spring_count, 3, 3)

    def rows(node: np.ndarray) -> np.ndarray:
        return np.broadcast_to((3 * node)[:, None, None] + a[None, :, None], shape)

    def cols(node: np.ndarray) -> np.ndarray:
        return np.broadcast_to((3 * node)[:, None, None] + a[None, None, :], shape)
    ri, rj, ci, cj = rows(system.i), rows(system.j), cols(system.i), cols(system.j)
    rows_all = np.concatenate([ri, rj, ri, rj]).ravel()
    cols_all = np.concatenate([ci, cj, cj, ci]).ravel()
    vals = np.concatenate([block, block, -block, -block]).ravel()
    if system.cells is not None:  # the cells' centre term (any Poisson's ratio; no barrier at rest)
        rv, cv, vv = rest_stiffness_triplets(system.cells)
        rows_all, cols_all, vals = (np.concatenate([rows_all, rv]), np.concatenate([cols_all, cv]),
                                    np.concatenate([vals, vv]))
    size = 3 * system.count
    return sp.csr_matrix((vals, (rows_all, cols_all)), shape=(size, size))


#: Free degrees of freedom above which :func:`static_displacement` uses PyAMG's conjugate
#: gradients (when installed) instead of the direct solve.
DIRECT_DOFS = 30_000


def _dissection(ijk: np.ndarray, nodes: np.ndarray, leaf: int = 64) -> list[np.ndarray]:
    """Geometric nested dissection of grid nodes: halve the longest extent, order the halves
    first and the separating plane last (much less fill than SuperLU's own orderings)."""
    p = ijk[nodes]
    if len(nodes) <= leaf:
        return [nodes]
    lo, hi = p.min(axis=0), p.max(axis=0)
    axis = int(np.argmax(hi - lo))
    if hi[axis] - lo[axis] < 2:
        return [nodes]
    mid = (lo[axis] + hi[axis]) // 2
    c = p[:, axis]
    return (_dissection(ijk, nodes[c < mid], leaf) + _dissection(ijk, nodes[c > mid], leaf)
            + [nodes[c == mid]])


def _rigid_modes(x: np.ndarray) -> np.ndarray:
    """(3M, 6): the 3 translations and 3 rotations of M nodes at x (PyAMG's near null space)."""
    b = np.zeros((len(x), 3, 6))
    for a in range(3):
        b[:, a, a] = 1.0
    b[:, 0, 3], b[:, 1, 3] = -x[:, 1], x[:, 0]
    b[:, 1, 4], b[:, 2, 4] = -x[:, 2], x[:, 1]
    b[:, 2, 5], b[:, 0, 5] = -x[:, 0], x[:, 2]
    return b.reshape(-1, 6)


def static_displacement(system: SpringSystem, forces: np.ndarray,
                        constrained: np.ndarray | None = None, *, method: str = "auto") -> np.ndarray:
    """The displacement (N, 3) in m at static equilibrium of the linearised springs under the
    nodal ``forces`` (N, 3) in N.

    Args:
        system: the springs (their rest positions are the reference state).
        forces: external forces per node.
        constrained: (N, 3) bool, the degrees of freedom held at 0 (default: all three of every
            ``system.fixed`` node).
        method: "direct" (SuperLU on a nested-dissection ordering of the grid's nodes), "amg"
            (conjugate gradients preconditioned by PyAMG's smoothed aggregation with the rigid
            modes, relative residual 1e-11; the 'fem' extra; a body with cells of kappa > 0 that
            defeat it is solved directly instead), "multigrid" (conjugate gradients preconditioned
            by deformgl's own V-cycle, :mod:`deformgl.sim.multigrid`, true relative residual 1e-8; a
            grid system held at its fixed nodes, ``constrained`` None), or "auto": direct up to
            :data:`DIRECT_DOFS` free unknowns, else amg when PyAMG is installed.

    Raises:
        DeformglError: the free part of K is singular (a rigid-body mode is not held), or the
            iterations did not converge.
    """
    from scipy.sparse.linalg import splu

    if method == "multigrid":
        return _multigrid_static(system, forces, constrained)
    hold = (np.repeat(system.fixed[:, None], 3, axis=1) if constrained is None
            else np.asarray(constrained, bool).reshape(-1, 3))
    nodes = np.flatnonzero(~hold.all(axis=1))
    if system.grid is not None:
        nodes = np.concatenate(_dissection(system.grid.ijk.astype(np.int64), nodes))
    dofs = (3 * nodes[:, None] + np.arange(3)).ravel()
    dofs = dofs[~hold.ravel()[dofs]]
    k = stiffness_matrix(system)[dofs][:, dofs]
    b = np.asarray(forces, float).ravel()[dofs]
    if method == "auto":
        method = "direct"
        partial = (hold.any(axis=1) & ~hold.all(axis=1)).any()  # amg wants whole 3x3 blocks
        if len(dofs) > DIRECT_DOFS and not partial:
            try:
                import pyamg  # type: ignore[import-untyped,import-not-found,unused-ignore]  # noqa: F401
                method = "amg"
            except ImportError:
                pass
    if method == "amg":
        import pyamg  # type: ignore[import-untyped,import-not-found,unused-ignore]

        ml = pyamg.smoothed_aggregation_solver(k.tocsr().tobsr(blocksize=(3, 3)), symmetry="symmetric",
                                               B=_rigid_modes(system.rest_positions[dofs[::3] // 3]),
                                               max_coarse=1000)
        residuals: list[float] = []
        u_free = ml.solve(b, tol=1e-11, accel="cg", maxiter=400, residuals=residuals)
        if residuals[-1] > 1e-9 * residuals[0]:
            if system.cells is None or system.cells.volume_modulus == 0:
                raise DeformglError(f"static solve: conjugate gradients did not converge "
                                    f"({len(residuals)} iterations, residual {residuals[-1] / residuals[0]:.1e})")
            method = "direct"  # nearly incompressible cells defeat the aggregation: solve directly
    if method == "direct":
        try:
            lu = splu(k.tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                      options={"SymmetricMode": True})
        except RuntimeError:
            raise DeformglError("static solve: the stiffness matrix is singular (a rigid-body "
                                "mode is not held by the constraints)") from None
        u_free = lu.solve(b)
        with np.errstate(all="ignore"):
            residual = float(np.linalg.norm(k @ u_free - b)) / max(float(np.linalg.norm(b)), 1e-300)
        if not residual < 1e-6:  # (nan too) a zero pivot rounded to a tiny one
            raise DeformglError("static solve: the stiffness matrix is singular (a rigid-body "
                                "mode is not held by the constraints)")
    elif method != "amg":
        raise ValueError(f"static_displacement: unknown method {method!r}")
    u = np.zeros(3 * system.count)
    u[dofs] = u_free
    if not np.all(np.isfinite(u)):
        raise DeformglError("static solve: the stiffness matrix is singular (a rigid-body mode "
                            "is not held by the constraints)")
    return u.reshape(-1, 3)


def _multigrid_static(system: SpringSystem, forces: np.ndarray, constrained: np.ndarray | None) -> np.ndarray:
    """:func:`static_displacement` by multigrid-preconditioned CG (method "multigrid")."""
    from deformgl.sim.implicit import multigrid_levels, pcg

    if constrained is not None or system.grid is None:
        raise ValueError("static_displacement: method 'multigrid' needs a grid system held at its fixed nodes")
    dofs = np.flatnonzero(np.repeat(~system.fixed, 3))
    k = stiffness_matrix(system)[dofs][:, dofs].tocsr()
    b = np.asarray(forces, float).ravel()[dofs]
    apply = multigrid_levels(system).cycle(k)
    u_free = np.zeros_like(b)
    for _ in range(4):  # restarted from the true residual where CG's updated one drifted below it
        u_free, report = pcg(k, b, u_free, iterations=2000, tolerance=1e-8, check_every=1, apply=apply)
        if report.within_tolerance:
            break
    if not report.within_tolerance:
        raise DeformglError(f"static solve: multigrid CG did not converge ({report.iterations} iterations, "
                            f"residual {report.residual:.1e})")
    u = np.zeros(3 * system.count)
    u[dofs] = u_free
    return u.reshape(-1, 3)


def lattice_value(case: LatticeCase, u: np.ndarray | None = None) -> float:
    """The workload's measured quantity on the lattice (m, or rad for the twist), from the
    displacement ``u`` (default: the static solve)."""
    if u is None:
        u = static_displacement(case.system, case.forces)
    nodes, area = case.measured_nodes, case.measured_area
    w = case.workload
    if w.load == "torque":
        r = case.grid.rest_positions[nodes] - _centre(w, 0) * (case.spacing / w.spacing(case.across))
        moment = r[:, 1] * u[nodes, 2] - r[:, 2] * u[nodes, 1]
        return float((area * moment).sum() / (area * (r[:, 1] ** 2 + r[:, 2] ** 2)).sum())
    return float(-(area * u[nodes, 1]).sum() / area.sum())


# ---- FEM (scikit-fem) -------------------------------------------------------------------------

def require_skfem() -> None:
    """Raise a one-line error when scikit-fem (the 'fem' extra) is not installed."""
    try:
        import skfem  # type: ignore[import-untyped,import-not-found,unused-ignore]  # noqa: F401
    except ImportError:
        raise DeformglError("the FEM reference needs scikit-fem: pip install 'deformgl[fem]'") from None


@dataclass(frozen=True)
class FemResult:
    """The FEM value of a workload at one mesh: ``per_thickness`` elements across the
    thickness, ``order`` 1 (ElementHex1) or 2 (ElementHex2), ``dofs`` unknowns, ``value`` the
    measured quantity (m or rad), ``seconds`` of wall time."""

    workload: str
    per_thickness: int
    order: int
    nu: float
    dofs: int
    value: float
    seconds: float


def fem_value(w: Workload, per_thickness: int, *, nu: float = 0.25, order: int = 2,
              material: ElasticMaterial = MATERIAL) -> FemResult:
    """The workload solved by linear-elastic hexahedral FEM (see the module docstring)."""
    import time

    require_skfem()
    from skfem import (Basis, BilinearForm, ElementHex1, ElementHex2, ElementVector,  # type: ignore[import-untyped,import-not-found,unused-ignore]
                       FacetBasis, Functional, LinearForm, MeshHex, asm, condense, solve)
    from skfem.helpers import ddot, sym_grad, trace  # type: ignore[import-untyped,import-not-found,unused-ignore]

    start = time.perf_counter()
    nx, ny, nz = w.cells(per_thickness)
    lx, ly, lz = w.size
    mesh = MeshHex.init_tensor(np.linspace(0, lx, nx + 1), np.linspace(0, ly, ny + 1),
                               np.linspace(0, lz, nz + 1))
    element = ElementVector(ElementHex2() if order == 2 else ElementHex1())
    intorder = 4 if order == 2 else 2
    basis = Basis(mesh, element, intorder=intorder)
    lam = material.youngs_modulus * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))  # Lame constants
    mu = material.youngs_modulus / (2.0 * (1.0 + nu))

    @BilinearForm
    def elasticity(u, v, _):
        eps_u, eps_v = sym_grad(u), sym_grad(v)
        return 2.0 * mu * ddot(eps_u, eps_v) + lam * trace(eps_u) * trace(eps_v)

    K = asm(elasticity, basis)

    def on(axis: int, side: int) -> Callable[[np.ndarray], np.ndarray]:
        value = 0.0 if side == 0 else w.size[axis]
        return lambda x: np.isclose(x[axis], value)

    if w.load == "gravity":
        rho_g = material.density * w.magnitude

        @LinearForm
        def body(v, _):
            return -rho_g * v[1]
        f = asm(body, basis)
    else:
        face = FacetBasis(mesh, element, facets=mesh.facets_satisfying(
            on(1, 1) if w.load == "pressure" else on(0, 1)), intorder=intorder)
        if w.load == "pressure":
            p = w.magnitude

            @LinearForm
            def traction(v, _):
                return -p * v[1]
        else:
            scale = w.magnitude / (w.size[1] * w.size[2] * (w.size[1] ** 2 + w.size[2] ** 2) / 12.0)
            cy, cz = w.size[1] / 2.0, w.size[2] / 2.0

            @LinearForm
            def traction(v, p):
                y, z = p.x[1] - cy, p.x[2] - cz
                return scale * (-z * v[1] + y * v[2])
        f = asm(traction, face)
    dofs = basis.get_dofs(on(*w.clamped)).all()
    u = solve(*condense(K, f, D=dofs))
    m_axis, m_side = w.measured
    mbasis = FacetBasis(mesh, element, facets=mesh.facets_satisfying(on(m_axis, m_side)),
                        intorder=intorder)
    ui = mbasis.interpolate(u)
    if w.load == "torque":
        cy, cz = w.size[1] / 2.0, w.size[2] / 2.0

        @Functional
        def moment(p):
            return (p.x[1] - cy) * p.u[2] - (p.x[2] - cz) * p.u[1]

        @Functional
        def polar(p):
            return (p.x[1] - cy) ** 2 + (p.x[2] - cz) ** 2
        value = moment.assemble(mbasis, u=ui) / polar.assemble(mbasis, u=ui)
    else:
        @Functional
        def down(p):
            return -p.u[1]

        @Functional
        def one(p):
            return 1.0 + 0.0 * p.x[0]
        value = down.assemble(mbasis, u=ui) / one.assemble(mbasis, u=ui)
    return FemResult(w.name, per_thickness, order, nu, int(basis.N), float(value),
                     time.perf_counter() - start)


def fem_reference(w: Workload, meshes: tuple[int, ...] = (1, 2, 4), *, nu: float = 0.25,
                  order: int = 2, material: ElasticMaterial = MATERIAL) -> tuple[float, float, list[FemResult]]:
    """The FEM value on meshes refined by halving: (value, its estimated relative error, the
    results). With three or more meshes converging monotonically the value is Richardson's
    extrapolation of the last three (the observed order ``p = log2(d1 / d2)`` of the last two
    changes) and the error estimate its distance to the finest mesh's value; otherwise the
    finest value, with the last change as the estimate."""
    results = [fem_value(w, n, nu=nu, order=order, material=material) for n in meshes]
    v = [r.value for r in results]
    if len(v) >= 3:
        d1, d2 = v[-2] - v[-3], v[-1] - v[-2]
        if d1 != 0 and 0 < d2 / d1 < 1:
            best = v[-1] + d2 * (d2 / d1) / (1 - d2 / d1)
            return best, abs(best - v[-1]) / abs(best), results
    err = abs(v[-1] - v[-2]) / abs(v[-1]) if len(v) > 1 else math.nan
    return v[-1], err, results


def observed_order(results: list[FemResult]) -> float:
    """The FEM's own convergence order from the last three meshes (``log2`` of the ratio of
    successive changes; nan with fewer meshes or non-monotone changes)."""
    if len(results) < 3:
        return math.nan
    d1 = results[-2].value - results[-3].value
    d2 = results[-1].value - results[-2].value
    return math.log2(d1 / d2) if d1 and d2 and d1 / d2 > 0 else math.nan


def beam_theory(w: Workload, material: ElasticMaterial = MATERIAL, nu: float = 0.25) -> tuple[float, float]:
    """Tip deflection in m of the cantilever under its weight: (Euler-Bernoulli ``q L^4 / (8 E
    I)``, Timoshenko: that plus ``q L^2 / (2 kappa G A)`` with Cowper's kappa ``10 (1 + nu) /
    (12 + 11 nu)`` of a rectangle)."""
    lx, ly, lz = w.size
    area, inertia = ly * lz, lz * ly ** 3 / 12.0
    q = material.density * w.magnitude * area
    eb = q * lx ** 4 / (8.0 * material.youngs_modulus * inertia)
    shear = material.youngs_modulus / (2.0 * (1.0 + nu))
    kappa = 10.0 * (1.0 + nu) / (12.0 + 11.0 * nu)
    return eb, eb + q * lx ** 2 / (2.0 * kappa * shear * area)


def twist_theory(w: Workload, material: ElasticMaterial = MATERIAL, nu: float = 0.25) -> float:
    """Saint-Venant twist angle in rad of a square bar: ``T L / (G beta a^4)``, beta = 0.1406."""
    shear = material.youngs_modulus / (2.0 * (1.0 + nu))
    return w.magnitude * w.size[0] / (shear * 0.1406 * w.thickness ** 4)
