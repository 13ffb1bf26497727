"""The public API from a mesh file or arrays to simulated nodes, a deformed mesh and a PNG.

Run:  python examples/api_cantilever.py out.png [--mesh MESH] [--integrator rk4] [--backend feedback]

Without ``--mesh`` the body is a 1 m x 0.4 m x 0.4 m box given as NumPy arrays. The end at x = 0
is held and the rest sags under gravity; ``deformgl.run`` refuses a dt above the integrator's
stability limit (``--unstable run`` or ``subdivide`` to go on anyway) and watches for blow-ups.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import deformgl as dg


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out")
    parser.add_argument("--mesh", help="a mesh file (default: a box as arrays)")
    parser.add_argument("--resolution", type=int, default=8, help="nodes along the longest side")
    parser.add_argument("--integrator", default="verlet", choices=dg.INTEGRATORS)
    parser.add_argument("--backend", default="fragment", choices=["fragment", "feedback", "numpy"])
    parser.add_argument("--dt", type=float, default=1e-3)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--unstable", default="refuse", choices=["refuse", "run", "subdivide"])
    args = parser.parse_args(argv)
    rubber = dg.ElasticMaterial(youngs_modulus=1e6, density=1100.0, mass_damping=2.0)  # SI: Pa, kg/m^3, 1/s
    options = dict(resolution=args.resolution, material=rubber, fixed=dg.below("x", 0.05))
    try:
        if args.mesh:
            body = dg.Body.from_mesh(args.mesh, **options)
        else:
            V = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 0.4) for z in (0.0, 0.4)])
            F = np.array([[1, 3, 0], [4, 1, 0], [0, 3, 2], [2, 4, 0], [1, 7, 3], [5, 1, 4],
                          [5, 7, 1], [3, 7, 2], [6, 4, 2], [2, 7, 6], [6, 5, 4], [7, 5, 6]])
            body = dg.Body.from_arrays(V, F, **options)
        with body:
            sim = body.simulate(args.integrator, args.backend, dt=args.dt)
            result = dg.run(sim, args.steps, unstable=args.unstable)
            for note in result.notes:
                print(note)
            vertices, _ = body.mapped_mesh(sim)
            print(f"{body.grid.count} nodes, {len(vertices)} vertices; lowest vertex at y = {vertices[:, 1].min():.4f}")
            dg.write_png(args.out, body.render(sim, size=(640, 480)))
    except dg.DeformglError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
