"""The five integrators of Movania & Feng 2012 on a :class:`SpringSystem`, float64 reference.

One signature for all (warp.sim style, state in, state out)::

    state = initial_state(system, dt)
    state = step(system, "rk4", state, dt, t, constraints=..., drags=...)

Definitions: Movania & Feng 2012, section 3 (eq. 3 ``a = F/m``, eq. 4-5 explicit Euler, eq. 6
Verlet, Movania & Feng 2012, eq. 7 implicit Euler, numbered as the text refers to them; midpoint and RK4 are only
named). The formulas were lost in extraction; their standard forms are in ``docs/EQUATIONS.md``.
Here ``a(x, v, t) = F / m`` with F from :func:`deformgl.sim.springs.forces`:

* ``euler`` (explicit/forward): ``x' = x + dt v``, ``v' = v + dt a(x, v)``.
* ``semi-implicit`` (the paper's "implicit Euler", symplectic): ``v' = v + dt a(x, v)``,
  ``x' = x + dt v'``.
* ``midpoint`` (RK2): ``x_m = x + dt/2 v``, ``v_m = v + dt/2 a(x, v)``; ``x' = x + dt v_m``,
  ``v' = v + dt a(x_m, v_m)``.
* ``rk4``: the classical four stages on the first-order system (x, v).
* ``verlet`` (position Verlet): ``x' = 2x - x_prev + dt^2 a(x, v)`` with no stored velocity: the
  velocity seen by damping, spring damping and wind is the backward difference
  ``v = (x - x_prev)/dt`` (as the fragment pass computes it), i.e. the README's damped form
  ``x' = x + (1 - c dt/m)(x - x_prev) + dt^2 a`` for global damping. That velocity is first-order
  accurate, so with velocity-dependent forces Verlet's global order drops from 2 to 1.

Constraints after the step (docs/EQUATIONS.md "Constraints after the step"; Movania & Feng 2012
section 4): spheres in order, then the ground plane (the ground wins where they conflict), then
fixed nodes get their old position back exactly and zero velocity. A sphere projects a node
inside it onto its surface (a node exactly at the centre goes up, +y). The velocity integrators
also make the contact inelastic and frictionless: the velocity component along the contact
normal n becomes ``max(v . n, u . n)``, u the obstacle's velocity over the step (0 for the
ground), so a resting node does not build up speed into the obstacle. Verlet needs no such rule:
its next velocity ``(x' - x)/dt`` already contains the projection.

Times: ``t`` is the time at the start of the step; stages evaluate forces (drag targets) at
their own times (t + dt/2, t + dt); constraints use the sphere centres at t + dt.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from deformgl.sim.springs import SpringSystem, forces
from deformgl.sim.scripted import Drag, Load

__all__ = ["INTEGRATORS", "EXPLICIT_INTEGRATORS", "IMPLICIT_INTEGRATORS", "STABLE_INTEGRATORS", "GPU_BUFFERS",
           "VEC4_BYTES", "State", "Sphere", "Constraints", "Drag", "Load",
           "acceleration", "apply_constraints", "initial_state", "step", "simulate",
           "run_until_converged",
           "memory_per_node"]

#: The five explicit integrators of this module (the stage table :data:`deformgl.sim.stages.SPECS`,
#: each with a stability limit: :mod:`deformgl.sim.limits`).
EXPLICIT_INTEGRATORS: tuple[str, ...] = ("euler", "semi-implicit", "midpoint", "rk4", "verlet")
#: Integrators that solve a system each step (no explicit dt limit; :mod:`deformgl.sim.implicit`).
IMPLICIT_INTEGRATORS: tuple[str, ...] = ("implicit-euler",)
#: Integrators without an explicit step limit, outside the stage table (XPBD: deformgl.sim.xpbd).
STABLE_INTEGRATORS: tuple[str, ...] = ("xpbd",)
#: Every integrator name make_simulation, the scenes and the CLI take (``deformgl.INTEGRATORS``).
INTEGRATORS: tuple[str, ...] = EXPLICIT_INTEGRATORS + IMPLICIT_INTEGRATORS + STABLE_INTEGRATORS

#: Bytes of one RGBA32F texel or one vec4 vertex attribute.
VEC4_BYTES = 16
#: The per-node vec4 buffers a GPU step keeps alive at once, assuming a pass never reads the
#: buffer it writes (ping-pong, as both fragment passes and transform feedback require) and that
#: static node data (mass, flags, connectivity) is not state. Verlet: current, previous, next
#: position (the three rotating textures of ARCHITECTURE.md). Euler and semi-implicit: x, v in
#: and out. Midpoint: x, v, the midpoint stage (x_m, v_m), x', v'. RK4: x, v, a stage state
#: (x_s, v_s) and a running sum of the weighted stage slopes (sum_x, sum_v), the latter two each
#: read by one pass and written by the next (ping-pong pairs); the last pass writes x', v' into
#: a free stage pair.
GPU_BUFFERS: dict[str, tuple[str, ...]] = {
    "euler": ("x", "v", "x_out", "v_out"),
    "semi-implicit": ("x", "v", "x_out", "v_out"),
    "midpoint": ("x", "v", "x_mid", "v_mid", "x_out", "v_out"),
    "rk4": ("x", "v", "x_stage_a", "v_stage_a", "x_stage_b", "v_stage_b",
            "sum_x_a", "sum_v_a", "sum_x_b", "sum_v_b"),
    "verlet": ("x", "x_prev", "x_out"),
    # backward Euler (deformgl.sim.backends.implicit_gpu): x, v in and out, the CG's b, P^-1,
    # dv, r, p (each ping-pong but b and P^-1), q and the per-texel dot product
    "implicit-euler": ("x", "v", "x_out", "v_out", "b", "inv", "dv", "dv_out", "r", "r_out", "p", "p_out",
                       "q", "prod"),
    # XPBD (deformgl/sim/backends/xpbd_gpu.py): x, v and x', v'; two iterates; two sets of up to
    # 6 multiplier textures (one per 4 neighbour constraints); two drag multipliers
    "xpbd": ("x", "v", "x_out", "v_out", "p_a", "p_b", *(f"lambda_{s}{layer}" for s in "ab" for layer in range(6)),
             "lambda_drag_a", "lambda_drag_b"),
}


def memory_per_node(name: str) -> int:
    """Bytes of GPU state per node for integrator ``name`` (see :data:`GPU_BUFFERS`)."""
    return VEC4_BYTES * len(GPU_BUFFERS[_check_name(name)])


@dataclass(frozen=True, eq=False)
class State:
    """What changes during a run.

    Attributes:
        x: (N, 3) float64 positions.
        v: (N, 3) float64 velocities (Verlet: the backward difference (x - x_prev)/dt, derived).
        x_prev: (N, 3) float64 positions one step earlier (only Verlet reads them).
    """

    x: np.ndarray
    v: np.ndarray
    x_prev: np.ndarray


@dataclass(frozen=True, eq=False)
class Sphere:
    """A sphere obstacle; nodes are kept out of it.

    Attributes:
        centre: (3,) position, or t -> (3,) for a moving sphere.
        radius: world units.
    """

    centre: ArrayLike | Callable[[float], ArrayLike]
    radius: float

    def centre_at(self, t: float) -> np.ndarray:
        """(3,) centre at time t."""
        c = self.centre(t) if callable(self.centre) else self.centre
        return np.asarray(c, dtype=np.float64)


@dataclass(frozen=True)
class Constraints:
    """Position constraints applied after every step.

    Attributes:
        ground: keep y >= ground (None: no ground plane).
        spheres: sphere obstacles.
    """

    ground: float | None = None
    spheres: tuple[Sphere, ...] = ()


def _check_name(name: str) -> str:
    if name not in EXPLICIT_INTEGRATORS:
        raise ValueError(f"unknown integrator {name!r}; expected one of {', '.join(EXPLICIT_INTEGRATORS)}")
    return name


def acceleration(system: SpringSystem, x: np.ndarray, v: np.ndarray, t: float,
                 drags: tuple[Drag, ...] = (), loads: tuple[Load, ...] = ()) -> np.ndarray:
    """``a = F / m`` (Movania & Feng 2012 eq. 3), zero at fixed nodes. (N, 3) float64."""
    a = forces(system, x, v, t, drags, loads) / system.mass[:, None]
    return np.where(system.fixed[:, None], 0.0, a)


def initial_state(system: SpringSystem, dt: float, *, x: ArrayLike | None = None,
                  v: ArrayLike | None = None, t: float = 0.0,
                  drags: tuple[Drag, ...] = (), loads: tuple[Load, ...] = ()) -> State:
    """A start state: positions (default: rest), velocities (default 0; 0 at fixed nodes).

    ``x_prev = x - dt v + dt^2/2 a(x, v, t)``, the Taylor expansion of x(t - dt) to O(dt^3):
    Verlet started from it keeps its global order 2 (x_prev = x - dt v alone makes it order 1).
    """
    x0 = np.array(system.rest_positions if x is None else x, dtype=np.float64)
    v0 = np.zeros_like(x0) if v is None else np.array(v, dtype=np.float64)
    v0[system.fixed] = 0.0
    a0 = acceleration(system, x0, v0, t, drags, loads)
    return State(x=x0, v=v0, x_prev=x0 - dt * v0 + 0.5 * dt * dt * a0)


_Accel = Callable[[np.ndarray, np.ndarray, float], np.ndarray]


def _euler(acc: _Accel, s: State, dt: float, t: float) -> tuple[np.ndarray, np.ndarray]:
    # Movania & Feng eq. 4-5 (lost; docs/EQUATIONS.md): x' = x + dt v, v' = v + dt a(x, v)
    return s.x + dt * s.v, s.v + dt * acc(s.x, s.v, t)


def _semi_implicit(acc: _Accel, s: State, dt: float, t: float) -> tuple[np.ndarray, np.ndarray]:
    # Movania & Feng eq. 7 (lost; docs/EQUATIONS.md): v' = v + dt a(x, v); x' = x + dt v'
    v = s.v + dt * acc(s.x, s.v, t)
    return s.x + dt * v, v


def _midpoint(acc: _Accel, s: State, dt: float, t: float) -> tuple[np.ndarray, np.ndarray]:
    # docs/EQUATIONS.md: midpoint (RK2) at (x + dt/2 v, v + dt/2 a), then the full step
    xm = s.x + 0.5 * dt * s.v
    vm = s.v + 0.5 * dt * acc(s.x, s.v, t)
    return s.x + dt * vm, s.v + dt * acc(xm, vm, t + 0.5 * dt)


def _rk4(acc: _Accel, s: State, dt: float, t: float) -> tuple[np.ndarray, np.ndarray]:
    # docs/EQUATIONS.md: classical RK4 on the first-order system y = (x, v), y' = (v, a(x, v, t))
    h = 0.5 * dt
    k1x, k1v = s.v, acc(s.x, s.v, t)
    k2x, k2v = s.v + h * k1v, acc(s.x + h * k1x, s.v + h * k1v, t + h)
    k3x, k3v = s.v + h * k2v, acc(s.x + h * k2x, s.v + h * k2v, t + h)
    k4x, k4v = s.v + dt * k3v, acc(s.x + dt * k3x, s.v + dt * k3v, t + dt)
    return (s.x + dt / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x),
            s.v + dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v))


def _verlet(acc: _Accel, s: State, dt: float, t: float) -> tuple[np.ndarray, None]:
    # Movania & Feng eq. 6 (lost; docs/EQUATIONS.md): x' = 2x - x_prev + dt^2 a,
    # v = (x - x_prev)/dt for the velocity-dependent forces (as shaders/sim/verlet.frag)
    v = (s.x - s.x_prev) / dt
    return 2.0 * s.x - s.x_prev + dt * dt * acc(s.x, v, t), None


_STEPPERS: dict[str, Callable[[_Accel, State, float, float],
                              tuple[np.ndarray, np.ndarray | None]]] = {
    "euler": _euler, "semi-implicit": _semi_implicit, "midpoint": _midpoint, "rk4": _rk4,
    "verlet": _verlet}


def _contact(x: np.ndarray, v: np.ndarray | None, hit: np.ndarray, normal: np.ndarray,
             surface: np.ndarray, u: np.ndarray) -> None:
    """Project the nodes ``hit`` onto ``surface`` and make their normal velocity >= u . n."""
    x[hit] = surface[hit]
    if v is not None:
        vn = np.einsum("nk,nk->n", v[hit], normal[hit])
        un = normal[hit] @ u
        v[hit] += (np.maximum(vn, un) - vn)[:, None] * normal[hit]


def apply_constraints(constraints: Constraints, x: np.ndarray, v: np.ndarray | None,
                      t: float, dt: float) -> None:
    """Spheres, then the ground, in place on the new positions x (and velocities v, if any).

    Movania & Feng 2012 section 4 ("positivity" ground constraint and sphere collision), in the
    form of docs/EQUATIONS.md: ``y' = max(y', y_ground)``; ``|x' - s| < r`` ->
    ``x' = s + r (x' - s)/|x' - s|``. ``t`` is the time at the start of the step.
    """
    for sphere in constraints.spheres:
        centre = sphere.centre_at(t + dt)
        u = (centre - sphere.centre_at(t)) / dt
        rel = x - centre
        dist = np.linalg.norm(rel, axis=1)
        up = np.array([0.0, 1.0, 0.0])
        normal = np.where((dist > 0)[:, None], rel / np.where(dist > 0, dist, 1.0)[:, None], up)
        _contact(x, v, dist < sphere.radius, normal, centre + sphere.radius * normal, u)
    if constraints.ground is not None:
        below = x[:, 1] < constraints.ground
        surface = x.copy()
        surface[:, 1] = constraints.ground
        normal = np.broadcast_to(np.array([0.0, 1.0, 0.0]), x.shape)
        _contact(x, v, below, normal, surface, np.zeros(3))


def step(system: SpringSystem, name: str, state: State, dt: float, t: float, *,
         constraints: Constraints | None = None, drags: tuple[Drag, ...] = (),
         loads: tuple[Load, ...] = ()) -> State:
    """One step of integrator ``name`` from time t to t + dt, then the constraints.

    Args:
        system: the spring system.
        name: one of :data:`EXPLICIT_INTEGRATORS`.
        state: the state at time t (not modified).
        dt: step in s, > 0.
        t: time at the start of the step.
        constraints: ground plane and spheres, or None.
        drags: scripted drags.
        loads: scripted per-node forces.

    Returns:
        The state at t + dt; fixed nodes keep their position bit for bit, with zero velocity.
    """
    if not dt > 0:
        raise ValueError(f"step: dt must be > 0, got {dt}")
    stepper = _STEPPERS[_check_name(name)]
    fixed = system.fixed[:, None]
    start = State(state.x, np.where(fixed, 0.0, state.v), state.x_prev)

    def acc(x: np.ndarray, v: np.ndarray, s: float) -> np.ndarray:
        return acceleration(system, x, v, s, drags, loads)

    x_new, v_new = stepper(acc, start, dt, t)
    if constraints is not None:
        apply_constraints(constraints, x_new, v_new, t, dt)
    x_new = np.where(fixed, state.x, x_new)
    if v_new is None:
        v_new = (x_new - state.x) / dt  # Verlet's velocity: the backward difference
    return State(x=x_new, v=np.where(fixed, 0.0, v_new), x_prev=state.x)


def simulate(system: SpringSystem, name: str, dt: float, steps: int, *,
             state: State | None = None, t0: float = 0.0, constraints: Constraints | None = None,
             drags: tuple[Drag, ...] = (), loads: tuple[Load, ...] = ()) -> State:
    """``steps`` steps from ``state`` (default :func:`initial_state` at rest) at time t0."""
    s = initial_state(system, dt, t=t0, drags=drags, loads=loads) if state is None else state
    for n in range(steps):
        s = step(system, name, s, dt, t0 + n * dt, constraints=constraints, drags=drags,
                 loads=loads)
    return s


def run_until_converged(system: SpringSystem, name: str, dt: float, *, max_steps: int,
                        threshold: float | None = None, patience: int = 1,
                        state: State | None = None, t0: float = 0.0,
                        constraints: Constraints | None = None,
                        drags: tuple[Drag, ...] = (),
                        loads: tuple[Load, ...] = ()) -> tuple[State, int]:
    """Step until the largest node displacement in a step is below ``threshold``.

    Movania & Feng 2012, section 4: "repeated until the difference between the current and the
    previous position of the mass is below a threshold" (0.001 in their units; here
    ``0.001 * system.spacing`` by default). The test is per step, so it depends on dt: a system
    starting from rest moves only about ``a dt^2`` in its first step, and every node of a
    swinging system slows down at a turning point. ``patience`` > 1 asks for that many
    consecutive steps below the threshold.

    Returns:
        (state, steps taken); steps taken == max_steps when it did not converge.
    """
    limit = 0.001 * system.spacing if threshold is None else threshold
    s = initial_state(system, dt, t=t0, drags=drags, loads=loads) if state is None else state
    quiet = 0
    for n in range(max_steps):
        new = step(system, name, s, dt, t0 + n * dt, constraints=constraints, drags=drags,
                   loads=loads)
        moved = float(np.max(np.linalg.norm(new.x - s.x, axis=1), initial=0.0))
        s = new
        quiet = quiet + 1 if moved < limit else 0
        if quiet >= patience:
            return s, n + 1
    return s, max_steps
