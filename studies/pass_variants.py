"""The fragment Verlet pass in its variants — compact, indexed, with the branch, blocked 1x2x2,
and the 3D-atlas layout drawn as rectangles, one quad or points — against the float64 NumPy
reference on 4k to 131k nodes (docs/PERFORMANCE.md, "Simulation step"):
``python -m studies.pass_variants``. The variants other than compact and blocked are options of
:class:`~deformgl.sim.backends.explicit_gpu.FragmentIntegrator` that only this study uses."""

from __future__ import annotations

from deformgl.bench.sim_speed import bench_sim, format_sim, machine_line
from studies.common import gl_context, parse, parser, run_main

#: {column: FragmentIntegrator options}
PASS_VARIANTS = {
    "compact": dict(layout="compact"), "compact indexed": dict(layout="indexed"),
    "compact+branch": dict(layout="compact", branch=True), "blocked 1x2x2": dict(block=(1, 2, 2)),
    "atlas rects": dict(layout="atlas", draw="rects"), "atlas quad": dict(layout="atlas", draw="quad"),
    "atlas points": dict(layout="atlas", draw="points")}


def main(argv: list[str] | None = None) -> int:
    p = parser("pass_variants", "the fragment Verlet pass in each variant against the NumPy reference")
    p.add_argument("--steps", type=int, default=40, help="steps per timing (default 40)")
    args = parse(p, argv)
    with gl_context(args) as ctx:
        print(format_sim(bench_sim(ctx, steps=args.steps, variants=PASS_VARIANTS), machine_line(ctx)))
    return 0


if __name__ == "__main__":
    run_main(main)
