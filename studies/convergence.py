"""When a run has converged (issue 26): the equilibrium stop against each integrator's own 1 s run.

The workload is the issue's cantilever: 0.2 x 0.02 x 0.02 m of E = 1e7 Pa, rho = 1000 kg/m^3 and
Rayleigh mass damping 50/s on the calibrated lattice (:func:`deformgl.sim.materials.lattice_system`),
21 nodes along (3 across), clamped at x = 0, sagging under gravity; its 1 s sag is 4.77 mm.

Per integrator and dt (subdivided where the dt check asks for it), on the fragment backend: the
run with the default :class:`~deformgl.sim.equilibrium.ConvergeRule` stops at some time; the tip's
sag there is compared with the sag of the same run continued to 1 s (the convergence checks only
read positions, so the continued run is the integrator's own 1 s run). The paper's displacement
criterion at its defaults is measured the same way for contrast.

XPBD at dt 1e-5 s does not settle on the float32 fragment backend: each sweep's position
correction, about w C / (1/(k dt^2)) = 2e-9 m, is below float32's resolution of positions near
0.1 m (1.5e-8 m), so the tip wanders in a limit cycle of +-0.4 mm and the stop (rightly) never
calls it converged; its row is also measured on the float64 NumPy backend, which settles.

``python -m studies.convergence [--quick]`` prints the table (``--quick``: dt 1e-4 s,
three integrators; the full table takes about 10 minutes on 2 cores with llvmpipe).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from typing import Any

import moderngl
import numpy as np

from deformgl.scene.body import Body, below
from deformgl import run
from deformgl.sim.equilibrium import ConvergeRule
from deformgl.sim.materials import ElasticMaterial

__all__ = ["BOX", "FACES", "MATERIAL", "OPTIONS", "RUNS", "StopRow", "cantilever", "stop_row", "format_rows"]

BOX = np.array([[x, y, z] for x in (0.0, 0.2) for y in (0.0, 0.02) for z in (0.0, 0.02)])
FACES = np.array([[1, 3, 0], [4, 1, 0], [0, 3, 2], [2, 4, 0], [1, 7, 3], [5, 1, 4],
                  [5, 7, 1], [3, 7, 2], [6, 4, 2], [2, 7, 6], [6, 5, 4], [7, 5, 6]])
MATERIAL = ElasticMaterial(1e7, 1000.0, mass_damping=50.0)
#: every integrator that runs the cantilever (explicit Euler and midpoint are refused: their
#: damped limits need every mode damped, and the dt bound holds the cells' barrier, which Rayleigh
#: beta does not damp: midpoint's limit is 2.2e-6 s, 50 substeps of 1e-4 s, beyond 16)
RUNS = ("semi-implicit", "rk4", "verlet", "implicit-euler", "xpbd")
#: options per (integrator, dt): at dt 1e-5 s the implicit matrix M + dt C + dt^2 K is within
#: (w_max dt)^2 = 5 % of M, so 5 CG iterations solve it to float32 (and XPBD's compliance
#: 1/(k dt^2) dominates, so 5 sweeps do too); at 1e-2 s implicit Euler's 20 Jacobi-CG iterations
#: leave a tenth of the weight unbalanced (it never stops), the multigrid's solve it; the
#: defaults elsewhere
OPTIONS: dict[tuple[str, float], dict[str, Any]] = {("implicit-euler", 1e-5): {"cg_iterations": 5},
                                                    ("implicit-euler", 1e-2): {"cg_preconditioner": "multigrid"},
                                                    ("xpbd", 1e-5): {"iterations": 5}}


def cantilever(ctx: moderngl.Context | None, resolution: int = 21) -> Body:
    """The cantilever body (nodes along its length = ``resolution``)."""
    return Body.from_arrays(BOX, FACES, resolution=resolution, material=MATERIAL, fixed=below("x", 0.02), ctx=ctx)


def tip_sag(body: Body, sim: object = None) -> float:
    """The downward displacement (m) of the node at the free end's lower edge."""
    rest = body.node_positions()
    tip = int(np.argmax(rest[:, 0] - 1e-6 * rest[:, 1]))
    return float(rest[tip, 1] - body.node_positions(sim)[tip, 1])


@dataclass(frozen=True)
class StopRow:
    """One run: where the stop ended it and how far that is from the 1 s run."""

    integrator: str
    dt: float
    backend: str
    criterion: str
    substeps: int
    converged: bool
    stop_time: float
    stop_sag: float
    final_sag: float
    measures: str
    wall: float

    @property
    def error(self) -> float:
        """(stop sag - 1 s sag) / 1 s sag."""
        return (self.stop_sag - self.final_sag) / self.final_sag


def stop_row(ctx: moderngl.Context | None, integrator: str, dt: float, *, criterion: str = "equilibrium",
             resolution: int = 21, seconds: float = 1.0, backend: str = "fragment") -> StopRow:
    """Run the cantilever with the convergence stop, then on to ``seconds``."""
    with cantilever(ctx, resolution) as body:
        sim = body.simulate(integrator, backend, dt=dt, **OPTIONS.get((integrator, dt), {}))
        total = round(seconds / dt)
        start = time.perf_counter()
        result = run(sim, total, unstable="subdivide", converge=ConvergeRule(criterion))
        wall = time.perf_counter() - start
        stopped, stop_time = tip_sag(body, sim), sim.time
        run(sim, total - result.steps // result.substeps, unstable="subdivide")  # the same run, on to the end
        if abs(sim.time - seconds) > 1e-9 * seconds:
            raise RuntimeError(f"the continued run ended at {sim.time} s, not {seconds} s")
        return StopRow(integrator, dt, backend, criterion, result.substeps, bool(result.converged), stop_time, stopped,
                       tip_sag(body, sim), result.convergence or "", wall)


def format_rows(rows: list[StopRow]) -> str:
    head = (f"{'integrator':<15} {'dt s':>7} {'backend':<8} {'sub':>3} {'criterion':<12} {'stop s':>7} {'stop sag m':>10} "
            f"{'1 s sag m':>10} {'error':>8}  {'wall s':>6}  last check")
    lines = [head]
    for r in rows:
        lines.append(f"{r.integrator:<15} {r.dt:>7.0e} {r.backend:<8} {r.substeps:>3} {r.criterion:<12} {r.stop_time:>7.4f} "
                     f"{r.stop_sag:>10.4e} {r.final_sag:>10.4e} {r.error:>+8.3%}  {r.wall:>6.2f}  "
                     f"{'converged' if r.converged else 'NOT converged'}: {r.measures}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="dt 1e-4 s, three integrators")
    args = parser.parse_args(argv)
    from deformgl.bench.sim_speed import machine_line
    from deformgl.gl.context import create_context

    ctx = create_context()
    try:
        print(machine_line(ctx))
        dts = (1e-4,) if args.quick else (1e-4, 1e-5)
        integrators = ("semi-implicit", "rk4", "verlet") if args.quick else RUNS
        rows = [stop_row(ctx, i, dt) for dt in dts for i in integrators]
        if not args.quick:  # XPBD at 1e-5 s settles in float64 (its float32 corrections fall below the ulp)
            rows.append(stop_row(ctx, "xpbd", 1e-5, backend="numpy"))
        rows += [stop_row(ctx, "verlet", dt, criterion="displacement") for dt in dts]
        print(format_rows(rows))
    finally:
        ctx.release()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
