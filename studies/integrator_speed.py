"""Every explicit integrator on every backend (fragment, feedback, NumPy) on 64^2 ... 2048^2
cloths and 20k / 131k-node volumes, against the fragment Verlet baseline (docs/PERFORMANCE.md,
"Integrators on every backend"): ``python -m studies.integrator_speed``."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import moderngl
import numpy as np

from deformgl.bench.sim_speed import block_system, fragment_verlet, machine_line, timed
from deformgl.sim.springs import from_grid
from studies.common import gl_context, parse, parser, progress, run_main


#: the integrators study's workloads: the paper's cloths (Movania & Feng 2012, section 5) and the
#: 20k / 131k-node volumes of ``deformgl bench sim``.
INTEGRATOR_CLOTHS = (64, 256, 1024, 2048)
INTEGRATOR_VOLUMES = ((27, 27, 27), (64, 64, 32))


@dataclass
class IntegratorRow:
    """One workload of the integrators study's: ms/step and bytes/node per (backend, integrator)."""

    name: str
    nodes: int
    steps: int
    baseline_ms: float
    ms: dict[tuple[str, str], float]
    bytes_per_node: dict[tuple[str, str], float]


def cloth_system(n: int, spacing: float = 0.01):
    """The benchmark cloth: n x n nodes, two corners fixed, structural, shear and flexion springs."""
    from deformgl.sim.springs import cloth

    fixed = np.zeros(n * n, bool)
    fixed[[0, (n - 1) * n]] = True  # corners (0, 0) and (n-1, 0)
    return cloth(n, n, spacing, k_structural=10.0, k_shear=10.0, k_flexion=2.0, mass=np.full(n * n, 1e-3),
                 fixed=fixed, gravity=(0.0, -9.81, 0.0), velocity_damping=1e-4)


def _integrator_workloads(cloths, volumes):
    """(name, grid, system, baseline system: the same without flexion springs) of each workload."""
    for n in cloths:
        system = cloth_system(n)
        grid = system.grid
        base = from_grid(grid, k_structural=10.0, k_shear=10.0, mass=1e-3, fixed=system.fixed,
                         velocity_damping=1e-4)
        yield f"{n}x{n} cloth", grid, system, base
    for spec in volumes:
        system = block_system(spec, k_flexion=2.0)
        yield "x".join(map(str, spec)) + " volume", system.grid, system, block_system(spec)


def bench_integrators(ctx: moderngl.Context, *, cloths=INTEGRATOR_CLOTHS, volumes=INTEGRATOR_VOLUMES,
                      steps: int = 20, backends=("fragment", "feedback", "numpy"),
                      node_steps: float = 2e6, progress: Callable[[str], None] | None = None) -> list[IntegratorRow]:
    """Every integrator on every backend on each workload, against the foundation's fragment-pass
    Verlet of the same grid (the baseline, measured in the same run).

    Steps per timing: ``steps``, fewer on big grids (about ``node_steps`` node-steps, at least 2)
    so that 2048^2 finishes; the NumPy reference gets a tenth of that.
    """
    from deformgl.sim.backends.feedback import FeedbackSimulation
    from deformgl.sim.backends.explicit_gpu import FragmentIntegrator
    from deformgl.sim.integrators import EXPLICIT_INTEGRATORS, initial_state, step as numpy_step
    from deformgl.sim.springs import max_angular_frequency

    rows = []
    for name, grid, system, base_system in _integrator_workloads(cloths, volumes):
        if progress is not None:
            progress(name)
        n_steps = max(2, min(steps, int(node_steps // grid.count)))
        dt = 0.5 / max_angular_frequency(system).omega
        base = fragment_verlet(ctx, base_system, dt, layout="compact")  # (one node per fragment, as the stages)
        try:
            base.step(2)
            ctx.finish()

            def run_base() -> None:
                base.step(n_steps)
                ctx.finish()
            baseline = timed(run_base, 3) / n_steps * 1e3
        finally:
            base.release()
        ms, per_node = {}, {}
        state = initial_state(system, dt)
        for backend in backends:
            for integrator in EXPLICIT_INTEGRATORS:
                if backend == "numpy":
                    k = max(1, n_steps // 10)
                    holder = [state]

                    def run_numpy() -> None:
                        for i in range(k):
                            holder[0] = numpy_step(system, integrator, holder[0], dt, i * dt)
                    ms[backend, integrator] = timed(run_numpy, 1 if grid.count > 3e5 else 3) / k * 1e3
                    continue
                sim: FragmentIntegrator | FeedbackSimulation
                if backend == "fragment":
                    sim = FragmentIntegrator(ctx, system, grid, integrator, dt, state=state)
                else:
                    sim = FeedbackSimulation(ctx, system, integrator, dt, state=state)
                try:
                    sim.step(2)
                    ctx.finish()

                    def run_gl() -> None:
                        sim.step(n_steps)
                        ctx.finish()
                    ms[backend, integrator] = timed(run_gl, 3) / n_steps * 1e3
                    per_node[backend, integrator] = sim.bytes_per_node
                finally:
                    sim.release()
        rows.append(IntegratorRow(name, grid.count, n_steps, baseline, ms, per_node))
    return rows


def format_integrators(rows: list[IntegratorRow], machine: str) -> str:
    """The the integrators study's table: ms/step, ratio to the baseline, GPU bytes per node."""
    lines = [machine, "structural + shear + flexion springs (k 10/10/2 N/m), velocity damping; cloths with two "
             "corners fixed, volumes with the top layer fixed; baseline: the foundation's fragment-pass "
             "position Verlet of the same grid (structural + shear), same run; ratio = baseline / ms "
             "(> 1: faster than the baseline)"]
    for r in rows:
        lines.append(f"{r.name} ({r.nodes} nodes, {r.steps} steps per timing): baseline fragment Verlet "
                     f"{r.baseline_ms:.3f} ms/step")
        lines.append(f"  {'backend':>9} {'integrator':>14} | {'ms/step':>9} | {'vs baseline':>11} | {'bytes/node':>10}")
        for (backend, name), ms in r.ms.items():
            per_node = r.bytes_per_node.get((backend, name))
            lines.append(f"  {backend:>9} {name:>14} | {ms:>9.3f} | {r.baseline_ms / ms:>10.3f}x | "
                         f"{'-' if per_node is None else f'{per_node:.0f}':>10}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = parser("integrator_speed", "each explicit integrator on each backend against the fragment Verlet baseline")
    p.add_argument("--steps", type=int, default=20, help="steps per timing (default 20)")
    args = parse(p, argv)
    with gl_context(args) as ctx:
        print(format_integrators(bench_integrators(ctx, steps=args.steps, progress=progress(args)), machine_line(ctx)))
    return 0


if __name__ == "__main__":
    run_main(main)
