"""The spline body at large deflection (issue 44, item 6): ``python -m studies.spline_large_deflection``.

The 0.2 x 0.02 x 0.02 m cantilever of docs/ACCURACY.md section 7 (rho = 1000 kg/m^3, its own
weight, clamped at x = 0 by a penalty of 10^3 E / h on the face's material) at the static
equilibrium of the corotational spline body (Newton's method of ``studies.tissue_accuracy``'s
``static_equilibrium``, the term's ``R K_e R^T`` as its Jacobian, the gravity in increments), the
end face's centre displacement (u_x, u_y) read through the B-spline field, against the neo-Hookean
FEM of the same E and ν (``studies.tissue_accuracy.NEO_HOOKEAN_FEM``). A case whose Newton
iterations stall is reported as such: the Jacobian leaves out the rotations' own derivative,
which matters where the rotations are large (50 kPa: the tip sags 94 % of the length).
"""

from __future__ import annotations

import time

import numpy as np

from deformgl.errors import DeformglError
from deformgl.sim.terms.spline.body import SplineBody
from deformgl.sim.terms.spline.term import SplineAnchor, spline_system
from studies.common import parse, parser, progress, run_main
from studies.tissue_accuracy import G, NEO_HOOKEAN_FEM, static_equilibrium


def tip(across: int, youngs_modulus: float, nu: float, *, increments: int = 8) -> tuple[float, float]:
    """The end face's centre (u_x, u_y) in m at equilibrium, ``across`` nodes across the 2 cm.

    Raises:
        DeformglError: Newton's iterations stalled in an increment.
    """
    h = 0.02 / (across - 1)
    lo, hi = [0.0, -0.01, -0.01], [0.2, 0.01, 0.01]
    body = SplineBody.from_box(lo, hi, h, youngs_modulus=youngs_modulus, poissons_ratio=nu, density=1000.0)
    points, weights = body.face_points(0, 0.0, lo, hi)
    system = spline_system(body, anchors=(SplineAnchor(body, points, weights, 1e3 * youngs_modulus / h),),
                           gravity=(0.0, -G, 0.0))
    x = static_equilibrium(system, increments=increments)
    u = body.field(np.array([[0.2, 0.0, 0.0]]), x - body.rest_positions)[0]
    return float(u[0]), float(u[1])


def main(argv: list[str] | None = None) -> int:
    p = parser("spline_large_deflection", "the spline cantilever at large deflection against neo-Hookean FEM")
    p.add_argument("--across", type=int, default=5, help="nodes across the 2 cm (default 5; about 2 minutes a case)")
    p.add_argument("--increments", type=int, default=8, help="gravity increments of the Newton solve (default 8)")
    args = parse(p, argv)
    report = progress(args)
    print("spline cantilever 0.2 x 0.02 x 0.02 m at static equilibrium, end-face centre (u_x, u_y) m; "
          "relative error against the neo-Hookean FEM")
    for (e, nu), ref in NEO_HOOKEAN_FEM.items():
        if report:
            report(f"E {e:g} Pa, nu {nu}")
        start = time.perf_counter()
        try:
            ux, uy = tip(args.across, e, nu, increments=args.increments)
        except DeformglError as exc:
            print(f"  E {e:>8g} Pa  nu {nu:.2f}  {args.across} across: {exc}")
            continue
        print(f"  E {e:>8g} Pa  nu {nu:.2f}  {args.across} across: ({ux:+.6f}, {uy:+.6f})  "
              f"error ({ux / ref[0] - 1:+.4f}, {uy / ref[1] - 1:+.4f})  {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    run_main(main)
