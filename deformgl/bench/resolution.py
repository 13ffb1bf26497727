"""``deformgl bench trade --resolution``: the grid resolution on the speed/accuracy chart.

Workload: the FEM-checked cantilever of :mod:`deformgl.bench.fem` (1 x 0.1 x 0.1 m, clamped,
released from rest under gravity, Rayleigh mass damping :data:`ALPHA`), for each resolution x
integrator x dt (fractions of :func:`~deformgl.sim.materials.critical_dt`). The tip's error at
T = :data:`SIM_TIME`, relative to the FEM static tip, kept apart as discretisation (the static
lattice against converged FEM, or :data:`FEM_TIP` without scikit-fem), time stepping (float64 at
dt against float64 RK4 at the RK4 limit / :data:`REFERENCE_DIVISOR`) and float32 (the fragment
backend against NumPy); ``error`` is their sum. Cost: the fragment backend's ms per simulated
second, the median of :data:`ROUNDS` alternating rounds. The front
(:func:`deformgl.bench.trade.pareto_front`) says which grid and integrator is cheapest for an accuracy."""

from __future__ import annotations

import dataclasses
import math
import os
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any

import moderngl
import numpy as np

from deformgl.bench import report_files
from deformgl.bench.fem import MATERIAL, WORKLOADS, LatticeCase, lattice_case, lattice_value
from deformgl.bench.trade import pareto_front
from deformgl.sim.materials import ElasticMaterial, critical_dt
from deformgl.sim.simulation import make_simulation

__all__ = ["ALPHA", "SIM_TIME", "ACROSS", "QUICK_ACROSS", "INTEGRATORS", "FRACTIONS",
           "QUICK_FRACTIONS", "FEM_TIP", "ResolutionRow", "ResolutionReport", "resolution_study"]

ALPHA = 64.0
SIM_TIME = 0.05
ACROSS = (2, 3, 4, 5)
QUICK_ACROSS = (2, 3)
#: Explicit Euler and midpoint have no stable dt without stiffness damping (see
#: deformgl.sim.materials.critical_dt): the lattice here has none.
INTEGRATORS = ("verlet", "semi-implicit", "rk4")
QUICK_INTEGRATORS = ("verlet", "semi-implicit")
FRACTIONS = (0.25, 0.5, 0.9)
QUICK_FRACTIONS = (0.5, 0.9)
REFERENCE_DIVISOR = 16.0
ROUNDS, BATCH = 5, 40
#: The converged FEM tip deflection of the cantilever in m (``python -m studies.accuracy``:
#: ElementHex2 on 1, 2, 4 elements across, Richardson-extrapolated), used without scikit-fem.
FEM_TIP = 1.477008e-02


@dataclass(frozen=True)
class ResolutionRow:
    """One grid x integrator x dt; errors relative to the FEM tip, cost of the fragment backend."""

    across: int
    spacing: float
    nodes: int
    integrator: str
    fraction: float
    dt: float
    steps: int
    discretisation: float
    time_stepping: float
    float32: float
    error: float
    ms_per_step: float
    ms_per_sim_s: float


@dataclass
class ResolutionReport:
    """What :func:`resolution_study` measured."""

    rows: list[ResolutionRow]
    fem_tip: float
    fem_source: str
    machine: str
    date: str
    sim_time: float = SIM_TIME

    def front(self) -> list[ResolutionRow]:
        """Pareto front of error against ms per simulated second, cheapest first."""
        return pareto_front(self.rows, key=lambda r: (r.ms_per_sim_s, r.error))

    def cheapest(self, tolerance: float) -> ResolutionRow | None:
        """The cheapest configuration whose error is at most ``tolerance`` (relative)."""
        ok = [r for r in self.front() if r.error <= tolerance]
        return ok[0] if ok else None

    def format(self) -> str:
        """The terminal table and the front in words."""
        lines = [self.machine, f"date: {self.date}; cantilever 1 x 0.1 x 0.1 m released under "
                 f"gravity, E = 1e8 Pa, rho = 1000 kg/m^3, mass damping {ALPHA:g} 1/s; tip at T = "
                 f"{self.sim_time:g} s; errors relative to the FEM static tip {self.fem_tip:.5e} m "
                 f"({self.fem_source}): discretisation (static lattice vs FEM), time stepping "
                 "(float64 run vs a converged float64 RK4 run), float32 (fragment vs NumPy); "
                 "cost: fragment backend, median of alternating rounds"]
        head = (f"  {'across':>6} {'h [m]':>8} {'nodes':>6} {'integrator':>13} {'dt/crit':>7} "
                f"{'dt [s]':>9} {'steps':>6} | {'discr.':>8} {'time':>8} {'float32':>8} "
                f"{'total':>8} | {'ms/step':>8} {'ms/sim-s':>9}")
        lines += [head, "  " + "-" * (len(head) - 2)]
        lines += [f"  {r.across:>6} {r.spacing:>8.4f} {r.nodes:>6} {r.integrator:>13} "
                  f"{r.fraction:>7.2f} {r.dt:>9.2e} {r.steps:>6} | {r.discretisation:>8.1e} "
                  f"{r.time_stepping:>8.1e} {r.float32:>8.1e} {r.error:>8.1e} | "
                  f"{r.ms_per_step:>8.3f} {r.ms_per_sim_s:>9.1f}" for r in self.rows]
        lines.append("Pareto front (total error against ms per simulated second, fragment backend):")
        above = math.inf
        for r in self.front():
            span = "above" if above == math.inf else f"between {r.error:.2e} and"
            lines.append(f"  for errors {span} {r.error if above == math.inf else above:.2e}: "
                         f"{r.across} nodes across (h = {r.spacing:.4f} m), {r.integrator} at "
                         f"dt = {r.dt:.2e} s = {r.fraction:.2f} x critical, {r.ms_per_sim_s:.3g} "
                         "ms per simulated second")
            above = r.error
        lines.append(f"  nothing measured is more accurate than {above:.1e}: a finer grid "
                     "(python -m studies.accuracy: the error falls about as h^1.7)")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {"machine": self.machine, "date": self.date, "sim_time": self.sim_time,
                "fem_tip": self.fem_tip, "fem_source": self.fem_source,
                "rows": [dataclasses.asdict(r) for r in self.rows]}

    def write_csv(self, path: str | os.PathLike) -> None:
        """One line per row, atomically."""
        report_files.write_csv(path, [dataclasses.asdict(r) for r in self.rows],
                               [f.name for f in dataclasses.fields(ResolutionRow)])

    def write_json(self, path: str | os.PathLike) -> None:
        """:meth:`to_dict` as JSON, atomically."""
        report_files.write_json(path, self.to_dict())

    @classmethod
    def read_json(cls, path: str | os.PathLike) -> ResolutionReport:
        """A report written by :meth:`write_json`."""
        import json

        with open(path, encoding="utf-8") as f:
            d = json.load(f)
        return cls([ResolutionRow(**r) for r in d["rows"]], d["fem_tip"], d["fem_source"],
                    d["machine"], d["date"], d["sim_time"])

    def write_chart(self, path: str | os.PathLike) -> None:
        """PNG: left, the total error against ms per simulated second (a colour per grid, a
        marker per integrator, the front dashed); right, the time-stepping (dashed) and float32
        (solid) errors against dt / critical dt, per grid and integrator.

        Raises:
            DeformglError: matplotlib is not installed (``pip install 'deformgl[plot]'``).
        """
        import textwrap

        from deformgl.bench.charts import new_figure, save_png

        fig, axes = new_figure(1, 2, width=5.5, height=4.4, what="resolution")
        left, right = axes[0]
        grids = sorted({r.across for r in self.rows})
        names = list(dict.fromkeys(r.integrator for r in self.rows))
        markers = {"verlet": "o", "semi-implicit": "s", "rk4": "D"}
        colours = {n: f"C{i}" for i, n in enumerate(grids)}
        for n in grids:
            for name in names:
                rows = sorted((r for r in self.rows if r.across == n and r.integrator == name),
                              key=lambda r: r.fraction)
                if not rows:
                    continue
                left.plot([r.ms_per_sim_s for r in rows], [r.error for r in rows], ls="none",
                          marker=markers.get(name, "o"), color=colours[n], ms=5,
                          label=f"{n} across, {name}")
                fr = [r.fraction for r in rows]
                right.plot(fr, [max(r.float32, 1e-12) for r in rows], marker=markers.get(name, "o"),
                           color=colours[n], lw=1, ms=4, label=f"{n} across, {name}")
                right.plot(fr, [max(r.time_stepping, 1e-12) for r in rows], ls="--",
                           marker=markers.get(name, "o"), color=colours[n], lw=0.8, ms=3)
        front = self.front()
        left.plot([r.ms_per_sim_s for r in front], [r.error for r in front], drawstyle="steps-post",
                  color="k", ls="--", lw=0.8, label="Pareto front")
        left.set(xscale="log", yscale="log", xlabel="ms per simulated second (fragment backend)",
                 ylabel="tip error vs FEM (discretisation + time + float32)",
                 title="cantilever: grid x integrator x dt")
        right.set(yscale="log", xlabel="dt / critical dt",
                  ylabel="relative tip error (solid: float32, dashed: time stepping)",
                  title="the errors that dt controls")
        for ax in (left, right):
            ax.grid(True, which="both", lw=0.3, alpha=0.5)
            ax.legend(fontsize=5, ncol=2)
        fig.suptitle(textwrap.fill(f"{self.machine} ({self.date}); tip at T = {self.sim_time:g} s, "
                                   f"FEM tip {self.fem_tip:.5e} m", 150), fontsize=7)
        fig.tight_layout()
        save_png(fig, path)


def _tip_at(case: LatticeCase, integrator: str, dt: float, steps: int, backend: str = "numpy",
            ctx: moderngl.Context | None = None) -> float:
    with make_simulation(case.system, integrator, backend, dt=dt, ctx=ctx) as sim:
        sim.step(steps)
        u = np.asarray(sim.positions(), np.float64) - case.system.rest_positions
    return lattice_value(case, u)


def fem_tip() -> tuple[float, str]:
    """The FEM static tip in m and where it comes from (scikit-fem if installed)."""
    try:
        import skfem  # type: ignore[import-untyped,import-not-found,unused-ignore]  # noqa: F401
    except ImportError:
        return FEM_TIP, "studies.accuracy's value; scikit-fem not installed"
    from deformgl.bench.fem import fem_reference

    value, _, _ = fem_reference(WORKLOADS["cantilever"], (1, 2, 4))
    return value, "scikit-fem ElementHex2, 1/2/4 across, extrapolated"


def resolution_study(ctx: moderngl.Context, *, quick: bool = False,
                     across: Sequence[int] | None = None, integrators: Sequence[str] | None = None,
                     fractions: Sequence[float] | None = None,
                     progress: Callable[[str], None] | None = None) -> ResolutionReport:
    """Every resolution x integrator x dt of the cantilever (see the module docstring).

    Args:
        ctx: the GL context (the fragment backend's runs and timings).
        quick: :data:`QUICK_ACROSS`, two integrators, :data:`QUICK_FRACTIONS`, 2 rounds of 10
            steps, a reference at the RK4 limit / 4, and the stored :data:`FEM_TIP` instead of
            a new FEM solve.
        across, integrators, fractions: override the defaults.
        progress: called with a line before each resolution.
    """
    from deformgl.bench.sim_speed import cpu_line
    from deformgl.bench.sim_speed import machine_line

    across = tuple(across or (QUICK_ACROSS if quick else ACROSS))
    integrators = tuple(integrators or (QUICK_INTEGRATORS if quick else INTEGRATORS))
    fractions = tuple(fractions or (QUICK_FRACTIONS if quick else FRACTIONS))
    rounds, batch = (2, 10) if quick else (ROUNDS, BATCH)
    material = ElasticMaterial(MATERIAL.youngs_modulus, MATERIAL.density, mass_damping=ALPHA)
    w = WORKLOADS["cantilever"]
    fem, source = (FEM_TIP, "studies.accuracy's value") if quick else fem_tip()
    pending: list[dict[str, Any]] = []
    for n in across:
        if progress:
            progress(f"resolution: {n} nodes across")
        case = lattice_case(w, n, material)
        static = lattice_value(case)
        ref_dt = critical_dt(material, case.spacing, "rk4", barrier=False) / (4.0 if quick else REFERENCE_DIVISOR)
        ref_steps = math.ceil(SIM_TIME / ref_dt)
        reference = _tip_at(case, "rk4", SIM_TIME / ref_steps, ref_steps)
        for name in integrators:
            for f in fractions:
                steps = math.ceil(SIM_TIME / (f * critical_dt(material, case.spacing, name, barrier=False)))
                dt = SIM_TIME / steps
                tip64 = _tip_at(case, name, dt, steps)
                tip32 = _tip_at(case, name, dt, steps, "fragment", ctx)
                pending.append(dict(case=case, across=n, integrator=name, fraction=f, dt=dt,
                                    steps=steps, discretisation=abs(static - fem) / fem,
                                    time_stepping=abs(tip64 - reference) / fem,
                                    float32=abs(tip32 - tip64) / fem, times=[]))
    # cost: alternating rounds over every configuration, one batch each, median per configuration
    sims = [make_simulation(p["case"].system, p["integrator"], "fragment", dt=p["dt"], ctx=ctx)
            for p in pending]
    try:
        for s in sims:  # warm-up (shader compilation, first upload)
            s.step(2)
        ctx.finish()
        for _ in range(rounds):
            for p, s in zip(pending, sims):
                start = time.perf_counter()
                s.step(batch)
                ctx.finish()
                p["times"].append((time.perf_counter() - start) / batch * 1e3)
    finally:
        for s in sims:
            s.release()
    rows = []
    for p in pending:
        ms = statistics.median(p["times"])
        case = p["case"]
        rows.append(ResolutionRow(p["across"], case.spacing, case.grid.count, p["integrator"],
                                  p["fraction"], p["dt"], p["steps"], p["discretisation"],
                                  p["time_stepping"], p["float32"],
                                  p["discretisation"] + p["time_stepping"] + p["float32"],
                                  ms, ms / p["dt"]))
    date = datetime.now(timezone.utc).isoformat(timespec="seconds")
    try:
        machine = machine_line(ctx)
    except Exception:  # pragma: no cover - a context without the info queries
        machine = cpu_line()
    return ResolutionReport(rows, fem, source, machine, date)
