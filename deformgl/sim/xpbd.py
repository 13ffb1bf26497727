"""XPBD on a :class:`SpringSystem`: the float64 reference of the fragment passes of
:mod:`deformgl.sim.backends.xpbd_gpu` (Macklin, Müller & Chentanez 2016, "XPBD: position-based
simulation of compliant constrained dynamics").

Every spring s = (i, j) is a distance constraint ``C_s = |x_i - x_j| - L_s`` with compliance
``alpha_s = 1 / k_s`` (Macklin, Müller & Chentanez 2016, eq. 2-3: the potential
``U = 1/2 C^T alpha^-1 C`` is the spring's ``1/2 k (|d| - L)^2``), so the solution of the
position-level equations (Macklin, Müller & Chentanez 2016, eq. 6-7) is an implicit (backward-Euler-like) step of the same springs
and, at rest, their static equilibrium. One step of dt is ``substeps`` substeps of
``h = dt / substeps`` ("small steps"); each substep (docs/EQUATIONS.md, "XPBD"):

1. predict (Macklin, Müller & Chentanez 2016, Algorithm 1, line 1): ``v* = v / (1 + h g_i) + h a_i``,
   ``x~ = x + h v*``, with ``g_i = mass_damping + (velocity_damping + wind_drag) / m_i`` (the
   material's Rayleigh mass damping, applied implicitly to the old velocity so it is stable at
   any h and leaves the statics alone) and ``a_i = gravity + (load_i(t) + wind_drag wind) / m_i``;
   fixed nodes (inverse mass 0) keep x;
2. ``lambda = 0`` for every spring and drag;
3. ``iterations`` Jacobi sweeps: every constraint from the same iterate x,
   ``d_lambda = -omega (C + at lambda + gs grad C . (x - x^n)) / ((1 + gs) n_s (w_i + w_j) + at)``
   (Macklin, Müller & Chentanez 2016, eq. 18, with the damping term of eq. 26), ``at = alpha / h^2`` (eq. 4), ``gs = c_s / (k_s h)``
   (Macklin, Müller & Chentanez 2016, eq. 26: ``gamma = at bt / h`` with ``bt = h^2 beta``, ``beta = c_s`` the spring damping),
   ``w = 1/m``, ``grad C = +-u``, u = (x_i - x_j)/|x_i - x_j|. The Jacobi relaxation: the
   coupling term ``w_i + w_j`` is multiplied by ``n_s = max(n_i, n_j)``, n a node's constraint
   count (the averaging of Macklin, Müller, Chentanez & Kim 2014, "Unified particle physics",
   eq. 11, applied to the mass term only), so the diagonal bounds each row's Gershgorin sum of
   the linearised system ``(J W J^T + at) d_lambda = r`` and the sweep converges for
   ``0 < omega < 2``; a compliance-dominated (soft) constraint still converges at ``|1 - omega|``
   per sweep, a stiff one at about ``omega / n_s``. Every term is symmetric in i and j, so both
   copies of a spring's lambda on the GPU (one per end) stay equal. Then ``lambda += d_lambda``,
   ``x_i += w_i u d_lambda``, ``x_j -= w_j u d_lambda`` (Macklin, Müller & Chentanez 2016, eq. 17), all at once; drags are
   zero-rest-length vector constraints ``C = x - target(t + h)`` of compliance ``1 / k_drag``
   (``n_s`` = the node's count); each physics term of the system adds its constraints in the
   same sweep (``Term.xpbd``, :class:`~deformgl.sim.terms.constraints.TermConstraints`; the cells of a
   material lattice: their volume constraints ``J - 1`` and corner barriers ``J_c - J_b >= 0``,
   :mod:`deformgl.sim.terms.volume.xpbd_form`, whose constraint potentials are the energies of
   :mod:`deformgl.sim.terms.volume.energy`, so the fixed point is the equilibrium of ``springs.forces``), and
   a node's count n_i also holds the terms' constraints at it (the cells': its volume constraints,
   and its barriers active after the previous sweep); then spheres and the ground project x
   (``integrators.apply_constraints`` without the velocity rule);
4. ``v = (x - x^n) / h`` (Algorithm 1, line 15); fixed nodes: x^n exactly, v = 0.

XPBD has no explicit step limit: for any dt a sweep only redistributes bounded corrections. It
trades accuracy instead: with few iterations a stiff body is too soft (the Jacobi sweep has not
propagated the load) and the implicit step damps motion. :attr:`XpbdSolver.residual` is the
relative residual ``|C + at lambda| / |C|`` of Macklin, Müller & Chentanez 2016, eq. 7 at the last iterate
(the terms' constraints in it in metres like the springs': the cells' times the spacing h).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deformgl.sim.clock import CpuSimulationBase
from deformgl.sim.integrators import Constraints, Drag, Load, State, apply_constraints
from deformgl.sim.springs import SpringSystem
from deformgl.sim.terms.constraints import TermConstraints
from deformgl.sim.terms.glsl import refuse_terms

__all__ = [
    "DEFAULT_ITERATIONS",
    "DEFAULT_SUBSTEPS",
    "NAME",
    "OMEGA",
    "RESIDUAL_NOTE",
    "XpbdNumpy",
    "XpbdSettings",
    "XpbdSolver",
    "check_terms",
    "constraint_counts",
    "node_terms",
    "relative_residual",
    "term_constraints",
]

#: The integrator name (``make_simulation(system, NAME, ...)``, ``--integrator xpbd``).
NAME = "xpbd"
DEFAULT_ITERATIONS = 10
DEFAULT_SUBSTEPS = 1
#: Jacobi over-relaxation (0 < omega < 2; the constraint count scales the mass term, see above).
OMEGA = 1.5
#: A run notes when the relative residual of the last step is above this.
RESIDUAL_NOTE = 0.1


@dataclass(frozen=True)
class XpbdSettings:
    """Solver settings: Jacobi sweeps per substep (>= 1), substeps per step (>= 1), relaxation
    omega (0 < omega < 2)."""

    iterations: int = DEFAULT_ITERATIONS
    substeps: int = DEFAULT_SUBSTEPS
    omega: float = OMEGA

    def __post_init__(self) -> None:
        if isinstance(self.iterations, bool) or not isinstance(self.iterations, int) or self.iterations < 1:
            raise ValueError(f"xpbd: iterations must be an integer >= 1, got {self.iterations!r}")
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, int) or self.substeps < 1:
            raise ValueError(f"xpbd: substeps must be an integer >= 1, got {self.substeps!r}")
        if not 0.0 < float(self.omega) < 2.0:
            raise ValueError(f"xpbd: omega must be in (0, 2), got {self.omega!r}")


def constraint_counts(system: SpringSystem, drags: tuple[Drag, ...] = ()) -> np.ndarray:
    """(N,) float64 constraints per node: springs with k > 0 at it, its drags and the terms'
    static counts (:meth:`TermConstraints.static_counts`: the cells' volume constraints where
    kappa > 0) (>= 1). The terms' dynamic counts are added per sweep on top
    (:meth:`TermConstraints.dynamic_counts`: the cells' active barriers)."""
    live = system.stiffness > 0
    n = np.bincount(system.i[live], minlength=system.count) + np.bincount(system.j[live],
                                                                          minlength=system.count)
    n = n.astype(np.float64)
    for d in drags:
        n[d.node] += 1.0
    for term in term_constraints(system, np.zeros(system.count)):
        n += term.static_counts()
    return np.maximum(n, 1.0)


def term_constraints(system: SpringSystem, inverse_mass: np.ndarray) -> tuple[TermConstraints, ...]:
    """The XPBD forms (``Term.xpbd``) of the system's terms that act, in the terms' order, after
    :func:`check_terms`."""
    check_terms(system)
    found = []
    for term in system.terms:
        form = term.xpbd(inverse_mass) if term.acts() else None
        if form is not None:
            if not form.name:
                form.name = term.name
            found.append(form)
    return tuple(found)


def node_terms(system: SpringSystem) -> tuple[np.ndarray, np.ndarray]:
    """(inverse mass, damping rate g in 1/s), both (N,); inverse mass 0 at fixed nodes."""
    w = np.where(system.fixed, 0.0, 1.0 / system.mass)
    g = system.mass_damping + (system.velocity_damping + system.wind_drag) / system.mass
    return w, g


def check_terms(system: SpringSystem) -> None:
    """ValueError (one line) naming the first of ``system.terms`` without an XPBD form
    (:meth:`deformgl.sim.terms.Term.refusal`, which says why)."""
    refuse_terms(system.terms, "xpbd", "xpbd")


def _check_drags(drags: tuple[Drag, ...], count: int) -> None:
    nodes = [d.node for d in drags]
    for node in nodes:
        if not 0 <= node < count:
            raise ValueError(f"xpbd: drag node {node} outside the system")
    if len(set(nodes)) != len(nodes):
        raise ValueError("xpbd: two drags on one node (each drag keeps one multiplier per node)")


class XpbdSolver:
    """The float64 XPBD step (see the module docstring) on any spring system.

    Args:
        system: the springs.
        settings: iterations, substeps, omega.
        constraints: ground and spheres, or None.
        drags: scripted drags (constraints of compliance 1 / stiffness).
        loads: scripted per-node forces (in the prediction).
    """

    def __init__(self, system: SpringSystem, settings: XpbdSettings, *,
                 constraints: Constraints | None = None, drags: tuple[Drag, ...] = (),
                 loads: tuple[Load, ...] = ()) -> None:
        check_terms(system)
        _check_drags(tuple(drags), system.count)
        self.system, self.settings = system, settings
        self.constraints, self.drags, self.loads = constraints, tuple(drags), tuple(loads)
        live = system.stiffness > 0
        self.i, self.j = system.i[live], system.j[live]
        self.k, self.rest = system.stiffness[live], system.rest_length[live]
        self.ratio = system.damping[live] / self.k  # c_s / k_s (Rayleigh beta), s
        self.w, self.g = node_terms(system)
        counts = constraint_counts(system, self.drags)
        self.omega = float(settings.omega)
        self.counts = counts                                     # n_i without the active barriers
        self.count = np.maximum(counts[self.i], counts[self.j])  # n_s = max(n_i, n_j)
        self.drag_count = np.array([counts[d.node] for d in self.drags])
        #: the terms' constraints (:func:`term_constraints`: the cells' volume and barrier constraints)
        self.term_constraints = term_constraints(system, self.w)
        #: relative residual |C + at lambda| / |C| of Macklin, Müller & Chentanez 2016, eq. 7 after the last sweep (nan: no step yet)
        self.residual = float("nan")
        #: the terms' multipliers after the last substep, one per term (the cells': ((C,) volume,
        #: (C, 8) barrier)); empty before a step
        self.term_multipliers: tuple[object, ...] = ()

    def _external(self, t: float) -> np.ndarray:
        """(N, 3) a_i = gravity + (loads + wind_drag wind) / m_i at time t."""
        s = self.system
        f = np.zeros((s.count, 3))
        for load in self.loads:
            f[load.nodes] += load.node_forces(t, s.mass)
        f += s.wind_drag * s.wind
        return s.gravity + f / s.mass[:, None]

    def substep(self, x: np.ndarray, v: np.ndarray, h: float, t: float) -> tuple[np.ndarray, np.ndarray]:
        """One substep of h from (x, v) at time t: the new (x, v)."""
        fixed = self.system.fixed[:, None]
        v_star = v / (1.0 + h * self.g)[:, None] + h * self._external(t)
        xn = x
        p = np.where(fixed, x, x + h * v_star)
        at = 1.0 / (self.k * h * h)
        gs = self.ratio / h
        lam = np.zeros(len(self.k))
        lam_d = np.zeros((len(self.drags), 3))
        targets = [np.asarray(d.target(t + h), np.float64) for d in self.drags]
        at_d = [1.0 / (float(d.stiffness) * h * h) for d in self.drags]
        wi, wj = self.w[self.i], self.w[self.j]
        terms = self.term_constraints
        multipliers = [term.start() for term in terms]
        count, drag_count, counts = self.count, self.drag_count, self.counts
        for _ in range(self.settings.iterations):
            dynamic = [c for c in (term.dynamic_counts(m) for term, m in zip(terms, multipliers)) if c is not None]
            if dynamic:
                # n_i this sweep: the static count plus the terms' constraints active after the last sweep
                counts = self.counts + sum(dynamic[1:], dynamic[0])
                count = np.maximum(counts[self.i], counts[self.j])
                drag_count = np.array([counts[d.node] for d in self.drags])
            d = p[self.i] - p[self.j]
            length = np.linalg.norm(d, axis=1)
            u = d / np.where(length > 0, length, 1.0)[:, None]
            c = length - self.rest
            moved = np.einsum("sk,sk->s", u, (p[self.i] - xn[self.i]) - (p[self.j] - xn[self.j]))
            dl = -self.omega * (c + at * lam + gs * moved) / ((1.0 + gs) * count * (wi + wj) + at)
            lam += dl
            dx = np.zeros_like(p)
            np.add.at(dx, self.i, (wi * dl)[:, None] * u)
            np.add.at(dx, self.j, -(wj * dl)[:, None] * u)
            for q, drag in enumerate(self.drags):
                node = drag.node
                dld = -self.omega * (p[node] - targets[q] + at_d[q] * lam_d[q]) / (drag_count[q] * self.w[node] + at_d[q])
                lam_d[q] += dld
                dx[node] += self.w[node] * dld
            for term, m in zip(terms, multipliers):
                dx += term.sweep(p, m, counts, h, self.omega)
            p = p + dx
            if self.constraints is not None:
                apply_constraints(self.constraints, p, None, t, h)
            p = np.where(fixed, xn, p)
        c = np.linalg.norm(p[self.i] - p[self.j], axis=1) - self.rest  # at the last iterate
        at_lam = at * lam
        self.term_multipliers = tuple(multipliers)
        for term, m in zip(terms, multipliers):
            c_term, at_lam_term = term.residual_terms(p, m, h)
            c, at_lam = np.concatenate([c, c_term]), np.concatenate([at_lam, at_lam_term])
        self.residual = relative_residual(c, at_lam)
        v_new = np.where(fixed, 0.0, (p - xn) / h)
        return p, v_new

    def step(self, state: State, dt: float, t: float) -> State:
        """One step of dt (``substeps`` substeps) from ``state`` at time t."""
        if not dt > 0:
            raise ValueError(f"xpbd: dt must be > 0, got {dt}")
        n = self.settings.substeps
        h = dt / n
        x = np.array(state.x, np.float64)
        v = np.where(self.system.fixed[:, None], 0.0, np.asarray(state.v, np.float64))
        for q in range(n):
            x, v = self.substep(x, v, h, t + q * h)
        return State(x=x, v=v, x_prev=np.array(state.x, np.float64))


def relative_residual(c: np.ndarray, at_lambda: np.ndarray) -> float:
    """|C + at lambda| / |C| (0 where every C is 0)."""
    num = float(np.linalg.norm(c + at_lambda))
    den = float(np.linalg.norm(c))
    return 0.0 if den == 0.0 else num / den


class XpbdNumpy(CpuSimulationBase):
    """:class:`XpbdSolver` behind the :class:`~deformgl.sim.simulation.Simulation` interface
    (backend "numpy"; no GL objects: ``position_slot()`` is None).

    Args:
        system, dt, constraints, drags, loads: as :class:`~deformgl.sim.simulation.NumpySimulation`.
        state: start state (default: rest, v = 0); t0: its time.
        iterations, substeps, omega: :class:`XpbdSettings`.
    """

    integrator = NAME

    def __init__(self, system: SpringSystem, dt: float, *, constraints: Constraints | None = None,
                 drags: tuple[Drag, ...] = (), loads: tuple[Load, ...] = (), state: State | None = None,
                 t0: float = 0.0, iterations: int = DEFAULT_ITERATIONS, substeps: int = DEFAULT_SUBSTEPS,
                 omega: float = OMEGA) -> None:
        if not dt > 0:
            raise ValueError(f"xpbd: dt must be > 0, got {dt}")
        self.system = system
        self.settings = XpbdSettings(iterations, substeps, omega)
        self.solver = XpbdSolver(system, self.settings, constraints=constraints, drags=drags, loads=loads)
        self._start_clock(dt, t0)
        self.count = system.count
        x0 = np.array(system.rest_positions, np.float64)
        self.state = State(x0, np.zeros_like(x0), x0.copy()) if state is None else state

    @property
    def residual(self) -> float:
        """Relative residual of Macklin, Müller & Chentanez 2016, eq. 7 after the last sweep of the last substep."""
        return self.solver.residual

    def step(self, n: int = 1) -> None:
        """``n`` steps of dt."""
        for _ in range(n):
            self._advance(self.solver.step(self.state, self.dt, self.t))
