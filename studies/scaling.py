"""``python -m studies.scaling``: time per step from about 4k to 1M nodes, and its power-law fit.

Every backend steps full blocks (structural + shear springs, top layer fixed: the same
18-neighbour workload). ms/step: median over rounds, each timing k ~ ``node_steps / nodes``
steps (ending in ``ctx.finish()``) of every (size, backend), so load from other processes hits
all sizes alike. Setup and the CPU model build are timed apart. Bytes per node: the textures
and buffers a backend allocates / nodes. The fit is least squares of ln(ms) on ln(nodes),
``ms = a * nodes^b``; on small grids fixed per-pass costs pull b below 1 and a working set in
the CPU caches pushes it above 1, so the fit over sizes >= :data:`UPPER_NODES` is given too.
"""

from __future__ import annotations

import math
import os
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import moderngl
import numpy as np

from deformgl.bench.sim_speed import block_system, fragment_verlet, machine_line
from deformgl.errors import GLError
from deformgl.bench.report_files import write_csv, write_json

__all__ = ["BACKENDS", "DEFAULT_SIZES", "QUICK_SIZES", "UPPER_NODES", "PowerFit", "ScalingReport", "ScalingRow",
           "bench_scaling", "fit_power_law", "gl_bytes"]

#: Cube edges of the default study: 4096, 19683, 64000, 262144 and 1000000 nodes.
DEFAULT_SIZES: tuple[int, ...] = (16, 27, 40, 64, 100)
#: ``python -m studies.scaling --quick``: 4096 to 262144 nodes (about 1 GB instead of 4.7 GB held).
QUICK_SIZES: tuple[int, ...] = (16, 27, 40, 64)
BACKENDS = ("foundation", "fragment", "feedback")
#: The upper fit uses sizes with at least this many nodes.
UPPER_NODES = 64_000
#: Errors that mean "this backend cannot run this size here" (recorded as a skip).
_SKIP_ERRORS = (GLError, moderngl.Error, MemoryError)


@dataclass(frozen=True)
class PowerFit:
    """``ms = prefactor * nodes ** exponent``, least squares in log-log.

    Attributes:
        exponent: b (1.0: time proportional to nodes).
        prefactor: a in ms.
        points: number of sizes fitted.
        rms_log: root-mean-square residual of ln(ms) (0.1: about 10 % scatter).
    """

    exponent: float
    prefactor: float
    points: int
    rms_log: float


def fit_power_law(nodes: Sequence[float], ms: Sequence[float]) -> PowerFit:
    """Least-squares fit of ln(ms) = ln(a) + b ln(nodes).

    Raises:
        ValueError: fewer than two distinct node counts, or a value that is not positive.
    """
    x, y = np.asarray(nodes, float), np.asarray(ms, float)
    if x.shape != y.shape or len(np.unique(x)) < 2:
        raise ValueError("fit_power_law: needs at least two distinct node counts")
    if not (np.all(x > 0) and np.all(y > 0) and np.all(np.isfinite(y))):
        raise ValueError("fit_power_law: nodes and ms must be positive and finite")
    lx, ly = np.log(x), np.log(y)
    b, ln_a = np.polyfit(lx, ly, 1)
    rms = float(np.sqrt(np.mean((ly - (ln_a + b * lx)) ** 2)))
    return PowerFit(float(b), float(np.exp(ln_a)), len(x), rms)


def gl_bytes(obj: object) -> int:
    """GPU bytes a moderngl buffer, texture or texture array holds (0 for anything else)."""
    if isinstance(obj, moderngl.Buffer):
        return int(obj.size)
    if isinstance(obj, (moderngl.Texture, moderngl.TextureArray)):
        layers = getattr(obj, "layers", 1)
        return int(obj.width * obj.height * layers * obj.components * np.dtype(obj.dtype).itemsize)
    return 0


@dataclass
class ScalingRow:
    """One (size, backend) of the study; ``skipped`` holds the reason when it did not run."""

    backend: str
    shape: tuple[int, int, int]
    nodes: int
    steps: int = 0  # per timing
    ms_per_step: float | None = None  # median of the timings
    ms_min: float | None = None
    bytes_per_node: float | None = None
    setup_s: float | None = None
    skipped: str | None = None

    @property
    def ns_per_node_step(self) -> float | None:
        """Nanoseconds per node and step."""
        return None if self.ms_per_step is None else self.ms_per_step * 1e6 / self.nodes


@dataclass
class ScalingReport:
    """Result of :func:`bench_scaling`."""

    rows: list[ScalingRow]
    machine: str
    integrator: str
    repeats: int
    model_s: dict[int, float] = field(default_factory=dict)  # CPU model build per node count
    wall_s: float = 0.0
    #: llvmpipe's rasteriser threads (the environment when the report was made)
    lp_threads: str = field(default_factory=lambda: os.environ.get("LP_NUM_THREADS",
                                                                   "unset (one per core)"))

    def backends(self) -> list[str]:
        """Backends in study order."""
        return list(dict.fromkeys(r.backend for r in self.rows))

    def fits(self, min_nodes: int = 0, *, fastest: bool = False) -> dict[str, PowerFit | None]:
        """Power-law fit per backend over the timed sizes with >= ``min_nodes`` (None: < 2) of
        the median ms/step, or with ``fastest`` of the fastest round's."""
        out: dict[str, PowerFit | None] = {}
        for b in self.backends():
            pts = [(r.nodes, ms) for r in self.rows if r.backend == b and r.nodes >= min_nodes
                   and (ms := r.ms_min if fastest else r.ms_per_step) is not None]
            ok = len({n for n, _ in pts}) >= 2
            out[b] = fit_power_law(*zip(*pts)) if ok else None
        return out

    def to_records(self) -> list[dict[str, object]]:
        """One flat dict per (size, backend), for CSV or JSON (None where skipped)."""
        return [{**asdict(r), "shape": "x".join(map(str, r.shape)), "integrator": self.integrator,
                 "ns_per_node_step": r.ns_per_node_step, "model_s": self.model_s.get(r.nodes),
                 "repeats": self.repeats} for r in self.rows]

    def write_json(self, path: str | os.PathLike[str]) -> None:
        """``{"machine", "integrator", "rows", "fits"}`` as JSON, atomically."""
        write_json(path, {"machine": self.machine, "integrator": self.integrator, "lp_threads": self.lp_threads,
                          "rows": self.to_records(), "fits": self.fit_records()})

    def write_csv(self, path: str | os.PathLike[str]) -> None:
        """One line per (size, backend), atomically."""
        write_csv(path, self.to_records())

    def write_chart(self, path: str | os.PathLike[str]) -> None:
        """PNG: ms per step against nodes, log-log, one line per backend, with the power law
        fitted on sizes >= :data:`UPPER_NODES` (its exponent in the legend).

        Raises:
            DeformglError: matplotlib is not installed (``pip install 'deformgl[plot]'``).
        """
        from deformgl.bench.charts import new_figure, save_png

        fig, axes = new_figure(1, 1, width=6.0, height=4.4, what="scaling")
        ax = axes[0][0]
        fits = self.fits(UPPER_NODES)
        for backend in self.backends():
            pts = sorted((r.nodes, r.ms_per_step) for r in self.rows
                         if r.backend == backend and r.ms_per_step is not None)
            if not pts:
                continue
            fit = fits.get(backend)
            label = backend + (f" (b = {fit.exponent:.2f} from {UPPER_NODES // 1000}k nodes)" if fit else "")
            line, = ax.plot(*zip(*pts), marker="o", lw=1, label=label)
            if fit:
                xs = np.array([UPPER_NODES, pts[-1][0]], float)
                ax.plot(xs, fit.prefactor * xs ** fit.exponent, ls="--", lw=0.8, color=line.get_color())
        ax.set(xscale="log", yscale="log", xlabel="nodes", ylabel="ms per step",
               title=f"{self.integrator} step, full blocks; median of {self.repeats} rounds")
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=7)
        fig.suptitle(self.machine, fontsize=8)
        fig.tight_layout()
        save_png(fig, path)

    def fit_records(self) -> list[dict[str, object]]:
        """One dict per fit: backend, ``range`` "all" or "upper", ``of`` "median" or "fastest"
        (exponent None: fewer than 2 sizes)."""
        empty = {"exponent": None, "prefactor": None, "points": 0, "rms_log": None}
        return [{"backend": b, "range": name, "min_nodes": lo, "of": of, **(asdict(f) if f else empty)}
                for of in ("median", "fastest") for name, lo in (("all", 0), ("upper", UPPER_NODES))
                for b, f in self.fits(lo, fastest=of == "fastest").items()]

    def format(self) -> str:
        """The table (ms/step, ns/node-step, bytes/node, setup per backend) and the fits."""
        names = self.backends()
        sizes = list(dict.fromkeys((r.shape, r.nodes) for r in self.rows))
        cell = {(r.nodes, r.backend): r for r in self.rows}
        lines = [self.machine, f"{self.integrator}, structural + shear springs (18 neighbours), full "
                 f"blocks; ms/step: median of {self.repeats} rounds, each timing every size and backend "
                 "once, after a warm-up round; setup (upload, compile) and the CPU model build are not in "
                 "ms/step"]
        time_head = f"{'grid':>9} {'nodes':>8} | " + " | ".join(f"{b + ' ms/step':>20} {'ns/node-step':>12}"
                                                                for b in names)
        mem_head = f"{'nodes':>8} {'model s':>8} | " + " | ".join(f"{b + ' B/node':>17} {'setup s':>8}"
                                                                  for b in names)
        times, mems, notes = [time_head, "-" * len(time_head)], [mem_head, "-" * len(mem_head)], []
        for shape, n in sizes:
            rs = [cell.get((n, b)) for b in names]
            notes += [f"  {r.backend} at {n} nodes skipped: {r.skipped}" for r in rs if r and r.skipped]
            times.append(f"{'x'.join(map(str, shape)):>9} {n:>8} | " + " | ".join(
                f"{r.ms_per_step:>20.3f} {r.ns_per_node_step:>12.2f}" if r and r.ms_per_step is not None
                else f"{'skipped':>20} {'-':>12}" for r in rs))
            mems.append(f"{n:>8} {self.model_s.get(n, math.nan):>8.2f} | " + " | ".join(
                f"{r.bytes_per_node:>17.1f} {r.setup_s:>8.2f}" if r and r.setup_s is not None
                else f"{'-':>17} {'-':>8}" for r in rs))
        lines += times + ["", "GPU memory (textures + buffers allocated / nodes), setup and CPU model "
                          "build time"] + mems
        lines += notes + ["", "fit ms/step = a * nodes^b, least squares of ln(ms) on ln(nodes); small "
                          "grids are dominated by fixed per-pass costs and fit in CPU caches, so the "
                          f"upper fit (sizes >= {UPPER_NODES} nodes) is the one to compare with b = 1.0"]
        fits = {"all sizes": self.fits(), f">= {UPPER_NODES}": self.fits(UPPER_NODES),
                f">= {UPPER_NODES}, fastest rounds": self.fits(UPPER_NODES, fastest=True)}
        for b in names:
            lines.append(f"  {b:>10}: " + "; ".join(f"{k}: {_fit_text(f[b])}" for k, f in fits.items()))
        if "llvmpipe" in self.machine:
            lines.append(f"LP_NUM_THREADS={self.lp_threads}: the fragment passes rasterise on that many "
                         "threads, so load from other processes changes their speed (their fastest "
                         "round vs median shows how much); transform feedback runs on one thread")
        lines.append(f"study wall time {self.wall_s:.1f} s")
        return "\n".join(lines)


def _fit_text(f: PowerFit | None) -> str:
    """``exponent b = ... (a = ..., sizes, residual)`` of a fit."""
    if f is None:
        return "exponent - (fewer than 2 sizes)"
    return (f"exponent b = {f.exponent:.3f} (a = {f.prefactor:.3g} ms, {f.points} sizes, "
            f"rms ln {f.rms_log:.3f})")


def _make(ctx: moderngl.Context, backend: str, system, integrator: str, dt: float):
    """Construct a backend's simulation; returns (sim, GPU bytes it allocated)."""
    from deformgl.sim.backends.blocked import BlockedTextures
    from deformgl.sim.backends.feedback import FeedbackSimulation
    from deformgl.sim.backends.explicit_gpu import FragmentIntegrator

    if backend == "foundation":  # the fragment backend's Verlet fast path, counted from its GL objects
        base = fragment_verlet(ctx, system, dt)
        fast = base.foundation
        t = fast.textures
        if isinstance(t, BlockedTextures):  # (several nodes per fragment: the default from 2,000 nodes)
            objects = [t.node, t.neighbours, t.weights, *(x for s in t.state for x in s), t.view_texture, t.place]
        else:
            objects = [t.node, t.neighbours, t.weights, *t.state, getattr(fast.verlet, "vbo", None)]
        return base, sum(gl_bytes(o) for o in objects)
    sim: FragmentIntegrator | FeedbackSimulation = (
        FragmentIntegrator(ctx, system, system.grid, integrator, dt, path="general") if backend == "fragment"
        else FeedbackSimulation(ctx, system, integrator, dt))
    return sim, sim.bytes_per_node * system.count


def bench_scaling(ctx: moderngl.Context, *, sizes: Sequence[int | tuple[int, int, int]] = DEFAULT_SIZES,
                  backends: Sequence[str] = BACKENDS, integrator: str = "verlet",
                  node_steps: float = 6e6, max_steps: int = 50, repeats: int = 9,
                  progress: Callable[[str], None] | None = None) -> ScalingReport:
    """Time per step of each backend on full blocks from small to large.

    Args:
        ctx: GL context.
        sizes: cube edges (``64`` is 64^3 nodes) or block shapes ``(nx, ny, nz)``.
        backends: any of :data:`BACKENDS`; "foundation" is the fragment-pass position Verlet.
        integrator: integrator of the "fragment" and "feedback" backends.
        node_steps, max_steps: steps per timing: ``node_steps / nodes``, in 2..max_steps.
        repeats: timing rounds; each times every (size, backend) once, the median is reported.
            All simulations stay allocated until the end (the sum of their memory is needed).
        progress: called with a short label before each setup and each timing round.

    Returns:
        The report; a (size, backend) that cannot run here (texture limit, out of memory, an
        integrator the backend lacks) is a row with ``skipped`` set to the reason.

    Raises:
        ValueError: an unknown backend or integrator, or repeats < 1.
    """
    from deformgl.sim.integrators import EXPLICIT_INTEGRATORS
    from deformgl.sim.springs import max_angular_frequency

    if unknown := [b for b in backends if b not in BACKENDS]:
        raise ValueError(f"unknown backend(s) {unknown}; expected some of {', '.join(BACKENDS)}")
    if integrator not in EXPLICIT_INTEGRATORS:
        raise ValueError(f"unknown integrator {integrator!r}; expected one of {', '.join(EXPLICIT_INTEGRATORS)}")
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    start = time.perf_counter()
    report = ScalingReport([], machine_line(ctx), integrator, repeats)
    live: list[tuple[ScalingRow, Any, list[float]]] = []  # row, simulation, ms/step samples
    try:
        for size in sizes:
            shape = (size, size, size) if isinstance(size, (int, np.integer)) else tuple(size)
            t0 = time.perf_counter()
            system = block_system(shape)  # type: ignore[arg-type]
            n = system.count
            report.model_s[n] = time.perf_counter() - t0
            dt = 0.5 / max_angular_frequency(system).omega
            steps = int(min(max_steps, max(2, node_steps // n)))
            for backend in backends:
                if progress is not None:
                    progress(f"setup {backend} {'x'.join(map(str, shape))} ({n} nodes)")
                row = ScalingRow(backend, shape, n, steps)  # type: ignore[arg-type]
                report.rows.append(row)
                if backend == "foundation" and integrator != "verlet":
                    row.skipped = f"the foundation backend is position Verlet only, not {integrator}"
                    continue
                t1 = time.perf_counter()
                try:
                    sim, allocated = _make(ctx, backend, system, integrator, dt)
                    ctx.finish()
                except _SKIP_ERRORS as exc:
                    row.skipped = f"{type(exc).__name__}: {exc}"
                    continue
                row.setup_s, row.bytes_per_node = time.perf_counter() - t1, allocated / n
                live.append((row, sim, []))
            del system
        # Round-robin over every (size, backend), alternating direction: load from other processes
        # (llvmpipe's speed changes up to 2x on a shared machine) then hits all sizes alike and
        # cancels in the exponent. Round 0 is the warm-up (shaders compile on the first draw).
        for rnd in range(repeats + 1):
            if progress is not None:
                progress(f"timing round {rnd}/{repeats}" + (" (warm-up)" if rnd == 0 else ""))
            for entry in list(live if rnd % 2 else reversed(live)):
                row, sim, ms = entry
                t1 = time.perf_counter()
                try:
                    sim.step(row.steps)
                    ctx.finish()
                except _SKIP_ERRORS as exc:
                    row.skipped = f"{type(exc).__name__}: {exc}"
                    live = [e for e in live if e is not entry]
                    sim.release()
                    continue
                if rnd:
                    ms.append((time.perf_counter() - t1) / row.steps * 1e3)
        for row, _, ms in live:
            row.ms_per_step, row.ms_min = statistics.median(ms), min(ms)
    finally:
        for _, sim, _ in live:
            sim.release()
    report.wall_s = time.perf_counter() - start
    return report


def main(argv: list[str] | None = None) -> int:
    """``python -m studies.scaling [--quick] [--out DIR]``: the table, and with ``--out``
    DIR/scaling.csv, .json and .png."""
    from deformgl.files import OutputSet
    from studies.common import chart, gl_context, parse, parser, progress

    args = parse(parser("scaling", "ms/step from 4k to 1M nodes, the fitted exponent, bytes/node"), argv)
    out = args.out
    outputs = OutputSet([out / f"scaling.{ext}" for ext in ("csv", "json", "png")] if out else [])
    with gl_context(args) as ctx:
        scaling = bench_scaling(ctx, progress=progress(args), **({"sizes": QUICK_SIZES} if args.quick else {}))
    print(scaling.format())
    if out is not None:
        with outputs:
            scaling.write_csv(out / "scaling.csv")
            scaling.write_json(out / "scaling.json")
            chart(lambda: scaling.write_chart(out / "scaling.png"))
    return 0


if __name__ == "__main__":
    from studies.common import run_main

    run_main(main)
