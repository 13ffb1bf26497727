"""``deformgl bench sim``: the fragment backend's Verlet step, in the compact and the blocked
node layout, against the float64 NumPy reference, and (``--peers``) against the same step in Taichi,
Warp and Numba; and what every timing of ``deformgl bench`` shares (the machine line, the median
timer, the benchmark bodies). Speed as ratios against a baseline measured in the same process.

Timings include a ``ctx.finish()`` so the GPU work is really done; each figure is the median
of several repeats. Every report names the machine and the renderer.
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass

import moderngl
import numpy as np

from deformgl.gl.context import context_info
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.backends.explicit_gpu import FragmentIntegrator
from deformgl.sim.simulation import NumpySimulation, Simulation
from deformgl.sim.springs import SpringSystem, from_grid, max_angular_frequency

#: The benchmark volumes: about 4k, 20k and 131k nodes in full blocks, and a ball of about 20k
#: nodes filling 52 % of its box (where drawing only around existing nodes matters).
SIM_GRIDS = ((16, 16, 16), (27, 27, 27), (64, 64, 32), "ball34")


def bench_occupancy(spec: tuple[int, int, int] | str) -> np.ndarray:
    """Occupancy of a benchmark grid: a full block of that shape, or ``"ballN"``: a ball in N^3."""
    if isinstance(spec, str):
        n = int(spec.removeprefix("ball"))
        c = (n - 1) / 2.0
        i, j, k = np.indices((n, n, n))
        return (i - c) ** 2 + (j - c) ** 2 + (k - c) ** 2 <= (n / 2.0) ** 2
    return np.ones(spec, bool)


def cpu_line() -> str:
    """One line naming the CPU and core count (no GL: for the studies that run on the CPU)."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            names = [ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")]
        cpu = names[0] if names else cpu
    except OSError:
        pass
    return f"machine: {cpu}, {os.cpu_count()} cores"


def machine_line(ctx: moderngl.Context) -> str:
    """One line naming the CPU, core count and GL renderer."""
    info = context_info(ctx)
    return f"{cpu_line()}; renderer: {info.renderer}; GL {info.version}"


def timed(fn: Callable[[], None], repeats: int = 5) -> float:
    """Median wall time of ``fn`` in seconds."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def block_system(spec: tuple[int, int, int] | str, spacing: float = 0.01, *, k_flexion: float = 0.0,
                 damping: float = 1e-3) -> SpringSystem:
    """Benchmark body: a block or ball of nodes, top layer fixed, structural and shear springs of
    10 N/m (and flexion springs of ``k_flexion``), 1 g per node, velocity damping ``damping``."""
    grid = NodeGrid(np.zeros(3), spacing, bench_occupancy(spec))
    top = grid.ijk[:, 1] == grid.ijk[:, 1].max()
    return from_grid(grid, k_structural=10.0, k_shear=10.0, k_flexion=k_flexion, mass=1e-3, fixed=top,
                     velocity_damping=damping)


def fragment_verlet(ctx: moderngl.Context, system: SpringSystem, dt: float, **layout) -> FragmentIntegrator:
    """The fragment backend's Verlet fast path (Mosegaard & Sørensen 2005, section 3.1) of ``system``
    in a node layout (``layout``, ``block``: :class:`FragmentIntegrator`'s)."""
    return FragmentIntegrator(ctx, system, None, "verlet", dt, path="foundation", **layout)


#: A way to build the timed simulation of a system at a step (s): (ctx, system, dt) -> Simulation.
SimFactory = Callable[[moderngl.Context, SpringSystem, float], Simulation]


def compact_verlet(ctx: moderngl.Context, system: SpringSystem, dt: float) -> Simulation:
    """:func:`fragment_verlet` on the compact layout (one node per fragment)."""
    return fragment_verlet(ctx, system, dt, layout="compact")


def stable_dt(system: SpringSystem, fraction: float) -> float:
    """``fraction`` of 1 / w_max (the bound of :func:`deformgl.sim.springs.max_angular_frequency`)."""
    return fraction / max_angular_frequency(system).omega


@dataclass
class SimRow:
    """One grid of ``bench sim``."""

    name: str
    nodes: int
    variant_ms: dict[str, float]
    numpy_ms: float


def bench_sim(ctx: moderngl.Context, *, steps: int = 40, grids=SIM_GRIDS,
              variants: dict[str, SimFactory] | None = None) -> list[SimRow]:
    """Fragment-pass Verlet step against the float64 NumPy reference on the same grids, in each
    of ``variants`` ({name: :data:`SimFactory`}; default: the compact layout, and the blocked
    layout the backend picks by itself, as a scene gets it)."""
    variants = variants or {"compact": compact_verlet, "blocked (default)": fragment_verlet}
    rows = []
    for spec in grids:
        system = block_system(spec)
        dt = stable_dt(system, 0.2)
        per_variant = {}
        for name, build in variants.items():
            sim = build(ctx, system, dt)
            sim.step(3)
            ctx.finish()

            def run(sim: Simulation = sim) -> None:
                sim.step(steps)
                ctx.finish()

            per_variant[name] = timed(run) / steps * 1e3
            sim.release()
        ref = NumpySimulation(system, "verlet", dt)
        ref_steps = max(1, min(steps, int(2e5 // system.count)))
        numpy_ms = timed(lambda: ref.step(ref_steps), repeats=3) / ref_steps * 1e3
        name = spec if isinstance(spec, str) else "x".join(map(str, spec))
        rows.append(SimRow(name, system.count, per_variant, numpy_ms))
    return rows


def format_sim(rows: list[SimRow], machine: str) -> str:
    """The ``bench sim`` table."""
    names = list(rows[0].variant_ms)
    head = f"{'grid':>9} {'nodes':>7} | " + " | ".join(f"{n + ' ms/step':>20} {'Mnode/s':>8}" for n in names)
    head += f" | {'numpy ms/step':>13} | {'speed-up vs numpy':>17}"
    lines = [machine, "fragment pass, position Verlet, 18 neighbours (Mosegaard & Sørensen 2005, eq. 1-3); baseline: float64 "
             "NumPy reference in this process", head, "-" * len(head)]
    for r in rows:
        cells = " | ".join(f"{ms:>20.3f} {r.nodes / ms / 1e3:>8.1f}" for ms in r.variant_ms.values())
        best = min(r.variant_ms.values())
        lines.append(f"{r.name:>9} {r.nodes:>7} | {cells} | {r.numpy_ms:>13.2f} | {r.numpy_ms / best:>16.1f}x")
    return "\n".join(lines)


def peers_report(ctx: moderngl.Context, *, steps: int = 40, grids=((27, 27, 27), (64, 64, 32)),
                 rounds: int = 7) -> str:
    """``bench sim --peers``: the foundation's fragment Verlet step, on the compact layout and on the
    blocked layout it picks by itself (several nodes per fragment), against the same step in Taichi
    (CPU), NVIDIA Warp (CPU) and Numba (``parallel=True``) on the same grids, in the same process. All steppers of a grid
    are built and warmed up first; then ``rounds`` rounds time ``steps`` steps of each in turn,
    so load from other processes hits all alike. Best and median of the rounds; ratios are
    fragment throughput / peer throughput, of the medians."""
    from deformgl.bench.peers import PeerStepper, available_peers, make_stepper, peer_import_errors

    def peer_run(st: PeerStepper) -> Callable[[], None]:
        def run() -> None:
            st.step(steps)
        return run

    lines = [machine_line(ctx), "same 18-neighbour position-Verlet step (Mosegaard & Sørensen 2005, eq. 1/2, damping, gravity, fixed "
             f"nodes) in float32; {rounds} alternating rounds of {steps} steps, best / median ms per step; "
             "ratio = fragment nodes/s / peer nodes/s of the medians (> 1: the fragment pass is faster)"]
    for peer, reason in peer_import_errors().items():
        lines.append(f"{peer}: not installed ({reason}); pip install 'deformgl[peers]'")
    versions = {p: v for p, v in available_peers().items() if v is not None}
    if not versions:
        return "\n".join(lines)
    for spec in grids:
        system = block_system(spec)
        dt = stable_dt(system, 0.2)
        sims = {"fragment": fragment_verlet(ctx, system, dt, layout="compact"),
                "blocked": fragment_verlet(ctx, system, dt)}
        steppers: dict[str, PeerStepper] = {}
        try:
            for peer in versions:
                steppers[peer] = make_stepper(peer, system, dt)

            def run_fragment(sim: FragmentIntegrator) -> Callable[[], None]:
                def run() -> None:
                    sim.step(steps)
                    ctx.finish()
                return run
            runs: dict[str, Callable[[], None]] = {name: run_fragment(sim) for name, sim in sims.items()}
            runs.update({peer: peer_run(st) for peer, st in steppers.items()})
            for run in runs.values():  # JIT and warm-up
                run()
            times: dict[str, list[float]] = {name: [] for name in runs}
            for r in range(rounds):
                for name in (list(runs) if r % 2 == 0 else list(reversed(runs))):
                    t0 = time.perf_counter()
                    runs[name]()
                    times[name].append((time.perf_counter() - t0) / steps * 1e3)
            block = sims["blocked"].block
        finally:
            for sim in sims.values():
                sim.release()
            for st in steppers.values():
                st.release()
        best = {name: min(t) for name, t in times.items()}
        median = {name: statistics.median(t) for name, t in times.items()}
        name = "x".join(map(str, spec))
        shape = "compact" if block is None else "x".join(map(str, block))
        lines.append(f"{name} ({system.count} nodes): fragment (compact) {best['fragment']:.3f} / "
                     f"{median['fragment']:.3f} ms/step ({system.count / median['fragment'] / 1e3:.1f} M nodes/s); "
                     f"blocked ({shape}, the default) {best['blocked']:.3f} / {median['blocked']:.3f} ms/step "
                     f"({system.count / median['blocked'] / 1e3:.1f} M nodes/s) -> blocked / compact = "
                     f"{median['fragment'] / median['blocked']:.2f}x")
        for peer, st in steppers.items():
            layer = f" ({st.threading_layer} layer)" if hasattr(st, "threading_layer") else ""
            lines.append(f"  {peer} {versions[peer]} CPU, {st.threads} thread(s){layer}: {best[peer]:.3f} / "
                         f"{median[peer]:.3f} ms/step ({system.count / median[peer] / 1e3:.1f} M nodes/s) "
                         f"-> fragment / {peer} = {median[peer] / median['fragment']:.2f}x, "
                         f"blocked / {peer} = {median[peer] / median['blocked']:.2f}x")
    return "\n".join(lines)