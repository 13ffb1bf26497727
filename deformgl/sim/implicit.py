"""Implicit (backward) Euler on a :class:`SpringSystem`, float64 reference (scipy.sparse).

One step linearises the forces at the start of the step (Baraff & Witkin 1998; the
method SOFA's default ``EulerImplicitSolver`` uses) and solves for the velocity change::

    (M + dt C + dt^2 H) dv = dt (f(x, v, t + dt) - dt H v),   v' = v + dv,   x' = x + dt v'

with ``H = -df/dx`` the spring stiffness matrix and ``C = -df/dv`` the damping matrix
(docs/EQUATIONS.md, "Implicit Euler"). Per spring (i, j), ``d = x_i - x_j``, ``u = d/|d|``:

* ``H_s = k (u u^T + g (I - u u^T))`` with the geometric factor ``g = 1 - L/|d|``. Compressed
  springs have ``g < 0`` and can make H indefinite, so the default ``geometric="projected"``
  clamps it to ``max(0, g)`` (H positive semidefinite, the system SPD; the measured choice, see
  docs/EQUATIONS.md); "full" keeps g, "none" drops the term (``g = 0``). Clamping g is the
  eigenvalue projection of the spring's block (eigenvalues k along u, k g across), so "eigen"
  (NumPy only, for the cells below) treats the springs as "projected".
* ``C_s = c_s u u^T`` (spring damping along the spring; its dependence on x is dropped).

Per full cell (``system.cells``, :mod:`deformgl.sim.terms.volume.energy`): the Hessian of the volumetric term
``V kappa/2 (J - 1)^2`` and of the corner barriers inside ``J_b``, built by
:func:`deformgl.sim.terms.volume.hessian.cell_matrix`. Their geometric part ``w (J - J0) d^2 J / dx^2``
is indefinite wherever it is not zero (:mod:`deformgl.sim.terms.volume.hessian`), so "projected" and
"none" keep the Gauss-Newton part ``w dJ/dx dJ/dx^T`` only (positive semidefinite; the GPU's
product too), "full" the exact Hessian, and "eigen" each cell's exact 24x24 block with its
negative eigenvalues set to 0 (:data:`~deformgl.sim.terms.volume.hessian.CELL_HESSIAN`; measured against
each other in tests/test_cells_implicit.py). The right-hand side has the exact forces
(:func:`~deformgl.sim.springs.forces`, cells included).

Per node: ``C`` has ``c + alpha m_i + wind_drag`` on the diagonal (global, Rayleigh mass and wind
damping), a drag of stiffness ``k_d`` adds ``k_d I`` to H at its node. Fixed nodes have no rows:
the solve is over the free nodes only (their dv is 0). Ground and spheres are applied after the
solve as the explicit integrators do (:func:`deformgl.sim.integrators.apply_constraints`), a
projection of the new positions and velocities; the solve does not see them.

The solver is preconditioned conjugate gradients, warm-started from the previous step's dv
(scaled to its best multiple by default, :data:`WARM_STARTS`),
written out here (not ``scipy.sparse.linalg.cg``) so the GPU backend
(:mod:`deformgl.sim.backends.implicit_gpu`) runs the same iteration and can be matched against it
step for step: ``iterations`` is the most iterations per step; with ``tolerance`` > 0 it stops
when the relative residual ``|r| / |b|`` is at most ``tolerance`` or ``|r|`` is at most the
absolute floor (:func:`residual_floor`, in N s), tested every ``check_every`` iterations: the
same test for every preconditioner (``r = b - A dv``, CG's updated residual; the report gives and
judges the true ``|b - A dv| / |b|`` at the end, the GPU backend's too). ``solver="direct"``
solves exactly (``scipy.sparse.linalg.spsolve``).
The preconditioner P (:data:`PRECONDITIONERS`) is "jacobi", the diagonal of A, "block-jacobi",
the 3x3 diagonal block of A per node (its x y z coupling: the springs' ``u u^T`` terms), inverted
per node, or "multigrid", a geometric V-cycle over the node grid at 2h, 4h, ...
(:mod:`deformgl.sim.multigrid`; grid systems only). Jacobi and block-Jacobi are symmetric
positive definite where A is; the V-cycle is symmetric, and positive definite while its smoother
converges on the step's A (docs/EQUATIONS.md "Multigrid"), so CG stays CG.
"""

from __future__ import annotations

from dataclasses import dataclass
from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from deformgl.sim.clock import CpuSimulationBase
from deformgl.sim.integrators import Constraints, State, apply_constraints, initial_state
from deformgl.sim.multigrid import CoarseLevels, block_inverse, grid_levels
from deformgl.sim.springs import SpringSystem, forces
from deformgl.sim.scripted import Drag, Load

__all__ = ["GEOMETRIC", "PRECONDITIONERS", "DEFAULT_PRECONDITIONER", "CG_DEFAULTS", "SolveReport", "SolverStats",
           "EPS32", "EPS64", "residual_floor", "multigrid_levels", "LinearSystem",
           "WARM_STARTS", "DEFAULT_WARM_START", "assemble", "check_preconditioner", "check_warm_start",
           "warm_start", "preconditioner", "pcg", "implicit_step", "ImplicitNumpySimulation",
           "solver_note"]

#: How the geometric stiffness of a spring (and a cell) enters H (module docstring).
GEOMETRIC = ("projected", "full", "none", "eigen")
#: The CG preconditioners: the diagonal of A, its 3x3 block per node, or the grid's V-cycle.
PRECONDITIONERS = ("jacobi", "block-jacobi", "multigrid")
DEFAULT_PRECONDITIONER = "jacobi"
#: How CG starts a step: "scaled", the last step's dv times the s that minimises the A-norm
#: error along it, ``s = (b . dv) / (dv . A dv)`` (0 if that is not > 0; never worse than
#: "zero"); "previous", the last step's dv as it is; "zero", dv = 0. Measured (``bench trade
#: --stiff``, docs/PERFORMANCE.md): "previous" lets truncated CG drift away on the finer stiff
#: blocks (17 across, dt = 1/250 s, 10 iterations: 4.2x the sag off after 0.3 s), "scaled" and
#: "zero" do not (7.5e-6 of the sag).
WARM_STARTS = ("scaled", "previous", "zero")
DEFAULT_WARM_START = "scaled"
#: Default CG settings: iterations per step, relative tolerance (0: always ``iterations``), and
#: how many iterations between residual tests.
CG_DEFAULTS = {"cg_iterations": 20, "cg_tolerance": 0.0, "cg_check_every": 4}


@dataclass(frozen=True)
class SolveReport:
    """One step's linear solve.

    Attributes:
        iterations: CG iterations done.
        residual: the relative residual ``|b - A dv| / |b|`` after them (0 for a zero
            right-hand side; NaN where it was not read: the GPU without a tolerance).
        within_tolerance: the residual is at most the tolerance, or ``|b - A dv|`` at most the
            absolute floor (:func:`residual_floor`); True without a tolerance: the solver's own
            per-step convergence, not the run's equilibrium (a run's ``converged``,
            :mod:`deformgl.sim.equilibrium`).
    """

    iterations: int
    residual: float
    within_tolerance: bool


@dataclass
class SolverStats:
    """A run's linear solves, what the run record reports as ``solver`` (apart from the run's
    equilibrium ``converged``): steps, iterations (mean and most per step), the last and the
    worst relative residual, the absolute floor (N s, :func:`residual_floor`) and the steps
    that missed both."""

    preconditioner: str
    tolerance: float
    floor: float = 0.0
    steps: int = 0
    iterations_total: int = 0
    iterations_most: int = 0
    residual_last: float = float("nan")
    residual_worst: float = float("nan")
    unconverged: int = 0

    def add(self, report: SolveReport) -> None:
        self.steps += 1
        self.iterations_total += report.iterations
        self.iterations_most = max(self.iterations_most, report.iterations)
        if not np.isnan(report.residual):
            self.residual_last = report.residual
            self.residual_worst = (report.residual if np.isnan(self.residual_worst)
                                   else max(self.residual_worst, report.residual))
        if not report.within_tolerance:
            self.unconverged += 1

    def summary(self) -> dict[str, Any]:
        """The record's ``solver`` entry (residuals None where none was read)."""
        def value(x: float) -> float | None:
            return None if np.isnan(x) else float(x)

        return {"method": "cg", "preconditioner": self.preconditioner, "tolerance": self.tolerance,
                "residual_floor_Ns": self.floor, "steps": self.steps,
                "iterations_mean": self.iterations_total / self.steps if self.steps else 0.0,
                "iterations_most": self.iterations_most, "residual_last": value(self.residual_last),
                "residual_worst": value(self.residual_worst), "unconverged_steps": self.unconverged}


#: float32's unit roundoff: the relative precision of a GPU node position.
EPS32 = float(np.finfo(np.float32).eps) / 2
#: Half float64's machine epsilon (the NumPy reference's rounding).
EPS64 = float(np.finfo(np.float64).eps) / 2


def residual_floor(system: SpringSystem, x: np.ndarray, dt: float, *, drags: tuple[Drag, ...] = (),
                   eps: float = EPS32) -> float:
    """The absolute floor of the solve's residual, in N s (an impulse, b's unit): ``dt`` times the
    force noise that rounding the node positions to the backend's precision makes (``eps``, half
    its machine epsilon: :data:`EPS32` on the GPU, :data:`EPS64` in NumPy). Rounding a coordinate
    ``x_j`` errs uniformly within half its ulp, at most ``eps |x_j|``: a standard deviation of
    ``s_j = eps |x_j| / sqrt(3)``. The force on the free nodes moves by ``H dx``, whose expected size
    for independent errors is ``sqrt(sum_j s_j^2 |H_j|^2)`` (``H_j`` the free nodes' rows of column
    j of the stiffness H at ``x``: the springs', the volumetric cells', the physics terms' and the
    drags' terms alike). A right-hand side this size is rounding noise (a stiff body at rest in
    equilibrium, on the GPU): the solve counts a residual this small as solved, whatever its
    relative size, each backend at its own precision. (In float32 it can be a good part of a
    stiff body's first ``|b|``: rounding the positions of a 1 m steel cantilever moves the forces by a third of
    its nodes' weight.)"""
    x = np.asarray(x, np.float64)
    hessian = assemble(system, x, np.zeros_like(x), 0.0, dt, drags=drags).hessian
    rows = hessian[np.flatnonzero(np.repeat(~system.fixed, 3))]
    column2 = np.asarray(rows.multiply(rows).sum(axis=0)).ravel()
    sigma = eps * np.abs(x).ravel() / np.sqrt(3.0)
    return float(dt * np.sqrt(column2 @ sigma ** 2))


@dataclass(frozen=True)
class LinearSystem:
    """``A dv = b`` of one step over the free nodes.

    Attributes:
        matrix: (3F, 3F) scipy CSR A (F free nodes, x y z of each).
        rhs: (3F,) b.
        free: (N,) bool, the nodes that have rows.
        hessian: (3N, 3N) CSR H (all nodes; the rhs uses it).
    """

    matrix: sp.csr_matrix
    rhs: np.ndarray
    free: np.ndarray
    hessian: sp.csr_matrix


def _blocks(system: SpringSystem, x: np.ndarray, geometric: str) -> tuple[np.ndarray, np.ndarray]:
    """(S, 3, 3) H_s and C_s of every spring."""
    if geometric not in GEOMETRIC:
        raise ValueError(f"geometric must be one of {', '.join(GEOMETRIC)}, got {geometric!r}")
    d = x[system.i] - x[system.j]
    length = np.linalg.norm(d, axis=1)
    u = d / np.where(length > 0, length, 1.0)[:, None]
    uu = u[:, :, None] * u[:, None, :]
    g = np.where(length > 0, 1.0 - system.rest_length / np.where(length > 0, length, 1.0), 0.0)
    if geometric in ("projected", "eigen"):
        g = np.maximum(g, 0.0)
    elif geometric == "none":
        g = np.zeros_like(g)
    eye = np.eye(3)[None]
    h = system.stiffness[:, None, None] * (uu + g[:, None, None] * (eye - uu))
    return h, system.damping[:, None, None] * uu


def _spread(system: SpringSystem, blocks: np.ndarray) -> sp.csr_matrix:
    """The (3N, 3N) matrix of per-spring blocks B: +B at (i, i), (j, j), -B at (i, j), (j, i)."""
    n = system.count
    a, b = system.i, system.j
    rows_n = np.concatenate([a, b, a, b])
    cols_n = np.concatenate([a, b, b, a])
    vals = np.concatenate([blocks, blocks, -blocks, -blocks])
    r = (3 * rows_n[:, None, None] + np.arange(3)[None, :, None]).repeat(3, axis=2)
    c = (3 * cols_n[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1)
    return sp.csr_matrix((vals.ravel(), (r.ravel(), c.ravel())), shape=(3 * n, 3 * n))


def assemble(system: SpringSystem, x: np.ndarray, v: np.ndarray, t: float, dt: float, *,
             drags: tuple[Drag, ...] = (), loads: tuple[Load, ...] = (),
             geometric: str = "projected") -> LinearSystem:
    """The step's linear system (module docstring): the springs', the drags', the cells' and
    each of ``system.terms``' blocks of H (``geometric``: :data:`GEOMETRIC`); forces at time ``t + dt``."""
    n = system.count
    h_blocks, c_blocks = _blocks(system, x, geometric)
    node_h = np.zeros(n)
    for drag in drags:
        node_h[drag.node] += drag.stiffness
    hess = _spread(system, h_blocks) + sp.diags(np.repeat(node_h, 3))
    node_c = system.velocity_damping + system.mass_damping * system.mass + system.wind_drag
    a_full = (_spread(system, dt * dt * h_blocks + dt * c_blocks)
              + sp.diags(np.repeat(system.mass + dt * node_c + dt * dt * node_h, 3)))
    for term in system.terms:  # each physics term's share of H (the cells': CELL_HESSIAN[geometric])
        term_h = term.hessian(x, geometric)
        hess = hess + term_h
        a_full = a_full + dt * dt * term_h
    f = forces(system, x, v, t + dt, drags, loads)
    b_full = dt * (f.ravel() - dt * (hess @ v.ravel()))
    free = ~system.fixed
    dof = np.repeat(free, 3)
    return LinearSystem(a_full.tocsr()[dof][:, dof].tocsr(), b_full[dof], free, hess.tocsr())


def check_warm_start(name: object) -> str:
    """``name`` if it is one of :data:`WARM_STARTS` (ValueError naming ``cg_warm_start`` if not)."""
    if name not in WARM_STARTS:
        raise ValueError(f"cg_warm_start must be one of {', '.join(WARM_STARTS)}, got {name!r}")
    return str(name)


def warm_start(a: sp.csr_matrix, b: np.ndarray, previous: np.ndarray, kind: str = DEFAULT_WARM_START) -> np.ndarray:
    """CG's start from the last step's solution ``previous`` (:data:`WARM_STARTS`)."""
    check_warm_start(kind)
    if kind == "zero":
        return np.zeros_like(previous)
    if kind == "previous":
        return previous.copy()
    d = float(previous @ (a @ previous))
    return previous * (float(b @ previous) / d if d > 0 else 0.0)


def check_preconditioner(name: object) -> str:
    """``name`` if it is one of :data:`PRECONDITIONERS` (ValueError naming ``preconditioner`` if not)."""
    if name not in PRECONDITIONERS:
        raise ValueError(f"cg_preconditioner must be one of {', '.join(PRECONDITIONERS)}, got {name!r}")
    return str(name)


def preconditioner(a: sp.csr_matrix, kind: str = DEFAULT_PRECONDITIONER) -> sp.spmatrix:
    """P^-1 of ``a`` (3F x 3F, x y z per node): ``1 / diag(A)`` ("jacobi") or the inverses of the
    3x3 diagonal blocks (``"block-jacobi"``), as a sparse matrix ("multigrid" is a cycle, not a
    matrix: :class:`deformgl.sim.multigrid.Hierarchy`)."""
    check_preconditioner(kind)
    if kind == "jacobi":
        return sp.diags(1.0 / a.diagonal()).tocsr()
    if kind == "multigrid":
        raise ValueError("preconditioner: 'multigrid' is a V-cycle (deformgl.sim.multigrid.Hierarchy), not a matrix")
    return block_inverse(a)


def pcg(a: sp.csr_matrix, b: np.ndarray, x0: np.ndarray, *, iterations: int, tolerance: float = 0.0,
        check_every: int = 4, preconditioner_kind: str = DEFAULT_PRECONDITIONER,
        apply: Callable[[np.ndarray], np.ndarray] | None = None,
        floor: float = 0.0) -> tuple[np.ndarray, SolveReport]:
    """Preconditioned CG from ``x0``, the iteration of the GPU backend (module docstring).

    Args:
        preconditioner_kind: "jacobi" or "block-jacobi" (:func:`preconditioner`), unless
            ``apply`` (``r -> P^-1 r``, a multigrid cycle) is given.
        tolerance: stop when ``|r| <= tolerance |b|`` or ``|r| <= floor`` (N s), tested every
            ``check_every`` iterations (0: always ``iterations``).
    """
    if apply is None:
        inv = preconditioner(a, preconditioner_kind)
        apply = inv.__matmul__
    x = x0.copy()
    r = b - a @ x
    z = apply(r)
    p = z.copy()
    rz = float(r @ z)
    b_norm = float(np.linalg.norm(b))
    stop = max(tolerance * b_norm, floor)
    done = 0
    for k in range(iterations):
        if tolerance > 0 and k % check_every == 0 and float(np.linalg.norm(r)) <= stop:
            break
        q = a @ p
        pq = float(p @ q)
        alpha = rz / pq if pq != 0 else 0.0
        x += alpha * p
        r -= alpha * q
        z = apply(r)
        rz_new = float(r @ z)
        beta = rz_new / rz if rz != 0 else 0.0
        p = z + beta * p
        rz = rz_new
        done = k + 1
    true = float(np.linalg.norm(b - a @ x))
    res = true / b_norm if b_norm > 0 else 0.0
    return x, SolveReport(done, res, tolerance <= 0 or res <= tolerance or true <= floor)


def implicit_step(system: SpringSystem, state: State, dt: float, t: float, *, dv0: np.ndarray | None = None,
                  constraints: Constraints | None = None, drags: tuple[Drag, ...] = (),
                  loads: tuple[Load, ...] = (), iterations: int = 20, tolerance: float = 0.0,
                  check_every: int = 4, solver: str = "cg", geometric: str = "projected",
                  preconditioner: str = DEFAULT_PRECONDITIONER,
                  warm: str = DEFAULT_WARM_START, floor: float = 0.0,
                  multigrid: CoarseLevels | None = None) -> tuple[State, np.ndarray, SolveReport]:
    """One backward-Euler step from t to t + dt.

    Args:
        dv0: (N, 3) warm start of dv (default 0).
        solver: "cg" (:func:`pcg`) or "direct".
        preconditioner: CG's, one of :data:`PRECONDITIONERS` ("multigrid": the system needs its
            node grid).
        warm: how CG starts from ``dv0`` (:func:`warm_start`).
        floor: the residual's absolute floor in N s (:func:`residual_floor`).
        multigrid: "multigrid"'s levels (:func:`multigrid_levels`: the coarse operators of the
            first step they served, kept); built from this step's matrix if not given.
        the rest: as :func:`deformgl.sim.integrators.step` and :func:`pcg`.

    Returns:
        (the state at t + dt, dv (N, 3) for the next warm start, the solve's report).
    """
    if not dt > 0:
        raise ValueError(f"implicit_step: dt must be > 0, got {dt}")
    fixed = system.fixed[:, None]
    v = np.where(fixed, 0.0, state.v)
    lin = assemble(system, state.x, v, t, dt, drags=drags, loads=loads, geometric=geometric)
    dof = np.repeat(lin.free, 3)
    start = np.zeros(3 * system.count) if dv0 is None else np.asarray(dv0, np.float64).ravel()
    if solver == "direct":
        sol = np.asarray(spla.spsolve(lin.matrix.tocsc(), lin.rhs)) if lin.rhs.size else lin.rhs
        report = SolveReport(0, 0.0, True)
    elif solver == "cg":
        apply = None
        if preconditioner == "multigrid":
            apply = (multigrid_levels(system) if multigrid is None else multigrid).cycle(lin.matrix)
        sol, report = pcg(lin.matrix, lin.rhs, warm_start(lin.matrix, lin.rhs, start[dof], warm),
                          iterations=iterations, tolerance=tolerance, check_every=check_every,
                          preconditioner_kind=preconditioner, apply=apply, floor=floor)
    else:
        raise ValueError(f"solver must be 'cg' or 'direct', got {solver!r}")
    dv = np.zeros(3 * system.count)
    dv[dof] = sol
    dv3 = dv.reshape(-1, 3)
    v_new = v + dv3
    x_new = state.x + dt * v_new
    if constraints is not None:
        apply_constraints(constraints, x_new, v_new, t, dt)
    x_new = np.where(fixed, state.x, x_new)
    return State(x=x_new, v=np.where(fixed, 0.0, v_new), x_prev=state.x), dv3, report


def multigrid_levels(system: SpringSystem) -> CoarseLevels:
    """The multigrid of ``system``'s free nodes (:func:`deformgl.sim.multigrid.grid_levels`);
    ValueError naming ``preconditioner`` for a system without a node grid or without a coarser
    level (at most 2 nodes along every axis), on every backend alike."""
    if system.grid is None:
        raise ValueError("cg_preconditioner 'multigrid' needs a grid system (a node grid: springs.from_grid, "
                         "springs.cloth or materials.lattice_system); use 'jacobi' or 'block-jacobi'")
    levels = grid_levels(system.grid.occupied, system.grid.ijk[~system.fixed])
    if not levels:
        raise ValueError("cg_preconditioner 'multigrid' needs a grid of at least 3 nodes along some axis "
                         "(it has no coarser level); use 'block-jacobi'")
    return CoarseLevels(levels)


def solver_note(unconverged: int, steps: int, worst: float, tolerance: float) -> str | None:
    """The run's note when CG missed its tolerance in some steps (None when it never did)."""
    if unconverged == 0:
        return None
    return (f"implicit-euler: CG did not reach the tolerance {tolerance:g} in {unconverged} of {steps} steps "
            f"(worst relative residual {worst:.3g}); raise physics.implicit.iterations")


class ImplicitNumpySimulation(CpuSimulationBase):
    """Backward Euler (:func:`implicit_step`) behind the :class:`~deformgl.sim.simulation.Simulation`
    interface, float64. Holds no GL objects: ``position_slot()`` is None.

    Args:
        system, dt, constraints, drags, loads, state, t0: as
            :class:`~deformgl.sim.simulation.NumpySimulation`.
        cg_iterations, cg_tolerance, cg_check_every: see :func:`pcg`.
        cg_preconditioner: one of :data:`PRECONDITIONERS`.
        cg_warm_start: one of :data:`WARM_STARTS`.
        solver, geometric: see :func:`implicit_step`.

    Attributes:
        last_report: the last step's :class:`SolveReport`; unconverged: steps that missed the
        tolerance; worst_residual: the largest residual of those; stats: the run's
        :class:`SolverStats`; floor: the residual's absolute floor (N s, :func:`residual_floor`
        at the start state).
    """

    integrator = "implicit-euler"

    def __init__(self, system: SpringSystem, dt: float, *, constraints: Constraints | None = None,
                 drags: tuple[Drag, ...] = (), loads: tuple[Load, ...] = (), state: State | None = None,
                 t0: float = 0.0, cg_iterations: int = 20, cg_tolerance: float = 0.0, cg_check_every: int = 4,
                 cg_preconditioner: str = DEFAULT_PRECONDITIONER, cg_warm_start: str = DEFAULT_WARM_START,
                 solver: str = "cg",
                 geometric: str = "projected") -> None:
        if not dt > 0:
            raise ValueError(f"ImplicitNumpySimulation: dt must be > 0, got {dt}")
        check_cg(cg_iterations, cg_tolerance, cg_check_every)
        check_preconditioner(cg_preconditioner)
        check_warm_start(cg_warm_start)
        multigrid = multigrid_levels(system) if cg_preconditioner == "multigrid" else None
        self.system = system
        self._start_clock(dt, t0)
        self.constraints, self.drags, self.loads = constraints, tuple(drags), tuple(loads)
        self.count = system.count
        self.state = (initial_state(system, self.dt, t=self.t, drags=self.drags, loads=self.loads)
                      if state is None else state)
        self.tolerance = float(cg_tolerance)
        self.floor = residual_floor(system, self.state.x, self.dt, drags=self.drags, eps=EPS64)
        self.options: dict[str, Any] = dict(iterations=int(cg_iterations), tolerance=float(cg_tolerance),
                            check_every=int(cg_check_every), solver=solver, geometric=geometric,
                            preconditioner=cg_preconditioner, warm=cg_warm_start, floor=self.floor,
                            multigrid=multigrid)
        self.dv = np.zeros((self.count, 3))
        self.last_report = SolveReport(0, 0.0, True)
        self.unconverged, self.worst_residual = 0, 0.0
        self.stats = SolverStats("direct" if solver == "direct" else cg_preconditioner, self.tolerance, self.floor)

    def step(self, n: int = 1) -> None:
        for _ in range(n):
            new, self.dv, report = implicit_step(self.system, self.state, self.dt, self.t, dv0=self.dv,
                                                 constraints=self.constraints, drags=self.drags,
                                                 loads=self.loads, **self.options)
            self.last_report = report
            self.stats.add(report)
            if not report.within_tolerance:
                self.unconverged += 1
                self.worst_residual = max(self.worst_residual, report.residual)
            self._advance(new)

    def solver_note(self) -> str | None:
        """What the run loop notes about the solves (CG missed its tolerance), or None."""
        return solver_note(self.unconverged, self.steps_done, self.worst_residual, self.tolerance)

    def solver_stats(self) -> dict[str, Any]:
        """The run's solves for the run record (:meth:`SolverStats.summary`)."""
        return self.stats.summary()


def check_cg(iterations: object, tolerance: object, check_every: object) -> None:
    """ValueError unless iterations >= 1, tolerance >= 0 and check_every >= 1."""
    if not isinstance(iterations, int) or isinstance(iterations, bool) or iterations < 1:
        raise ValueError(f"cg_iterations must be an integer >= 1, got {iterations!r}")
    if not isinstance(tolerance, (int, float)) or isinstance(tolerance, bool) or not tolerance >= 0:
        raise ValueError(f"cg_tolerance must be a number >= 0, got {tolerance!r}")
    if not isinstance(check_every, int) or isinstance(check_every, bool) or check_every < 1:
        raise ValueError(f"cg_check_every must be an integer >= 1, got {check_every!r}")
