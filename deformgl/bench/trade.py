"""``deformgl bench trade``: speed against accuracy of the five integrators (Movania & Feng 2012,
section 3; :mod:`deformgl.sim.integrators`) on each backend.

Workloads (:func:`standard_workloads`): a damped 6x6x6 block whose top corner a
:class:`~deformgl.sim.scripted.Drag` pulls along a smooth path, and a 16x16 cloth falling onto a
fixed sphere; at most 300 free nodes, so :func:`~deformgl.sim.limits.dt_limit` uses the exact
spectrum. dt = f x limit for f in :data:`FRACTIONS`, rounded so that T/dt is an integer; a run
that goes non-finite or :data:`DIVERGED_SPACINGS` spacings off is "diverged". Error: node
positions at T = :data:`SIM_TIME` against a float64 RK4 reference at a tiny step (the halved run's
difference is its error estimate), RMS and max over the free nodes, in grid spacings; the
sphere contact makes the cloth first order for every integrator, hence its finer reference.
Cost: the median wall time of a separate batch of steps (``ctx.finish()`` included), as ms/step
and ms per simulated second; the Pareto front (:func:`pareto_front`) is per workload and
backend. The grid resolution is the other knob: ``--resolution`` (:mod:`deformgl.bench.resolution`)."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import textwrap
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any, TypeVar

import moderngl
import numpy as np

from deformgl.bench.sim_speed import machine_line, timed
from deformgl.grid.nodes import NodeGrid
from deformgl.bench import report_files
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS, Constraints, Sphere, initial_state, simulate
from deformgl.sim.springs import SpringSystem, cloth, from_grid
from deformgl.sim.scripted import Drag
from deformgl.sim.limits import dt_limit

__all__ = ["BACKENDS", "FRACTIONS", "QUICK_FRACTIONS", "SIM_TIME", "DIVERGED_SPACINGS",
           "Workload", "Reference", "TradeRow", "TradeReport", "standard_workloads",
           "pareto_front", "read_csv", "trade_study"]

BACKENDS = ("fragment", "feedback", "numpy")
FRACTIONS = (0.1, 0.2, 0.35, 0.5, 0.7, 0.9)
QUICK_FRACTIONS = (0.15, 0.6)
SIM_TIME = 0.5
DIVERGED_SPACINGS = 10.0
#: runs of more steps than this are skipped (recorded as "too many steps")
MAX_STEPS = 20_000
_MARKERS = {"euler": "v", "semi-implicit": "s", "midpoint": "^", "rk4": "D", "verlet": "o"}
P = TypeVar("P")


@dataclass(frozen=True, eq=False)
class Workload:
    """A standard scene: system, its grid, obstacles and drags, simulated for ``time`` s; the
    reference step is the RK4 limit / ``reference_divisor`` (then halved)."""

    name: str
    system: SpringSystem
    grid: NodeGrid
    constraints: Constraints | None = None
    drags: tuple[Drag, ...] = ()
    time: float = SIM_TIME
    reference_divisor: float = 50.0


def _ramp(start: np.ndarray, move: np.ndarray, duration: float) -> Callable[[float], np.ndarray]:
    """t -> start + move (1 - cos(pi t/duration))/2, held after ``duration`` (smooth on [0, T])."""
    return lambda t: start + move * 0.5 * (1.0 - math.cos(math.pi * min(t, duration) / duration))


def standard_workloads(sim_time: float = SIM_TIME) -> tuple[Workload, ...]:
    """The volume under a drag and the cloth on a sphere (see the module docstring); spring
    damping c_s = k_s / w_top gives the top mode (w_top 121 and 154 rad/s) damping ratio 0.5."""
    h, n, c, m = 0.1, 6, 0.06, 16
    grid = NodeGrid(np.array([-(n - 1) * h / 2, 0.0, -(n - 1) * h / 2]), h, np.ones((n,) * 3, bool))
    k = (20.0, 10.0, 4.0)
    block = from_grid(grid, k_structural=k[0], k_shear=k[1], k_flexion=k[2],
                      damping_structural=k[0] / 121, damping_shear=k[1] / 121,
                      damping_flexion=k[2] / 121, mass=0.01, fixed=grid.ijk[:, 1] == 0,
                      velocity_damping=0.002)
    top = int(grid.index[n - 1, n - 1, n - 1])
    drag = Drag(top, _ramp(grid.rest_positions[top], np.array([3 * h, h, 0.0]), sim_time), 20.0)
    origin = np.array([-(m - 1) * c / 2, 0.32, -(m - 1) * c / 2])
    k = (40.0, 20.0, 4.0)
    sheet = cloth(m, m, c, k_structural=k[0], k_shear=k[1], k_flexion=k[2],
                  damping_structural=k[0] / 154, damping_shear=k[1] / 154,
                  damping_flexion=k[2] / 154, origin=origin, mass=0.01, velocity_damping=0.01)
    return (Workload("volume under a drag", block, grid, drags=(drag,), time=sim_time),
            Workload("cloth on a sphere", sheet, NodeGrid(origin, c, np.ones((m, 1, m), bool)),
                     Constraints(spheres=(Sphere((0.0, 0.0, 0.0), 0.3),)), time=sim_time,
                     reference_divisor=512.0))


@dataclass(frozen=True)
class Reference:
    """The float64 RK4 reference of one workload (error in grid spacings: the largest node
    difference between the run at ``2 dt`` and the reference run at ``dt``)."""

    workload: str
    nodes: int
    spacing: float
    dt: float
    steps: int
    error: float


@dataclass
class TradeRow:
    """One (workload, backend, integrator, dt) run; errors in grid spacings, dt in s.

    ``status`` is "ok", "diverged", "no stable dt" or "too many steps" (over :data:`MAX_STEPS`); ``vs_numpy`` is the largest node distance
    to the numpy backend's result for the same integrator and dt (float32 drift; nan for numpy).
    """

    workload: str
    backend: str
    integrator: str
    fraction: float
    dt: float
    steps: int
    limit: float
    rms: float
    max: float
    ms_per_step: float
    ms_per_sim_s: float
    vs_numpy: float
    status: str = "ok"

    @property
    def cost(self) -> float:
        """ms per simulated second."""
        return self.ms_per_sim_s

    @property
    def error(self) -> float:
        """RMS error in grid spacings."""
        return self.rms


def _first_two(p: Any) -> tuple[float, float]:
    """The default key of :func:`pareto_front`: a point's first two items."""
    return (p[0], p[1])


def pareto_front(points: Iterable[P],
                 key: Callable[[P], tuple[float, float]] = _first_two) -> list[P]:
    """The non-dominated points, cheapest first (so error falls along the list).

    A point is dominated when another is no worse in cost and error and better in one. Points
    with a non-finite cost or error are dropped; of identical points the first is kept.

    Args:
        points: anything; ``key(p)`` gives its (cost, error), default ``(p[0], p[1])``.
        key: the (cost, error) of a point.
    """
    keyed = [(key(p), i, p) for i, p in enumerate(points)]
    front, best = [], math.inf
    for (_, error), _, p in sorted((it for it in keyed if all(map(math.isfinite, it[0]))),
                                   key=lambda it: it[:2]):
        if error < best:
            front.append(p)
            best = error
    return front


_FIELDS = [f.name for f in dataclasses.fields(TradeRow)]


def _row(d: dict[str, Any]) -> TradeRow:
    # The field types are strings (``from __future__ import annotations``): "int", "float", ...
    types = {f.name: str(f.type) for f in dataclasses.fields(TradeRow)}
    conv: dict[str, Callable[[Any], Any]] = {"int": int, "float": float, "str": str}
    values: dict[str, Any] = {k: (math.nan if d[k] in (None, "") else conv[types[k]](d[k]))
                              for k in _FIELDS}
    return TradeRow(**values)


def read_csv(path: str | os.PathLike) -> list[TradeRow]:
    """Rows of a CSV written by :meth:`TradeReport.write_csv`."""
    with open(path, encoding="utf-8", newline="") as f:
        return [_row(d) for d in csv.DictReader(f)]


def _e(x: float) -> str:
    return f"{x:.1e}" if math.isfinite(x) else "-"


@dataclass
class TradeReport:
    """Everything a trade study measured (see the module docstring)."""

    rows: list[TradeRow]
    machine: str
    date: str
    sim_time: float
    references: list[Reference] = field(default_factory=list)

    def groups(self) -> list[tuple[str, str]]:
        """(workload, backend) pairs in report order."""
        return list(dict.fromkeys((r.workload, r.backend) for r in self.rows))

    def front(self, workload: str, backend: str) -> list[TradeRow]:
        """Pareto front of the converged runs (RMS error vs ms per simulated second)."""
        return pareto_front((r for r in self.rows if r.workload == workload
                             and r.backend == backend and r.status == "ok"),
                            key=lambda r: (r.cost, r.error))

    def front_words(self, workload: str, backend: str) -> str:
        """The front as advice, e.g. ``for errors above 1.0e-02 spacings use verlet at ...``."""
        front = self.front(workload, backend)
        if not front:
            return f"{workload}, {backend} backend: no run converged"
        runs: list[list[TradeRow]] = []
        for r in front:  # consecutive points of one integrator form one piece of advice
            if runs and runs[-1][-1].integrator == r.integrator:
                runs[-1].append(r)
            else:
                runs.append([r])
        parts, above = [], math.inf
        for run in runs:
            lo, a, b = run[-1].error, run[0], run[-1]
            when = (f"for errors above {_e(lo)} spacings" if above == math.inf else
                    f"for errors between {_e(lo)} and {_e(above)}")
            span = (f"dt = {a.dt:.2e} s = {a.fraction:.2g} x limit, {a.cost:.3g}" if a is b else
                    f"dt = {a.dt:.2e} to {b.dt:.2e} s = {a.fraction:.2g} to {b.fraction:.2g} x "
                    f"limit, {a.cost:.3g} to {b.cost:.3g}")
            parts.append(f"{when} use {a.integrator} at {span} ms per simulated second")
            above = lo
        ref = next((r.error for r in self.references if r.workload == workload), math.nan)
        return (f"{workload}, {backend} backend: " + "; ".join(parts) +
                f"; nothing measured is more accurate than {_e(above)} spacings "
                f"(reference error estimate {_e(ref)})")

    def format(self) -> str:
        """The terminal table, grouped by workload and backend, then the front in words."""
        lines = [self.machine, f"date: {self.date}; simulated time T = {self.sim_time:g} s; "
                 "error: node-position error at T against the float64 RK4 reference, in grid "
                 "spacings (RMS and max over free nodes); cost: median ms/step of a batch "
                 "(ctx.finish() included) and ms per simulated second = (ms/step)/dt; vs numpy: "
                 "largest distance to the numpy backend's result (float32 drift)"]
        head = (f"    {'integrator':>13} {'dt/limit':>8} {'dt [s]':>9} {'steps':>6} | "
                f"{'rms err':>8} {'max err':>8} | {'ms/step':>8} {'ms/sim-s':>9} | "
                f"{'vs numpy':>8} | status")
        previous = None
        for workload, backend in self.groups():
            ref = next((r for r in self.references if r.workload == workload), None)
            if workload != previous and ref is not None:
                lines.append(f"{workload}: {ref.nodes} nodes, spacing {ref.spacing:g} m; "
                             f"reference rk4 dt = {ref.dt:.3g} s ({ref.steps} steps), estimated "
                             f"error {_e(ref.error)} spacings")
            previous = workload
            lines += [f"  {backend} backend", head, "    " + "-" * (len(head) - 4)]
            for r in self.rows:
                if (r.workload, r.backend) != (workload, backend):
                    continue
                if r.status == "no stable dt":
                    lines.append(f"    {r.integrator:>13} no stable dt (limit 0): skipped")
                    continue
                if r.status == "too many steps":
                    lines.append(f"    {r.integrator:>13} {r.fraction:>8.3f} {r.dt:>9.3e} {r.steps:>6}: more than "
                                 f"{MAX_STEPS} steps, skipped")
                    continue
                lines.append(f"    {r.integrator:>13} {r.fraction:>8.3f} {r.dt:>9.3e} "
                             f"{r.steps:>6} | {_e(r.rms):>8} {_e(r.max):>8} | "
                             f"{r.ms_per_step:>8.3f} {r.ms_per_sim_s:>9.1f} | "
                             f"{_e(r.vs_numpy):>8} | {r.status}")
        lines.append("Pareto front (RMS error against ms per simulated second):")
        lines += [textwrap.fill(self.front_words(w, b), 100, initial_indent="  ",
                                subsequent_indent="    ") for w, b in self.groups()]
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (nan as null)."""
        def clean(obj: Any) -> dict[str, Any]:
            return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                    for k, v in dataclasses.asdict(obj).items()}
        return {"machine": self.machine, "date": self.date, "sim_time": self.sim_time,
                "references": list(map(clean, self.references)),
                "rows": list(map(clean, self.rows))}

    @classmethod
    def read_json(cls, path: str | os.PathLike) -> TradeReport:
        """A report written by :meth:`write_json`."""
        with open(path, encoding="utf-8") as f:
            d = json.load(f)
        def reference(r: dict[str, Any]) -> Reference:
            values: dict[str, Any] = {k: (math.nan if v is None else v) for k, v in r.items()}
            return Reference(**values)
        refs = [reference(r) for r in d["references"]]
        return cls([_row(r) for r in d["rows"]], d["machine"], d["date"], d["sim_time"], refs)

    def write_csv(self, path: str | os.PathLike) -> None:
        """One line per row (floats in full precision), atomically."""
        report_files.write_csv(path, [dataclasses.asdict(r) for r in self.rows], _FIELDS)

    def write_json(self, path: str | os.PathLike) -> None:
        """:meth:`to_dict` as JSON, atomically."""
        report_files.write_json(path, self.to_dict())

    def write_chart(self, path: str | os.PathLike) -> None:
        """PNG: log-log RMS error against ms per simulated second, one subplot per workload and
        backend, one line per integrator (a marker per dt), the Pareto front as a dashed step
        line through circled points.

        Raises:
            DeformglError: matplotlib is not installed (``pip install 'deformgl[plot]'``).
        """
        from deformgl.bench.charts import new_figure, save_png

        workloads = list(dict.fromkeys(w for w, _ in self.groups()))
        backends = list(dict.fromkeys(b for _, b in self.groups()))
        fig, axes = new_figure(len(workloads), len(backends), width=5.0, height=4.2, what="trade")
        from matplotlib.ticker import NullFormatter
        for (i, workload), (j, backend) in ((a, b) for a in enumerate(workloads)
                                            for b in enumerate(backends)):
            ax = axes[i][j]
            rows = [r for r in self.rows if (r.workload, r.backend) == (workload, backend)]
            for name in EXPLICIT_INTEGRATORS:
                pts = sorted((r.cost, r.error) for r in rows
                             if r.integrator == name and r.status == "ok")
                if pts:
                    ax.plot(*zip(*pts), marker=_MARKERS.get(name, "o"), ms=4, lw=1, label=name)
            front = self.front(workload, backend)
            if front:
                xs, ys = [r.cost for r in front], [r.error for r in front]
                ax.plot(xs, ys, drawstyle="steps-post", color="k", ls="--", lw=0.8)
                ax.scatter(xs, ys, s=90, facecolors="none", edgecolors="k", label="Pareto front")
            bad = [f"{r.integrator} {r.fraction:.2g}" for r in rows if r.status == "diverged"]
            if bad:
                ax.text(0.02, 0.02, "diverged: " + ", ".join(bad), transform=ax.transAxes,
                        fontsize=6, va="bottom")
            ax.set(xscale="log", yscale="log", xlabel="ms per simulated second",
                   ylabel="RMS error [grid spacings]", title=f"{workload}, {backend} backend")
            ax.xaxis.set_minor_formatter(NullFormatter())  # (overlapping 2x10^1 3x10^1 ...)
            ax.grid(True, which="both", lw=0.3, alpha=0.5)
            ax.legend(fontsize=6)
        fig.suptitle(textwrap.fill(f"{self.machine} ({self.date}); error at T = "
                                   f"{self.sim_time:g} s vs float64 RK4 reference", 150),
                     fontsize=8)
        fig.tight_layout()
        save_png(fig, path)


def _errors(w: Workload, x: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    with np.errstate(all="ignore"):
        e = np.linalg.norm(np.asarray(x, np.float64) - ref, axis=1)[~w.system.fixed]
        e = e / w.system.spacing
    if not np.all(np.isfinite(e)):
        return math.inf, math.inf
    return float(np.sqrt(np.mean(e * e))), float(e.max())


def _reference(w: Workload, rk4_limit: float, divisor: float) -> tuple[np.ndarray, Reference]:
    steps = math.ceil(w.time * divisor / rk4_limit)
    coarse = simulate(w.system, "rk4", w.time / steps, steps, constraints=w.constraints,
                      drags=w.drags).x
    fine = simulate(w.system, "rk4", w.time / (2 * steps), 2 * steps,
                    constraints=w.constraints, drags=w.drags).x
    error = float(np.linalg.norm(coarse - fine, axis=1).max() / w.system.spacing)
    return fine, Reference(w.name, w.system.count, w.system.spacing, w.time / (2 * steps),
                           2 * steps, error)


def _run(ctx: moderngl.Context, w: Workload, backend: str, name: str, dt: float, steps: int,
         batch: int, repeats: int) -> tuple[np.ndarray, float]:
    """Final positions after ``steps`` steps and the median ms/step of ``batch`` more."""
    state = initial_state(w.system, dt, drags=w.drags)
    cons, drags = w.constraints, w.drags
    if backend == "numpy":
        with np.errstate(all="ignore"):
            holder = [simulate(w.system, name, dt, steps, state=state, constraints=cons,
                               drags=drags)]
            x = holder[0].x.copy()

            def more() -> None:
                holder[0] = simulate(w.system, name, dt, batch, state=holder[0],
                                     constraints=cons, drags=drags)
            return x, timed(more, repeats) / batch * 1e3
    if backend == "fragment":
        from deformgl.sim.backends.explicit_gpu import FragmentIntegrator
        sim: Any = FragmentIntegrator(ctx, w.system, w.grid, name, dt, state=state,
                                      constraints=cons, drags=drags)
    else:
        from deformgl.sim.backends.feedback import FeedbackSimulation
        sim = FeedbackSimulation(ctx, w.system, name, dt, state=state, constraints=cons,
                                 drags=drags)
    try:
        sim.step(steps)
        x = sim.positions().astype(np.float64)

        def more_gl() -> None:
            sim.step(batch)
            ctx.finish()
        return x, timed(more_gl, repeats) / batch * 1e3
    finally:
        sim.release()


def trade_study(ctx: moderngl.Context, *, backends: Sequence[str] = BACKENDS,
                fractions: Sequence[float] | None = None, quick: bool = False,
                workloads: Sequence[Workload] | None = None,
                progress: Callable[[str], None] | None = None) -> TradeReport:
    """Every integrator x dt x backend on the standard workloads (see the module docstring).

    Args:
        ctx: the GL context (unused by the numpy backend).
        backends: of :data:`BACKENDS`.
        fractions: dt as fractions of each integrator's limit (default :data:`FRACTIONS`, or
            :data:`QUICK_FRACTIONS` when ``quick``).
        quick: fewer dts, a coarser reference (RK4 limit / 32 at most) and shorter timings
            (one batch of 10 steps instead of the median of 5 batches of 50).
        workloads: default :func:`standard_workloads`.
        progress: called with a line before each workload and backend.

    Raises:
        ValueError: an unknown backend.
    """
    unknown = set(backends) - set(BACKENDS)
    if unknown:
        raise ValueError(f"unknown backend(s) {sorted(unknown)}; expected {', '.join(BACKENDS)}")
    fractions = tuple(fractions or (QUICK_FRACTIONS if quick else FRACTIONS))
    batch, repeats = (10, 1) if quick else (50, 5)
    order = sorted(backends, key=lambda b: b != "numpy")  # numpy first: the vs-numpy column
    rows: list[TradeRow] = []
    refs: list[Reference] = []
    wl = tuple(workloads or standard_workloads())
    for w in wl:
        limits = {name: dt_limit(w.system, name).dt for name in EXPLICIT_INTEGRATORS}
        if progress:
            progress(f"{w.name}: reference")
        divisor = min(w.reference_divisor, 32.0) if quick else w.reference_divisor
        ref_x, ref = _reference(w, limits["rk4"], divisor)
        refs.append(ref)
        numpy_x: dict[tuple[str, int], np.ndarray] = {}
        for backend in order:
            if progress:
                progress(f"{w.name}: {backend} backend")
            for name in EXPLICIT_INTEGRATORS:
                limit = limits[name]
                if limit <= 0:
                    rows.append(TradeRow(w.name, backend, name, math.nan, math.nan, 0, 0.0,
                                         math.nan, math.nan, math.nan, math.nan, math.nan,
                                         status="no stable dt"))
                    continue
                for f in sorted(set(fractions)):
                    steps = math.ceil(w.time / (f * limit))
                    dt = w.time / steps
                    if steps > MAX_STEPS:  # (forward Euler on the undamped volumetric modes of nu > 1/4)
                        rows.append(TradeRow(w.name, backend, name, dt / limit, dt, steps, limit,
                                             math.nan, math.nan, math.nan, math.nan, math.nan,
                                             status="too many steps"))
                        continue
                    x, ms = _run(ctx, w, backend, name, dt, steps, batch, repeats)
                    rms, mx = _errors(w, x, ref_x)
                    if backend == "numpy":
                        numpy_x[name, steps] = x
                    other = numpy_x.get((name, steps))
                    with np.errstate(all="ignore"):
                        vs = (math.nan if other is None or backend == "numpy" else
                              float(np.linalg.norm(x - other, axis=1).max() / w.system.spacing))
                    ok = math.isfinite(mx) and mx <= DIVERGED_SPACINGS
                    rows.append(TradeRow(w.name, backend, name, dt / limit, dt, steps, limit,
                                         rms, mx, ms, ms / dt, vs,
                                         "ok" if ok else "diverged"))
    names = [w.name for w in wl]
    rows.sort(key=lambda r: (names.index(r.workload), list(backends).index(r.backend),
                             EXPLICIT_INTEGRATORS.index(r.integrator), r.steps))
    date = datetime.now(timezone.utc).isoformat(timespec="seconds")
    return TradeReport(rows, machine_line(ctx), date, float(wl[0].time), refs)
