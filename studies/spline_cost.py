"""What a step of the spline cells costs on the fragment backend against the lattice's step on the
same node grid (issue 44, item 7; docs/PERFORMANCE.md, "Spline cells: cost per step"):
``python -m studies.spline_cost``.

The bodies: a box whose knot spans fill the grid (faces on knot planes, so every span is full and
the control grid is the whole box of nodes), E = 1 MPa, nu = 0.45, its top layer of control points
held; the lattice: ``bench sim``'s block of the same nodes on the fragment backend as a scene gets
it (the foundation Verlet pass, blocked where that measures faster). Rounds alternate between the
rows; the table gives each row's median ms per step and the spread of the rounds (min-max), and
its ratio to the lattice's median in the same process. The GPU bytes per node are the backend's
own count (textures, padding included)."""

from __future__ import annotations

import dataclasses
import statistics
import time
from collections.abc import Callable

import numpy as np

from deformgl.bench.sim_speed import block_system, fragment_verlet, machine_line, stable_dt
from deformgl.sim.limits import dt_limit
from deformgl.sim.simulation import NumpySimulation, Simulation, make_simulation
from deformgl.sim.terms.spline.body import SplineBody
from deformgl.sim.terms.spline.term import spline_system
from studies.common import gl_context, parse, parser, run_main

#: (nodes along x, y, z) of the control grids timed: about 20k and 131k nodes.
GRIDS = ((27, 27, 27), (64, 64, 32))


def spline_box(shape: tuple[int, int, int], spacing: float = 0.01):
    """The spline body whose spans fill a ``shape`` grid of control points, and its system (top
    layer of control points held, gravity, mass damping 1 /s)."""
    lo = np.full(3, 0.5 * spacing)
    hi = (np.array(shape) - 1.5) * spacing
    body = SplineBody.from_box(lo, hi, spacing, youngs_modulus=1e6, poissons_ratio=0.45, density=1000.0,
                               origin=np.zeros(3))
    system = spline_system(body, gravity=(0.0, -9.81, 0.0), mass_damping=1.0)
    top = body.rest_positions[:, 1] >= body.rest_positions[:, 1].max() - 1e-9
    return body, dataclasses.replace(system, fixed=top)


def _round(sim: Simulation, steps: int, finish: Callable[[], None]) -> float:
    t0 = time.perf_counter()
    sim.step(steps)
    finish()
    return (time.perf_counter() - t0) / steps * 1e3


def main(argv: list[str] | None = None) -> int:
    p = parser("spline_cost", "a step of the spline cells on the fragment backend against the lattice's")
    p.add_argument("--rounds", type=int, default=5, help="alternating timing rounds (default 5)")
    p.add_argument("--steps", type=int, default=4, help="steps per round (default 4)")
    p.add_argument("--small", action="store_true", help="the 20k-node grid only")
    args = parse(p, argv)
    grids = GRIDS[:1] if args.small else GRIDS
    with gl_context(args) as ctx:
        print(machine_line(ctx))
        print("ms per step (median of the rounds, min-max); ratio: to the lattice's median, same process")
        head = f"{'nodes':>7} {'spans':>7} | {'row':<34} | {'ms/step':>9} {'min-max':>17} | {'x lattice':>9} | {'B/node':>7}"
        print(head)
        print("-" * len(head))
        for shape in grids:
            body, system = spline_box(shape)
            lattice = block_system(shape)
            sims: dict[str, Simulation] = {
                "lattice, Verlet (foundation pass)": fragment_verlet(ctx, lattice, stable_dt(lattice, 0.2)),
                "spline, semi-implicit (stages)": make_simulation(
                    system, "semi-implicit", "fragment", dt=0.5 * dt_limit(system, "semi-implicit").dt, ctx=ctx),
                "spline, Verlet (stages)": make_simulation(
                    system, "verlet", "fragment", dt=0.5 * dt_limit(system, "verlet").dt, ctx=ctx),
            }
            times: dict[str, list[float]] = {name: [] for name in sims}
            for sim in sims.values():
                sim.step(1)
                ctx.finish()
            for _ in range(args.rounds):
                for name, sim in sims.items():
                    times[name].append(_round(sim, args.steps, ctx.finish))
            ref = NumpySimulation(system, "semi-implicit", 1e-5)
            numpy_ms = statistics.median(_round(ref, 1, lambda: None) for _ in range(3))
            base = statistics.median(times["lattice, Verlet (foundation pass)"])
            for name, sim in sims.items():
                ms = statistics.median(times[name])
                spread = f"{min(times[name]):.2f}-{max(times[name]):.2f}"
                print(f"{body.count:>7} {len(body.span_nodes):>7} | {name:<34} | {ms:>9.2f} {spread:>17} | "
                      f"{ms / base:>9.1f} | {sim.bytes_per_node:>7.0f}")
                sim.release()
            print(f"{body.count:>7} {len(body.span_nodes):>7} | {'spline, NumPy float64 (this CPU)':<34} | "
                  f"{numpy_ms:>9.2f} {'':>17} | {numpy_ms / base:>9.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main(main))
