"""The spline body hanging without inversion (issue 44, item 6): ``python -m studies.spline_inversion``.

The hanging cantilever of :mod:`studies.inversion` (0.2 x 0.02 x 0.02 m, rho = 1000 kg/m^3, its
x = 0 face clamped: here a penalty of 10^3 E / h on the face's material, as
:mod:`studies.spline_large_deflection` holds it) as a spline body, left to hang under its own
weight for ``--seconds`` at 0.9 x its ``dt_limit`` with mass damping, on the fragment backend (the
GPU form, float32): the census at the end is the spans with a Gauss point at det F <= 0
(:meth:`~deformgl.sim.terms.spline.term.SplineCells.inversions`), with whether every control point
stayed finite and the tip's sag. Issue 44 asks for E 5 and 50 kPa, 5 and 9 across, nu 0.25 and
0.45, mass damping 1, 3 and 10 /s, 10 s, semi-implicit Euler, Verlet and RK4: the default here is
the subset that fits a 2-core llvmpipe machine (5 across); ``--across 9`` and the other options
run the rest.
"""

from __future__ import annotations

import argparse
import itertools
import time

import numpy as np

from deformgl.sim.limits import dt_limit
from deformgl.sim.simulation import make_simulation
from deformgl.sim.terms.spline.body import SplineBody
from deformgl.sim.terms.spline.term import SplineAnchor, SplineCells, spline_system

G = 9.81


def hang(ctx, youngs_modulus: float, across: int, nu: float, damping: float, integrator: str,
         seconds: float) -> tuple[int, int, bool, float, int, float]:
    """(inverted spans, spans, finite, tip sag m, steps, wall s) of one run."""
    h = 0.02 / (across - 1)
    lo, hi = [0.0, -0.01, -0.01], [0.2, 0.01, 0.01]
    body = SplineBody.from_box(lo, hi, h, youngs_modulus=youngs_modulus, poissons_ratio=nu, density=1000.0)
    points, weights = body.face_points(0, 0.0, lo, hi)
    system = spline_system(body, anchors=(SplineAnchor(body, points, weights, 1e3 * youngs_modulus / h),),
                           gravity=(0.0, -G, 0.0), mass_damping=damping)
    dt = 0.9 * dt_limit(system, integrator).dt
    steps = int(np.ceil(seconds / dt))
    dt = seconds / steps
    start = time.perf_counter()
    with make_simulation(system, integrator, "fragment", dt=dt, ctx=ctx) as sim:
        sim.step(steps)
        x = np.asarray(sim.positions(), np.float64)
    wall = time.perf_counter() - start
    cells = next(t for t in system.terms if isinstance(t, SplineCells))
    finite = bool(np.isfinite(x).all())
    census = cells.inversions(x, None) if finite else (len(body.span_nodes), "")
    tip = -float(body.field(np.array([[0.2, 0.0, 0.0]]), x - body.rest_positions)[0, 1]) if finite else float("nan")
    return census[0], len(body.span_nodes), finite, tip, steps, wall


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies.spline_inversion", description=__doc__.split("\n\n")[0])
    parser.add_argument("--youngs", default="5e3,5e4", help="Young's moduli, Pa, comma separated")
    parser.add_argument("--across", default="5", help="nodes across the 2 cm, comma separated (issue 44: 5,9)")
    parser.add_argument("--nu", default="0.25,0.45", help="Poisson's ratios")
    parser.add_argument("--damping", default="1", help="mass damping, 1/s (issue 44: 1,3,10)")
    parser.add_argument("--integrators", default="semi-implicit", help="issue 44: semi-implicit,verlet,rk4")
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated seconds (issue 44: 10)")
    args = parser.parse_args(argv)
    from deformgl.gl.context import create_context

    ctx = create_context()
    print("spline cantilever 0.2 x 0.02 x 0.02 m hanging, 0.9 x dt_limit, fragment backend; spans with a Gauss "
          "point at det F <= 0 at the end")
    for e, n, nu, d, integrator in itertools.product(
            [float(v) for v in args.youngs.split(",")], [int(v) for v in args.across.split(",")],
            [float(v) for v in args.nu.split(",")], [float(v) for v in args.damping.split(",")],
            args.integrators.split(",")):
        inverted, spans, finite, tip, steps, wall = hang(ctx, e, n, nu, d, integrator, args.seconds)
        print(f"  E {e:>7g} Pa  {n} across  nu {nu:.2f}  damping {d:>4g} /s  {integrator:<13}: {inverted} of {spans} "
              f"spans inverted, finite {finite}, tip sag {tip * 1e3:.2f} mm, {steps} steps, {wall:.0f} s", flush=True)
    ctx.release()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
