"""XPBD on the speed/accuracy chart (issue 15, items 2 and 4): XPBD x iterations x substeps x dt
against the explicit integrators at their limits, on stiff workloads.

Workloads (:data:`CASES`), each on the calibrated lattice (:func:`deformgl.sim.materials.lattice_system`)
at two resolutions:

* ``cantilever``: the FEM-checked beam of :mod:`deformgl.bench.fem` (1 x 0.1 x 0.1 m, clamped at
  x = 0, under gravity), E = 1e8 Pa, rho = 1000 kg/m^3;
* ``tissue-3kPa`` and ``tissue-1MPa``: a 0.1 m cube of soft tissue (rho = 1060 kg/m^3) clamped at
  its base, under a body force scaled so that the static strain is :data:`STRAIN` (linear: the
  lattice's static solve is the reference).

Per configuration, measured on the fragment backend (float32, llvmpipe):

* ``static error``: the tip (the free face's mean displacement, :func:`deformgl.bench.fem.lattice_value`)
  after :data:`SETTLE` lowest-mode periods with Rayleigh mass damping of twice the lowest angular
  frequency (about critical), against the linear static solve of the same springs
  (:func:`deformgl.bench.fem.static_displacement`); the explicit integrators' fixed point is that
  equilibrium (their error here is the settling residue);
* ``decay``: numerical damping, the amplitude decay rate of the lowest mode in 1/s: released from
  the static shape with no load and no damping, ``ln(A_first / A_last) / (t_last - t_first)`` over
  the tip's peak amplitudes in the first and the last of :data:`DECAY_PERIODS` periods (the
  undamped reference keeps its amplitude: 0);
* ``cost``: ms of GPU time per simulated second, (ms per step) / dt, the median of
  :data:`ROUNDS` timed batches.

``python -m studies.xpbd_study [--quick]`` prints the table (``--quick``: one workload,
one resolution, two XPBD settings, Verlet); ``--convergence`` the float64 cantilever's tip
against the springs' static tip per (iterations, substeps) (:func:`cantilever_convergence`).
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import moderngl
import numpy as np

from deformgl.bench.fem import MATERIAL, WORKLOADS, LatticeCase, Workload, lattice_case, lattice_value, \
    static_displacement, stiffness_matrix
from deformgl.sim.integrators import State
from deformgl.sim.materials import ElasticMaterial, critical_dt
from deformgl import make_simulation

__all__ = ["CASES", "CONVERGENCE", "cantilever_convergence", "STRAIN", "SETTLE", "DECAY_PERIODS", "ROUNDS", "XpbdRow", "lowest_mode", "study_case",
           "xpbd_study", "format_rows"]

STRAIN = 0.005
SETTLE = 8.0
DECAY_PERIODS = 4
ROUNDS = 3
BATCH = 10

_TISSUE = Workload("tissue", (0.1, 0.1, 0.1), "gravity", 9.81, (1, 0), (1, 1), (3, 5), "m")


@dataclass(frozen=True)
class _Case:
    name: str
    workload: Workload
    material: ElasticMaterial
    across: tuple[int, int]


CASES: dict[str, _Case] = {
    "tissue-3kPa": _Case("tissue-3kPa", _TISSUE, ElasticMaterial(3.0e3, 1060.0, name="tissue"), (3, 5)),
    "tissue-1MPa": _Case("tissue-1MPa", _TISSUE, ElasticMaterial(1.0e6, 1060.0, name="stiff tissue"), (3, 5)),
    "cantilever": _Case("cantilever", WORKLOADS["cantilever"], MATERIAL, (3, 5)),
}
#: (iterations, substeps) of the XPBD rows, each at dt = 1/60 and 1/240 s.
XPBD_SETTINGS = ((10, 1), (100, 1), (10, 10), (30, 30))
XPBD_DTS = (1.0 / 60.0, 1.0 / 240.0)
EXPLICIT = (("verlet", 0.9), ("rk4", 0.9))


@dataclass(frozen=True)
class XpbdRow:
    """One configuration: workload, nodes across, node count, method ("xpbd" or an explicit
    integrator), dt in s, iterations and substeps (XPBD; 1 and 1 otherwise), static error
    (relative), decay rate of the lowest mode (1/s), ms per step, ms per simulated second."""

    case: str
    across: int
    nodes: int
    method: str
    dt: float
    iterations: int
    substeps: int
    static_error: float
    decay: float
    ms_per_step: float
    cost: float


def lowest_mode(case: LatticeCase) -> float:
    """The lowest angular frequency in rad/s of the lattice (fixed nodes held)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import eigsh

    system = case.system
    free = np.repeat(~system.fixed, 3)
    k = stiffness_matrix(system)[free][:, free]
    m = sp.diags(np.repeat(system.mass, 3)[free])
    values = eigsh(k.tocsc(), k=1, M=m.tocsc(), sigma=0.0, which="LM", return_eigenvectors=False)
    return float(math.sqrt(max(float(values[0]), 0.0)))


def _setup(c: _Case, across: int) -> tuple[LatticeCase, float, float]:
    """The lattice case with the load that gives :data:`STRAIN` (tissue), its static tip in m and
    its lowest angular frequency."""
    case = lattice_case(c.workload, across, c.material)
    if c.workload is _TISSUE:
        g = STRAIN * c.material.youngs_modulus / (c.material.density * c.workload.size[1])
        system = replace(case.system, gravity=np.array([0.0, -g, 0.0]))
        case = replace(case, system=system, forces=case.forces * g / c.workload.magnitude)
    return case, lattice_value(case, static_displacement(case.system, case.forces)), lowest_mode(case)


def _options(method: str, iterations: int, substeps: int) -> dict[str, int]:
    return {"iterations": iterations, "substeps": substeps} if method == "xpbd" else {}


def _settled_tip(ctx: moderngl.Context, case: LatticeCase, method: str, dt: float, omega1: float,
                 iterations: int, substeps: int) -> float:
    system = replace(case.system, mass_damping=2.0 * omega1)
    steps = math.ceil(SETTLE * 2.0 * math.pi / omega1 / dt)
    with make_simulation(system, method, "fragment", dt=dt, ctx=ctx, **_options(method, iterations, substeps)) as sim:
        sim.step(steps)
        u = np.asarray(sim.positions(), np.float64) - system.rest_positions
    return lattice_value(case, u)


def _decay(ctx: moderngl.Context, case: LatticeCase, method: str, dt: float, omega1: float,
           iterations: int, substeps: int) -> float:
    """ln(A_first / A_last) / time between, over the tip's peaks (see the module docstring)."""
    system = replace(case.system, gravity=np.zeros(3), mass_damping=0.0)
    x0 = system.rest_positions + static_displacement(case.system, case.forces)
    state = State(x0, np.zeros_like(x0), x0.copy())
    period = 2.0 * math.pi / omega1
    per = max(1, math.ceil(period / dt))
    sample = max(1, per // 40)  # ~40 samples a period
    tips = []
    with make_simulation(system, method, "fragment", dt=dt, ctx=ctx, state=state,
                         **_options(method, iterations, substeps)) as sim:
        for _ in range(0, DECAY_PERIODS * per, sample):
            sim.step(sample)
            u = np.asarray(sim.positions(), np.float64) - system.rest_positions
            tips.append(abs(lattice_value(case, u)))
    tips_a = np.array(tips)
    n = max(1, per // sample)
    first, last = float(tips_a[:n].max()), float(tips_a[-n:].max())
    if not (first > 0 and last > 0):
        return float("inf")
    span = (len(tips_a) - n) * sample * dt
    return math.log(first / last) / span if span > 0 else 0.0


def _ms_per_step(ctx: moderngl.Context, case: LatticeCase, method: str, dt: float, iterations: int,
                 substeps: int) -> float:
    with make_simulation(case.system, method, "fragment", dt=dt, ctx=ctx,
                         **_options(method, iterations, substeps)) as sim:
        sim.step(2)
        ctx.finish()
        times = []
        for _ in range(ROUNDS):
            start = time.perf_counter()
            sim.step(BATCH)
            ctx.finish()
            times.append((time.perf_counter() - start) / BATCH * 1e3)
    return statistics.median(times)


def study_case(ctx: moderngl.Context, c: _Case, across: int, *,
               xpbd: Sequence[tuple[int, int]] = XPBD_SETTINGS, dts: Sequence[float] = XPBD_DTS,
               explicit: Sequence[tuple[str, float]] = EXPLICIT,
               progress: Callable[[str], None] | None = None) -> list[XpbdRow]:
    """The rows of one workload at one resolution (``progress`` gets each row's line)."""
    case, static, omega1 = _setup(c, across)
    configs: list[tuple[str, float, int, int]] = [("xpbd", dt, it, sub) for dt in dts for it, sub in xpbd]
    configs += [(name, f * critical_dt(c.material, case.spacing, name, barrier=False), 1, 1) for name, f in explicit]
    rows = []
    for method, dt, it, sub in configs:
        tip = _settled_tip(ctx, case, method, dt, omega1, it, sub)
        decay = _decay(ctx, case, method, dt, omega1, it, sub)
        ms = _ms_per_step(ctx, case, method, dt, it, sub)
        rows.append(XpbdRow(c.name, across, case.grid.count, method, dt, it, sub, abs(tip - static) / abs(static),
                            decay, ms, ms / dt))
        if progress:
            progress(format_rows(rows[-1:]).splitlines()[-1])
    return rows


def xpbd_study(ctx: moderngl.Context, *, quick: bool = False,
               progress: Callable[[str], None] | None = None) -> list[XpbdRow]:
    """Every workload x resolution x configuration (``quick``: the cantilever at 3 across, XPBD
    (10, 1) and (30, 30) at 1/60 s, Verlet)."""
    rows: list[XpbdRow] = []
    if quick:
        return study_case(ctx, CASES["cantilever"], 3, xpbd=((10, 1), (30, 30)), dts=(1.0 / 60.0,),
                          explicit=(("verlet", 0.9),))
    for c in CASES.values():
        for across in c.across:
            if progress:
                progress(f"xpbd study: {c.name} at {across} across")
            rows += study_case(ctx, c, across, progress=progress)
    return rows


#: (iterations, substeps) of :func:`cantilever_convergence`.
CONVERGENCE = ((10, 1), (100, 1), (1, 50), (1, 200), (1, 400), (1, 800), (10, 50), (5, 200), (10, 200),
               (5, 400), (10, 400))


def cantilever_convergence(settings: Sequence[tuple[int, int]] = CONVERGENCE, *, across: int = 3,
                           steps: int = 30, dt: float = 1.0 / 60.0) -> list[tuple[int, int, float, float]]:
    """The float64 XPBD cantilever (E = 1e8 Pa, Rayleigh alpha 64 1/s) after ``steps`` steps of
    ``dt``: (iterations, substeps, tip / the springs' static tip, relative residual) per setting."""
    from deformgl.sim.xpbd import XpbdNumpy

    material = ElasticMaterial(MATERIAL.youngs_modulus, MATERIAL.density, mass_damping=64.0)
    case = lattice_case(WORKLOADS["cantilever"], across, material)
    static = lattice_value(case)
    out = []
    for it, sub in settings:
        sim = XpbdNumpy(case.system, dt, iterations=it, substeps=sub)
        sim.step(steps)
        out.append((it, sub, lattice_value(case, sim.positions() - case.system.rest_positions) / static,
                    sim.residual))
    return out


def format_rows(rows: Sequence[XpbdRow]) -> str:
    """A fixed-width table, one line per row."""
    head = (f"{'case':<12} {'across':>6} {'nodes':>6} {'method':<7} {'dt s':>9} {'iter':>5} {'sub':>4} "
            f"{'static err':>10} {'decay 1/s':>9} {'ms/step':>8} {'ms per sim s':>12}")
    lines = [head]
    for r in rows:
        lines.append(f"{r.case:<12} {r.across:>6} {r.nodes:>6} {r.method:<7} {r.dt:>9.3g} {r.iterations:>5} "
                     f"{r.substeps:>4} {r.static_error:>10.3g} {r.decay:>9.3g} {r.ms_per_step:>8.3g} {r.cost:>12.4g}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:  # python -m studies.xpbd_study
    parser = argparse.ArgumentParser(description="XPBD against the explicit integrators on stiff workloads")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--convergence", action="store_true",
                        help="instead: the float64 cantilever's tip / static tip per (iterations, substeps)")
    args = parser.parse_args(argv)
    if args.convergence:
        for it, sub, ratio, residual in cantilever_convergence():
            print(f"iterations {it:5d} substeps {sub:5d} sweeps/step {it * sub:6d}: tip / static {ratio:.4f}, "
                  f"residual {residual:.3g}", flush=True)
        return 0
    from deformgl.bench.sim_speed import machine_line
    from deformgl.gl.context import create_context

    ctx = create_context()
    print(machine_line(ctx))
    print(format_rows(xpbd_study(ctx, quick=args.quick, progress=lambda line: print(line, flush=True))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
