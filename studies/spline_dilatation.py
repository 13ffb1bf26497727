"""How the spline body takes its volumetric strain, measured before choosing (issue 44, item 1):
``python -m studies.spline_dilatation`` prints, for the three forms of
:attr:`deformgl.sim.terms.spline.body.SplineBody.dilatation` — the strain itself at every Gauss
point ("full"), its mean per span ("p0", the mean dilatation) and its L2 projection per span onto
linear functions ("p1") — the two checks of docs/ACCURACY.md section 3 against their FEM, static
float64 solves (SciPy) on box bodies whose nodes lie on the faces:

* the cantilever 1 x 0.1 x 0.1 m, clamped at x = 0 (a penalty of 10^3 E / h on the face's material),
  its own weight: the end face's mean sag over rho g L^4 / (E w^2), against the FEM of each ν
  (``studies.tissue_accuracy.CANTILEVER_FEM``);
* the 2 cm cube column, clamped base, top pressure: lateral over axial strain
  (``studies.tissue_accuracy.COLUMN_FEM``; lateral: the mean u_x over the band 0.4-0.6 of the height
  on the face x = side, over side / 2), where ν shows.

The bending check is where a projection that is too coarse softens the body; the column is where
a body that keeps the whole strain locks. docs/EQUATIONS.md, "Spline cells", quotes the table.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as spl

from deformgl.sim.terms.spline.body import DILATATIONS, SplineBody
from deformgl.sim.terms.spline.term import SplineAnchor, SplineCells
from studies.common import parse, parser, progress, run_main
from studies.tissue_accuracy import CANTILEVER_FEM, COLUMN_FEM

#: The cantilever's material (docs/ACCURACY.md section 2): E in Pa, rho in kg/m^3; g in m/s^2.
E, RHO, G = 1.0e8, 1000.0, 9.81
#: The clamp's penalty, times E / h (per m^2 of the clamped face).
CLAMP = 1.0e3


def _solve(body: SplineBody, clamp_axis: int, size, forces: np.ndarray, clamp: float = CLAMP) -> np.ndarray:
    """Node displacements (N, 3), m, of the body clamped on its face ``x[clamp_axis] = 0`` by a
    penalty ``clamp`` E / h."""
    points, weights = body.face_points(clamp_axis, 0.0, [0, 0, 0], size)
    anchor = SplineAnchor(body, points, weights, clamp * body.youngs_modulus / body.spacing)
    k = SplineCells(body).dt_stiffness(body.rest_positions) + anchor.matrix
    return spl.spsolve(k.tocsc(), forces.ravel()).reshape(-1, 3)


def cantilever_ratio(across: int, nu: float, dilatation: str = "p1", *, clamp: float = CLAMP) -> float:
    """The spline cantilever's normalised end-face sag over its FEM's at ``across`` nodes across."""
    size = (1.0, 0.1, 0.1)
    body = SplineBody.from_box([0, 0, 0], size, 0.1 / (across - 1), youngs_modulus=E, poissons_ratio=nu,
                               density=RHO, dilatation=dilatation)
    f = np.zeros((body.count, 3))
    f[:, 1] = -body.lumped_mass * G
    u = _solve(body, 0, size, f, clamp)
    tip, weights = body.face_points(0, 1.0, [0, 0, 0], size)
    sag = -float(weights @ body.field(tip, u)[:, 1]) / weights.sum()
    return sag / (RHO * G / (E * 0.01)) / CANTILEVER_FEM[nu]


def column_ratio(across: int, nu: float, dilatation: str = "p1", *, side: float = 0.02,
                 pressure: float = 1.0e3) -> float:
    """The spline column's lateral over axial strain over its mixed FEM's."""
    size = (side,) * 3
    body = SplineBody.from_box([0, 0, 0], size, side / (across - 1), youngs_modulus=1.0e4, poissons_ratio=nu,
                               density=1000.0, dilatation=dilatation)
    top, top_w = body.face_points(1, side, [0, 0, 0], size)
    nodes, values, _ = body.locate(top)
    f = np.zeros((body.count, 3))
    np.add.at(f[:, 1], nodes.ravel(), (-pressure * top_w[:, None] * values).ravel())
    u = _solve(body, 1, size, f)
    axial = -float(top_w @ body.field(top, u)[:, 1]) / top_w.sum() / side
    band, band_w = body.face_points(0, side, [0, 0.4 * side, 0], [side, 0.6 * side, side])
    lateral = float(band_w @ body.field(band, u)[:, 0]) / band_w.sum() / (side / 2)
    return lateral / axial / COLUMN_FEM[nu]


def table(across: tuple[int, ...], report=None) -> str:
    lines = ["spline body, static float64 solves: ratio to FEM by how the volumetric strain is taken",
             f"{'check':<10} {'nu':>5} {'across':>6} | " + " | ".join(f"{d:>7}" for d in DILATATIONS)]
    checks = (("cantilever", cantilever_ratio, (0.25, 0.45, 0.49)), ("column", column_ratio, (0.3, 0.45, 0.49)))
    for name, ratio, nus in checks:
        for nu in nus:
            for n in across:
                if report:
                    report(f"{name} nu {nu} at {n} across")
                row = [ratio(n, nu, d) for d in DILATATIONS]
                lines.append(f"{name:<10} {nu:>5.2f} {n:>6} | " + " | ".join(f"{r:>7.4f}" for r in row))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = parser("spline_dilatation", "the spline body's volumetric strain, three ways, against FEM")
    p.add_argument("--across", default="3,5,9", help="nodes across the thickness (default 3,5,9; --quick: 3,5)")
    args = parse(p, argv)
    across = (3, 5) if args.quick else tuple(int(a) for a in args.across.split(","))
    print(table(across, progress(args)))
    return 0


if __name__ == "__main__":
    run_main(main)
