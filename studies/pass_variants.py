"""The fragment Verlet pass in its node layouts — compact (neighbours by node-number offsets on a
dense grid), compact with the neighbour-index texture even there, and blocked 1x2x2 — against the
float64 NumPy reference on 4k to 131k nodes (docs/PERFORMANCE.md, "Simulation step"):
``python -m studies.pass_variants``. The indexed lookup is the one the product takes on grids that
are not dense; here it is forced (``FoundationVerlet.for_system(layout="indexed")``) to measure
what the offsets save."""

from __future__ import annotations

import moderngl

from deformgl.bench.sim_speed import SimFactory, bench_sim, compact_verlet, format_sim, fragment_verlet, machine_line
from deformgl.sim.backends.verlet_pass import FoundationVerlet
from deformgl.sim.simulation import Simulation
from deformgl.sim.springs import SpringSystem
from studies.common import gl_context, parse, parser, run_main


def indexed_verlet(ctx: moderngl.Context, system: SpringSystem, dt: float) -> Simulation:
    """The one-node pass reading its neighbours from the index texture on any grid."""
    return FoundationVerlet.for_system(ctx, system, dt, layout="indexed")


def blocked_1x2x2(ctx: moderngl.Context, system: SpringSystem, dt: float) -> Simulation:
    """The blocked layout, 1x2x2 nodes per fragment."""
    return fragment_verlet(ctx, system, dt, block=(1, 2, 2))


#: {column: how its simulation is built}
PASS_VARIANTS: dict[str, SimFactory] = {"compact": compact_verlet, "compact indexed": indexed_verlet,
                                        "blocked 1x2x2": blocked_1x2x2}


def main(argv: list[str] | None = None) -> int:
    p = parser("pass_variants", "the fragment Verlet pass in each node layout against the NumPy reference")
    p.add_argument("--steps", type=int, default=40, help="steps per timing (default 40)")
    args = parse(p, argv)
    with gl_context(args) as ctx:
        print(format_sim(bench_sim(ctx, steps=args.steps, variants=PASS_VARIANTS), machine_line(ctx)))
    return 0


if __name__ == "__main__":
    run_main(main)
