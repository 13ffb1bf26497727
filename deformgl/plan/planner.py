"""``deformgl plan SCENE --tolerance X``: model only what a scene requires (issue 12, item 5).

From the measurements of ``python -m studies.accuracy`` and ``deformgl bench trade --resolution``
(docs/ACCURACY.md), pick the coarsest grid, the integrator and the largest dt whose predicted
relative error of the body's deflection is below the tolerance, and say why:

* discretisation: ``e_d = C (h / t)^p`` with ``t`` the body's thickness (the smallest side of
  its bounding box, in m) and (C, p) fitted by least squares to the measured lattice-vs-FEM errors
  of the workload that deforms like the body (:data:`MEASURED`: bending, the cantilever;
  compression, the block; torsion, the twisted bar), at the body's Poisson's ratio
  (:func:`measured_errors`, :data:`MEASURED_NU`: compression's error grows with nu). The grid gets the fewest nodes across the
  thickness with ``e_d <= tolerance - e_t - e_32``;
* time stepping: Verlet (the cheapest step of the resolution study) at dt = 0.9 x the rest
  stiffness's :func:`~deformgl.sim.materials.critical_dt` when its measured time-stepping error
  ``e_t = D f`` (first order: the mass damping's velocity is a backward difference) is below a
  tenth of the tolerance and the cells' barrier allows that step (:func:`barrier_cap`: it does
  not, 0.31 x at nu = 1/4, since the dt check holds the barrier's envelope); else semi-implicit
  Euler at the largest f that keeps it so (float32 Verlet gets *less* accurate at smaller dt: the
  positions' rounding swallows a dt^2);
* float32: :data:`FLOAT32_ERROR`, the largest fragment-vs-NumPy difference measured at 0.9 x;
* implicit Euler (``bench trade --stiff``, docs/PERFORMANCE.md) at the frame step
  :data:`FRAME_DT` instead, when it is cheaper per simulated second and its error fits: its fixed
  point is the equilibrium at any dt, so its time-stepping error of the static deflection is 0
  and what remains is :data:`IMPLICIT_STATIC_ERROR` (the largest measured residue at the
  iterations the plan picks). Two preconditioners are weighed: Jacobi CG, whose iterations grow
  with the body's length (:func:`implicit_iterations`: 10 up to 17 nodes along, 30 above, more at
  a larger nu, measured to 33 along), and the multigrid V-cycle, whose iterations do not
  (:func:`multigrid_iterations`; its residue measured to 33 along, its iterations to 65). Every method is priced in its own terms
  (:mod:`deformgl.plan.cost`): the fragment passes, texel fetches, reductions and reads of its
  steps in a 60 Hz frame, at the renderer's measured rates (:data:`~deformgl.plan.cost.RATES`):
  an explicit step is one pass of 21 to 28 fetches a node, an implicit step tens of passes and
  reductions, a multigrid iteration a V-cycle over every level. It damps motion: the plan prints
  how much of the lowest mode (beam estimate ``w1 = 3.516 t / L^2 sqrt(E / (12 rho))``) survives
  a second, ``(1 + (w1 dt)^2)^(-1/(2 dt))``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from deformgl.errors import InputError
from deformgl.plan.cost import RATES, coarse_counts, explicit_work, implicit_work
from deformgl.sim.materials import PRESETS, ElasticMaterial, critical_dt

__all__ = ["MEASURED", "MEASURED_NU", "measured_errors", "LOADS", "MAX_FRACTION", "TIME_STEP_ERROR", "FLOAT32_ERROR", "FRAME_DT",
           "IMPLICIT_STATIC_ERROR", "Plan", "POISSON_CG_FACTOR", "implicit_iterations", "MULTIGRID_ITERATIONS",
           "MULTIGRID_MEASURED_ALONG", "multigrid_iterations", "poisson_iteration_factor",
           "fit", "make_plan", "lowest_mode_estimate", "plan_scene", "planned_scene", "add_parser", "run"]

#: Lattice-vs-FEM relative errors measured by ``python -m studies.accuracy`` (nodes across the
#: thickness -> |deformgl / FEM - 1|; 2-core AMD EPYC; docs/ACCURACY.md).
MEASURED: dict[str, dict[int, float]] = {
    "bending": {2: 0.459, 3: 0.192, 4: 0.0992, 5: 0.0596, 8: 0.0211, 9: 0.0164, 17: 0.00430},
    "compression": {2: 0.0601, 3: 0.0249, 5: 0.00984, 9: 0.00381, 17: 0.00145},
    "torsion": {2: 0.719, 3: 0.439, 5: 0.185, 9: 0.0576, 17: 0.0155},
}
LOADS = tuple(MEASURED)
#: The same at the body's Poisson's ratio (the lattice with its cells' volumetric term), at 3, 5,
#: 9 and 17 nodes across (the finest four, as :func:`fit` takes at 1/4) (2-core Intel Xeon, 2026-12-05): compression and torsion against
#: ``studies.accuracy``'s displacement FEM at that nu (Richardson-extrapolated; its own estimated
#: error on the block grows to 0.4 % at 0.45 and 0.9 % at 0.49, the locking of displacement
#: elements; ``python -m studies.tissue_accuracy``, table 4), bending against the
#: locking-free mixed FEM (the same command's table 1, ``--across 3,5,9,17``; docs/ACCURACY.md
#: sections 3 and 5). Torsion is shear and does not move with nu; compression
#: does: 3.7x the 1/4 error at 0.45 and 4.6x at 0.49 (9 across).
MEASURED_NU: dict[float, dict[str, dict[int, float]]] = {
    0.3: {"bending": {3: 0.1774, 5: 0.0549, 9: 0.0154, 17: 0.0043},
          "compression": {3: 0.0366, 5: 0.0145, 9: 0.0057, 17: 0.0022},
          "torsion": {3: 0.4385, 5: 0.1847, 9: 0.0575, 17: 0.0155}},
    0.45: {"bending": {3: 0.1490, 5: 0.0487, 9: 0.0151, 17: 0.0047},
           "compression": {3: 0.0907, 5: 0.0362, 9: 0.0141, 17: 0.0052},
           "torsion": {3: 0.4379, 5: 0.1841, 9: 0.0571, 17: 0.0152}},
    0.49: {"bending": {3: 0.1480, 5: 0.0496, 9: 0.0159, 17: 0.0052},
           "compression": {3: 0.1114, 5: 0.0446, 9: 0.0175, 17: 0.0064},
           "torsion": {3: 0.4375, 5: 0.1836, 9: 0.0566, 17: 0.0147}},
}
MAX_FRACTION = 0.9
#: Time-stepping error of the tip per unit dt / critical dt (the rest stiffness's,
#: ``critical_dt(barrier=False)``; ``bench trade --resolution``, first order): Verlet 3.3e-4 at
#: 0.9, semi-implicit Euler 8.6e-4 at 0.9 (2 across, the largest).
TIME_STEP_ERROR = {"verlet": 4.0e-4, "semi-implicit": 1.0e-3}
#: The largest float32 error (fragment vs NumPy) measured at 0.9 x the critical dt; float32
#: Verlet's grows as dt shrinks (3e-2 at 0.25 x), so Verlet is only used at 0.9 x.
FLOAT32_ERROR = {"verlet": 1.0e-4, "semi-implicit": 1.0e-5}
MAX_ACROSS = 257
#: Implicit Euler's step in s (one 60 Hz frame).
FRAME_DT = 1.0 / 60.0
#: Implicit Euler's largest measured static residue (relative to the sag, against the lattice's
#: equilibrium, after 0.5-1 s at dt 1/60 s) at the iterations :func:`implicit_iterations` picks:
#: 10 up to 17 across (2.1e-4), 30 above (5.2e-4); 10 at 33 across left 5.6 %. (Its fixed point
#: is the equilibrium: a longer run leaves less.)
IMPLICIT_STATIC_ERROR = 6.0e-4
#: The largest grid ``bench trade --stiff`` measured implicit Euler with Jacobi CG on (a cube, 33
#: nodes along each side): the plan does not extrapolate its iteration counts and residue beyond it.
IMPLICIT_MEASURED_ALONG = 33
#: Multigrid CG iterations per step at nu = 1/4 (times :func:`poisson_iteration_factor` above):
#: on the 1 MPa block at dt = 1/60 s, 3 iterations a step left 2.0e-4 of the sag (float32, 9 and
#: 17 across) and 5.0e-4 at 33 across, where 10 Jacobi iterations left 5.6 % (``python -m
#: studies.preconditioners``; its iterations to a residual of 1e-4 stay 6 to 8 from 9 to 65
#: across, 13 to 18 at nu = 0.45).
MULTIGRID_ITERATIONS = 3
#: The largest grid the multigrid's static residue at :data:`MULTIGRID_ITERATIONS` was measured
#: on (the block at 33 across; its iterations to a residual of 1e-4 were measured to 65).
MULTIGRID_MEASURED_ALONG = 33
#: CG iterations at Poisson's ratio nu over those at 1/4 (the cells' lambda - mu): the mean CG
#: iterations per step to a relative residual of 1e-4 on a 9-across liver block in float64
#: (``python -m studies.cells_cost``: 17.3, 42.4 and 90.3 at nu 0.25, 0.45, 0.49). On the 6 x 12 x 23 rubber
#: beam the static residue reached 6e-4 of the sag at 30 iterations at 1/4, 60 at 0.45 (30 left
#: 0.59 %) and 150 at 0.49 (100 left 0.15 %): within these factors (74 and 157).
POISSON_CG_FACTOR = {0.25: 1.0, 0.45: 42.4 / 17.3, 0.49: 90.3 / 17.3}


def measured_errors(load: str, poissons_ratio: float = 0.25) -> dict[int, float]:
    """The lattice's measured errors of ``load`` by nodes across at ``poissons_ratio``: at 1/4
    :data:`MEASURED`; above, at the resolutions of :data:`MEASURED_NU`, log e interpolated
    linearly in log 1/(1 - 2 nu) between the measured ratios (1/4 included), held at the 0.49
    table above 0.49 (the largest measured)."""
    if poissons_ratio <= 0.25:
        return dict(MEASURED[load])
    tables = {0.25: MEASURED, **MEASURED_NU}
    return {n: _in_nu({nu: t[load][n] for nu, t in tables.items()}, poissons_ratio, extrapolate=False)
            for n in MEASURED_NU[max(MEASURED_NU)][load]}


def _in_nu(values: dict[float, float], poissons_ratio: float, *, extrapolate: bool) -> float:
    """``values`` (measured at some Poisson's ratios, 1/4 the smallest) at ``poissons_ratio``: log
    value linear in log 1/(1 - 2 nu) between them; above the largest, along the last segment
    (``extrapolate``) or held."""
    def axis(nu: float) -> float:
        return math.log(1.0 / (1.0 - 2.0 * nu))
    nus = sorted(values)
    xs, ys = [axis(nu) for nu in nus], [math.log(values[nu]) for nu in nus]
    x = axis(max(nus[0], poissons_ratio))
    if x > xs[-1] and extrapolate:
        return math.exp(ys[-1] + (x - xs[-1]) * (ys[-1] - ys[-2]) / (xs[-1] - xs[-2]))
    return math.exp(float(np.interp(x, xs, ys)))


def fit(load: str, finest: int = 4, poissons_ratio: float = 0.25) -> tuple[float, float]:
    """(C, p) of ``e_d = C (h / t)^p``: least squares of log e against log(h/t) over the
    ``finest`` finest measured resolutions of ``load`` at ``poissons_ratio``
    (:func:`measured_errors`)."""
    pts = sorted(measured_errors(load, poissons_ratio).items())[-finest:]
    x = np.log([1.0 / (n - 1) for n, _ in pts])
    y = np.log([e for _, e in pts])
    p, logc = np.polyfit(x, y, 1)
    return float(math.exp(logc)), float(p)


@dataclass(frozen=True)
class Plan:
    """What :func:`make_plan` chose and the predicted errors (relative)."""

    tolerance: float
    load: str
    size: tuple[float, float, float]
    material: ElasticMaterial
    across: int
    spacing: float
    nodes_along_longest: int
    integrator: str
    fraction: float
    dt: float
    critical: float
    discretisation: float
    time_stepping: float
    float32: float
    model: tuple[float, float]
    iterations: int = 0           # CG iterations per step (implicit Euler), 0 explicit
    why_integrator: str = ""      # why this integrator and not the other kind
    mode_left: float = 1.0        # amplitude of the lowest mode left after 1 s (implicit: < 1)
    preconditioner: str = ""      # implicit Euler's CG preconditioner, "" explicit
    priced: tuple[str, ...] = ()  # each method's frame in passes, fetches, reductions and seconds

    @property
    def error(self) -> float:
        """The predicted total relative error."""
        return self.discretisation + self.time_stepping + self.float32

    def lines(self) -> list[str]:
        """What was chosen and why, for the terminal."""
        c, p = self.model
        t = min(self.size)
        m = self.material
        return [
            f"body: {self.size[0]:.4g} x {self.size[1]:.4g} x {self.size[2]:.4g} m (thickness "
            f"{t:.4g} m); material {m.name or 'from the scene'}: E = {m.youngs_modulus:g} Pa, "
            f"rho = {m.density:g} kg/m^3; tolerance {self.tolerance:g} (relative deflection error)",
            f"grid: {self.across} nodes across the thickness, spacing {self.spacing:.4g} m, "
            f"nodes_along_longest = {self.nodes_along_longest}: the coarsest grid whose predicted "
            f"discretisation error {self.discretisation:.2%} (e = {c:.3g} (h/t)^{p:.2f}, fitted to "
            f"the FEM study's {self.load} workload, docs/ACCURACY.md) leaves room for the time stepping and float32",
            (f"integrator: implicit-euler at dt = {self.dt:.3g} s with {self.iterations} {self.preconditioner} CG "
             f"iterations "
             f"(stable at any dt; the explicit integrators' critical dt on their grid is {self.critical:.3g} s): its "
             f"fixed point is the "
             f"equilibrium, predicted static error {self.float32:.2%} (bench trade --stiff)"
             if self.iterations else
             f"integrator: {self.integrator} at dt = {self.dt:.3g} s = {self.fraction:.2f} x the rest "
             f"critical dt {self.critical:.3g} s (2 h sqrt(rho / (36 mu + 12 kappa)); the cells' barrier caps it at "
             f"{barrier_cap(m):.2f} x): predicted time-stepping error {self.time_stepping:.2%} (bench trade "
             f"--resolution), float32 {self.float32:.2%}"),
            *([f"why: {self.why_integrator}"] if self.why_integrator else []),
            *(f"cost of a 1/60 s frame: {line}" for line in self.priced),
            *([f"note: the discretisation errors are those measured at this body's nu = {m.poissons_ratio:g} "
               f"(interpolated between the lattice's measurements at nu 0.25, 0.3, 0.45 and 0.49"
               f"{', held at 0.49' if m.poissons_ratio > 0.49 else ''}; compression grows with nu)"]
              if m.poissons_ratio > 0.25 else []),
            f"predicted total error {self.error:.2%} <= {self.tolerance:.2%}",
            "scene keys: [grid] spacing = " f"{self.spacing:.6g} (or nodes_along_longest = "
            f"{self.nodes_along_longest}); [physics] integrator = \"{self.integrator}\", dt = {self.dt:.6g}"
            + (f"; [physics.implicit] iterations = {self.iterations}, preconditioner = \"{self.preconditioner}\""
               if self.iterations else ""),
        ]


def make_plan(size: tuple[float, float, float], material: ElasticMaterial, tolerance: float,
              load: str = "bending", *, implicit: bool = True) -> Plan:
    """The plan of a body of bounding box ``size`` (m) and ``material`` for ``tolerance``
    (``implicit``: also consider implicit Euler at :data:`FRAME_DT`, module docstring).

    Raises:
        InputError: a tolerance outside (0, 1), an unknown load, or a tolerance that needs more
            than :data:`MAX_ACROSS` nodes across.
    """
    if not (0.0 < tolerance < 1.0):
        raise InputError(f"--tolerance: a relative error between 0 and 1, got {tolerance}")
    if load not in MEASURED:
        raise InputError(f"--load: one of {', '.join(LOADS)}, got {load!r}")
    if min(size) <= 0:
        raise InputError(f"the body's bounding box {size} m has no thickness")
    # Verlet at 0.9 x critical while its time-stepping error fits a tenth of the tolerance; a
    # smaller dt with float32 Verlet is less accurate (module docstring), so then semi-implicit.
    # The fractions are of the rest stiffness's critical dt, which the errors were measured on;
    # the cells' barrier caps the step below it (materials.critical_dt with its envelope)
    integrator = "verlet"
    cap = barrier_cap(material)
    fraction = MAX_FRACTION
    if cap < MAX_FRACTION or TIME_STEP_ERROR["verlet"] * fraction > 0.1 * tolerance:
        integrator = "semi-implicit"
        fraction = min(cap, 0.1 * tolerance / TIME_STEP_ERROR[integrator])
    e_t, e_32 = TIME_STEP_ERROR[integrator] * fraction, FLOAT32_ERROR[integrator]
    budget = tolerance - e_t - e_32
    c, p = fit(load, poissons_ratio=material.poissons_ratio)
    if budget <= 0:
        raise InputError(f"--tolerance {tolerance}: below the float32 error {e_32:g}")
    cells = max(1, math.ceil((c / budget) ** (1.0 / p)))  # cells across: e_d(1/cells) <= budget
    if cells + 1 > MAX_ACROSS:
        raise InputError(f"--tolerance {tolerance}: needs {cells + 1} nodes across the thickness "
                         f"(more than {MAX_ACROSS}); the lattice error falls as h^{p:.2f}")
    thickness = min(size)
    h = thickness / cells
    along = math.ceil(max(size) / h - 1e-9) + 1  # the built spacing is at most the planned one
    crit = critical_dt(material, h, integrator, barrier=False)
    plan = Plan(tolerance, load, size, material, cells + 1, h, along, integrator, fraction,
                fraction * crit, crit, c * (1.0 / cells) ** p, e_t, e_32, (c, p))
    return _consider_implicit(plan) if implicit else plan


def barrier_cap(material: ElasticMaterial) -> float:
    """The largest explicit step as a fraction of the rest stiffness's critical dt that the dt
    check's Gershgorin bound with the cells' barrier accepts, less the 10 % margin of
    :data:`MAX_FRACTION` (0.31 at nu = 1/4: the barrier's envelope, ``materials.critical_dt``)."""
    return MAX_FRACTION * critical_dt(material, 1.0) / critical_dt(material, 1.0, barrier=False)


def implicit_iterations(along: int, poissons_ratio: float = 0.25, across: int | None = None) -> int:
    """CG iterations per step of the plan's implicit Euler (:data:`IMPLICIT_STATIC_ERROR`), by
    the nodes along the body's longest side and across its thickness (``None``: as many as
    along): how far truncated CG must carry a correction, times :func:`poisson_iteration_factor`
    (the cells' volumetric stiffness lambda - mu raises the system's condition number), rounded
    up. 10 for compact bodies up to 17 along (cubes to 17: 2.1e-4 of the sag left), else 30:
    measured on beams, 10 iterations never settle 6 x 21 nodes (7-66 % of the sag over 2 s) and
    leave 1.0e-3 of it on 9 x 17 (rubber at 1/4, 1 s at 1/60 s), 30 leave 2e-8 there and 1.2e-5
    on 12 x 23. So 10 only where ``along <= 17`` and ``along <= 1.5 across``."""
    compact = along <= 17 and (across is None or along <= 1.5 * across)
    base = 10 if compact else 30
    return int(math.ceil(base * poisson_iteration_factor(poissons_ratio) - 1e-9))


def poisson_iteration_factor(poissons_ratio: float) -> float:
    """How many times more CG iterations implicit Euler needs at ``poissons_ratio`` than at 1/4
    (:data:`POISSON_CG_FACTOR`, interpolated linearly in log factor against log 1/(1 - 2 nu);
    extrapolated above 0.49 along the last segment)."""
    return _in_nu(POISSON_CG_FACTOR, poissons_ratio, extrapolate=True)


def multigrid_iterations(poissons_ratio: float = 0.25) -> int:
    """Multigrid CG iterations per step of the plan's implicit Euler: :data:`MULTIGRID_ITERATIONS`
    times :func:`poisson_iteration_factor`, rounded up, at any length (the V-cycle carries a
    correction across the body in one application)."""
    return int(math.ceil(MULTIGRID_ITERATIONS * poisson_iteration_factor(poissons_ratio) - 1e-9))


def lowest_mode_estimate(size: tuple[float, float, float], material: ElasticMaterial) -> float:
    """w1 in rad/s, the first bending mode of a cantilever of the body's length and thickness
    (Euler-Bernoulli: ``3.516 t / L^2 sqrt(E / (12 rho))``), an estimate for any body."""
    t, length = min(size), max(size)
    return 3.516 * t / length ** 2 * math.sqrt(material.youngs_modulus / (12.0 * material.density))


def _dims(size: tuple[float, float, float], h: float) -> tuple[int, int, int]:
    d = [math.floor(e / h + 1e-9) + 1 for e in size]
    return d[0], d[1], d[2]


def _consider_implicit(plan: Plan) -> Plan:
    """The plan with implicit Euler at the frame step when it is cheaper per simulated second on
    the coarsest grid that fits its own error budget (the tolerance less
    :data:`IMPLICIT_STATIC_ERROR`), with the cheaper of Jacobi and multigrid CG, every method
    priced by :mod:`deformgl.plan.cost`; and the reason either way."""
    import dataclasses

    c, p = plan.model
    budget = plan.tolerance - IMPLICIT_STATIC_ERROR
    w1 = lowest_mode_estimate(plan.size, plan.material)
    left = (1.0 + (w1 * FRAME_DT) ** 2) ** (-0.5 / FRAME_DT)
    cells = max(1, math.ceil((c / budget) ** (1.0 / p))) if budget > 0 else MAX_ACROSS
    if cells + 1 > MAX_ACROSS:
        return dataclasses.replace(plan, why_integrator=(
            f"implicit-euler rejected: its static residue {IMPLICIT_STATIC_ERROR:.2%} leaves no room for the grid "
            f"within the tolerance {plan.tolerance:.2%}"))
    h = min(plan.size) / cells
    along = math.ceil(max(plan.size) / h - 1e-9) + 1
    nu = plan.material.poissons_ratio
    volumetric = nu > 0.25
    # the grids as built: nodes_along_longest sets the spacing
    dims_i = _dims(plan.size, max(plan.size) / (along - 1))
    dims_e = _dims(plan.size, max(plan.size) / (plan.nodes_along_longest - 1))
    nodes_i, nodes_e = math.prod(dims_i), math.prod(dims_e)
    steps = FRAME_DT / plan.dt   # explicit steps per frame (per simulated second: not rounded)
    step = explicit_work(nodes_e, plan.integrator, cells=volumetric)
    explicit_s = step.seconds() * steps
    shown = step.times(max(1, round(steps)))
    priced = [f"{plan.integrator}, {steps:.3g} steps of {plan.dt:.3g} s on {nodes_e} nodes: {shown.words()}, "
              f"{explicit_s * 1e3:.3g} ms"]
    options = []
    for pre, its, measured in (("jacobi", implicit_iterations(along, nu, cells + 1), IMPLICIT_MEASURED_ALONG),
                               ("multigrid", multigrid_iterations(nu), MULTIGRID_MEASURED_ALONG)):
        if along > measured:
            priced.append(f"implicit-euler ({pre}): not considered, its grid would have {along} nodes along the "
                          f"longest side, beyond the {measured} its iterations were measured on")
            continue
        if pre == "multigrid" and max(dims_i) <= 2:
            continue
        work = implicit_work(nodes_i, its, pre, coarse=coarse_counts(dims_i) if pre == "multigrid" else None,
                             cells=volumetric)
        options.append((work.seconds(), pre, its))
        priced.append(f"implicit-euler ({pre}, {its} CG iterations) on {nodes_i} nodes: {work.words()}, "
                      f"{work.seconds() * 1e3:.3g} ms")
    rates = f"(priced at {RATES.renderer}'s measured rates, deformgl.plan.cost)"
    priced[0] += f" {rates}"
    if not options:
        return dataclasses.replace(plan, priced=tuple(priced), why_integrator=(
            f"implicit-euler not considered: its grid would have {along} nodes along the longest side, beyond "
            f"the {MULTIGRID_MEASURED_ALONG} that its iterations and residue were measured on"))
    implicit_s, pre, its = min(options)
    ratio = explicit_s / implicit_s
    grid = ("the same grid" if cells + 1 == plan.across else
            f"a grid of {cells + 1} across for its budget ({nodes_i} nodes against {nodes_e})")
    if ratio > 1.0:
        why = (f"{plan.integrator} would need {steps:.3g} steps of {plan.dt:.3g} s per 1/60 s frame; one implicit "
               f"step ({its} {pre} CG iterations) on {grid} is {ratio:.3g}x cheaper per simulated second "
               f"(each method priced in passes, fetches and reductions below); it damps motion: the lowest mode "
               f"(w1 ~ {w1:.3g} rad/s) keeps {left:.2g} of its amplitude per second (for dynamics use "
               f"{plan.integrator})")
        return dataclasses.replace(plan, integrator="implicit-euler", across=cells + 1, spacing=h,
                                   nodes_along_longest=along, fraction=FRAME_DT / plan.critical, dt=FRAME_DT,
                                   discretisation=c * (1.0 / cells) ** p, time_stepping=0.0,
                                   float32=IMPLICIT_STATIC_ERROR, iterations=its, why_integrator=why, mode_left=left,
                                   preconditioner=pre, priced=tuple(priced))
    why = (f"implicit-euler rejected: {plan.integrator} needs {steps:.3g} steps per 1/60 s frame and the cheaper "
           f"implicit step ({its} {pre} CG iterations, on {grid}) costs more: explicit is "
           f"{1 / ratio:.3g}x cheaper per simulated second (each method priced in passes, fetches and reductions "
           f"below; and it keeps the motion that implicit Euler damps to {left:.2g} per second)")
    return dataclasses.replace(plan, why_integrator=why, priced=tuple(priced))


def plan_scene(path: str | Path, tolerance: float, load: str = "bending",
               material: ElasticMaterial | None = None) -> Plan:
    """:func:`make_plan` for a scene file: its mesh's bounding box times ``mesh.scale`` and its
    ``[material]`` (or ``material`` when the scene has none).

    Raises:
        InputError: the scene is invalid, a cloth, or has no material and none was given.
    """
    from deformgl.grid.meshio import load_mesh
    from deformgl.scene.schema import load_scene

    scene = load_scene(path)
    if scene.cloth is not None or scene.mesh is None:
        raise InputError(f"{path}: plan models volume bodies (a mesh and a solid "
                         "[material]); this scene is a cloth")
    found = getattr(scene.physics, "material", None)
    if found is not None and not isinstance(found, ElasticMaterial):
        raise InputError(f"{path}: material: plan needs a solid (youngs_modulus, density)")
    if found is not None and found.model != "lattice":
        raise InputError(f'{path}: material.model: the planner\'s error and cost models are the lattice\'s; '
                         f'"{found.model}" is not planned yet')
    chosen = found or material
    if chosen is None:
        raise InputError(f"{path}: material: the scene has no [material] table; give --preset "
                         f"({', '.join(PRESETS)}) or --youngs-modulus and --density")
    mesh = load_mesh(scene.mesh.path)
    extent = (mesh.bounds[1] - mesh.bounds[0]) * float(getattr(scene.mesh, "scale", 1.0))
    return make_plan(tuple(float(e) for e in extent), chosen, tolerance, load)  # type: ignore[arg-type]


def implicit_refusal(scene: Any) -> str | None:
    """Why ``render --tolerance`` must not move ``scene`` to implicit Euler at 1/60 s, or None:
    a backend without it, or motion that the step would damp (drags, moving spheres, pulls that
    stop: implicit Euler at the frame step keeps almost none of a stiff body's motion)."""
    physics = scene.physics
    if physics.backend == "feedback":
        return "the scene's backend (feedback) has no implicit Euler"
    moving = [name for name, present in (
        ("drags", bool(physics.drag)), ("moving spheres", any(s.path is not None for s in physics.sphere)),
        ("pulls that stop", any(math.isfinite(p.stop) for p in physics.pull))) if present]
    if moving:
        return (f"the scene has {' and '.join(moving)}: motion that implicit Euler at 1/60 s damps "
                f"(deformgl plan weighs it for statics)")
    return None


def planned_scene(scene: Any, tolerance: float, load: str = "bending") -> tuple[Any, Plan]:
    """``deformgl render SCENE --tolerance X``: the scene on the plan's grid, integrator and dt,
    with as many steps as keep its simulated time (``physics.dt x physics.steps``), and the plan.

    Raises:
        InputError: the scene has no solid ``[material]`` or is a cloth (see :func:`make_plan`).
    """
    import dataclasses

    from deformgl.grid.meshio import load_mesh
    from deformgl.scene.spec import GridSpec

    material = getattr(scene.physics, "material", None)
    if scene.mesh is None or not isinstance(material, ElasticMaterial):
        raise InputError(f"{scene.source.name}: --tolerance: needs a volume body with a solid [material] "
                         f"(youngs_modulus, density); see deformgl plan --help")
    if material.model != "lattice":
        raise InputError(f'{scene.source.name}: --tolerance: the planner\'s error and cost models are the lattice\'s; '
                         f'material.model = "{material.model}" is not planned yet')
    mesh = load_mesh(scene.mesh.path)
    extent = (mesh.bounds[1] - mesh.bounds[0]) * float(scene.mesh.scale)
    refusal = implicit_refusal(scene)
    plan = make_plan(tuple(float(e) for e in extent), material, tolerance, load,  # type: ignore[arg-type]
                     implicit=refusal is None)
    if refusal is not None:
        plan = dataclasses.replace(plan, why_integrator=f"implicit-euler not considered: {refusal}")
    simulated = scene.physics.dt * scene.physics.steps
    steps = max(1, math.ceil(simulated / plan.dt - 1e-9))
    physics = dataclasses.replace(scene.physics, integrator=plan.integrator, dt=plan.dt, steps=steps)
    if plan.iterations:
        physics = dataclasses.replace(physics, implicit=dataclasses.replace(
            physics.implicit, iterations=plan.iterations, preconditioner=plan.preconditioner))
    return dataclasses.replace(scene, grid=GridSpec(plan.nodes_along_longest, None), physics=physics), plan


def add_parser(sub: Any) -> None:
    """The ``plan`` subcommand on the CLI's subparsers."""
    pl = sub.add_parser("plan", help="pick the coarsest grid, integrator and dt for an accuracy",
                        description="Model only what a scene requires: from the measured lattice-vs-FEM errors "
                                    "(docs/ACCURACY.md) and time-stepping errors (bench trade --resolution), the "
                                    "coarsest grid, the integrator and the largest dt whose predicted relative "
                                    "deflection error is below --tolerance, and why (docs/ACCURACY.md).")
    pl.add_argument("scene", type=Path, help="scene file (.toml) with a [material] table, or a shipped scene's name")
    pl.add_argument("--tolerance", type=float, required=True, metavar="X",
                    help="relative error of the deflection, e.g. 0.02 for 2 %%")
    pl.add_argument("--load", choices=["bending", "compression", "torsion"], default="bending",
                    help="how the body deforms: which measured workload's error model applies "
                         "(cantilever, compressed block, twisted bar; default bending)")
    pl.add_argument("--preset", default=None, help="the material when the scene has no [material] table")
    pl.add_argument("--youngs-modulus", type=float, default=None, metavar="PA",
                    help="E in Pa when the scene has no [material] table (with --density)")
    pl.add_argument("--density", type=float, default=None, metavar="KG_M3", help="rho in kg/m^3 (with --youngs-modulus)")


def run(args: Any, source: Path) -> int:
    """``deformgl plan``: the plan of the scene file ``source`` (found by the CLI), printed."""
    material = None
    if args.preset is not None:
        if args.preset not in PRESETS:
            raise InputError(f"--preset: one of {', '.join(PRESETS)}, got {args.preset!r}")
        material = PRESETS[args.preset]
    elif args.youngs_modulus is not None or args.density is not None:
        if args.youngs_modulus is None or args.density is None:
            raise InputError("--youngs-modulus and --density: give both")
        try:
            material = ElasticMaterial(args.youngs_modulus, args.density)
        except ValueError as exc:
            raise InputError(str(exc).replace("material.", "--").replace("_", "-")) from None
    plan = plan_scene(source, args.tolerance, args.load, material)
    print(f"plan for {args.scene}:")
    print("\n".join("  " + line for line in plan.lines()))
    return 0
