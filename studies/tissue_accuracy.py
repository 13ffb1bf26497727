"""The soft-tissue lattice (springs plus the cells' volumetric term, any Poisson's ratio) against
continuum references: ``python -m studies.tissue_accuracy [--quick] [--across 9,17]``.

Three checks, each on the lattice at the body's Poisson's ratio and, beside it, the springs-only
lattice of nu = 1/4 (``cells=None``: what deformgl was before), and a fourth table:

* **cantilever** (small strain): the 1 x 0.1 x 0.1 m cantilever of :mod:`deformgl.bench.fem`
  (clamped at x = 0, its own weight), the area mean of the end face's sag over
  ``rho g L^4 / (E w^2)``, by the linearised lattice's static solve
  (:func:`deformgl.bench.fem.static_displacement`), against the locking-free mixed Q2/Q1 FEM of
  :func:`studies.fem_tissue.mixed_cantilever_study` at the same nu (:data:`CANTILEVER_FEM`).
* **column** (small strain): a 2 cm cube clamped at its bottom face under a uniform pressure on
  its top face; its lateral strain (the mean u_x of the face x = +side/2 over the band 0.4 to 0.6
  of the height, the lattice's displacement taken piecewise linear between nodes as its
  trilinear cells are, over side/2) over its axial strain (the top face's mean -u_y over the
  height), against :func:`studies.fem_tissue.column_study` (:data:`COLUMN_FEM`).
* **large deflection**: the 0.2 x 0.02 x 0.02 m cantilever (rho = 1000 kg/m^3) at E = 500 kPa
  and 50 kPa, the end face's centre node displacement (u_x, u_y) at the static equilibrium of
  the nonlinear lattice (:func:`static_equilibrium`), against the inextensible elastica
  (:func:`studies.fem_tissue.elastica_tip`) and the neo-Hookean FEM
  (:func:`studies.fem_nonlinear.neo_hookean_cantilever_tip`, :data:`NEO_HOOKEAN_FEM`).
* **the plan's errors at nu** (:func:`workload_errors`): ``studies.accuracy``'s block in
  compression and bar in torsion at nu 0.3, 0.45, 0.49, the lattice against the displacement FEM
  computed here (the ``fem`` extra; without it the table is skipped with a line saying so):
  :data:`deformgl.plan.planner.MEASURED_NU`.

The FEM values of the three checks are stored (computing them takes minutes and the ``fem`` extra; ``python -m
studies.fem_tissue`` prints them, ``tests/test_fem_tissue.py`` checks the stored ones
against a fresh coarse solve) so that the lattice side runs with SciPy alone.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from deformgl.bench.fem import (MATERIAL, WORKLOADS, _dissection, _trapezoid, face_weights, lattice_case,
                                lattice_value, require_skfem, static_displacement)
from deformgl.errors import DeformglError
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.implicit import assemble
from deformgl.sim.materials import ElasticMaterial, lattice_system
from deformgl.sim.springs import SpringSystem, forces

__all__ = ["CANTILEVER_FEM", "COLUMN_FEM", "ELASTICA", "NEO_HOOKEAN_FEM", "cantilever_sag_ratio", "workload_errors",
           "column_ratio", "static_equilibrium", "large_deflection_tip", "main"]

G = 9.81
#: Mixed Q2/Q1 FEM, the aspect-10 clamped cantilever under its weight: end-face mean sag over
#: rho g L^4 / (E w^2), by nu (Richardson-extrapolated from 2, 4, 8 elements across, +-0.05 %;
#: ``python -m studies.fem_tissue``, table 1).
CANTILEVER_FEM = {0.25: 1.50581, 0.3: 1.50224, 0.45: 1.48561, 0.49: 1.47930}
#: Mixed Q2/Q1 FEM, the clamped cube column under a top pressure: lateral over axial strain, by
#: nu (extrapolated from 4, 8, 16 elements across, +-0.05 %; ``fem_tissue`` table 2).
COLUMN_FEM = {0.3: 0.30501, 0.45: 0.48334, 0.49: 0.53700}
#: The inextensible elastica of the 0.2 x 0.02 x 0.02 m cantilever, rho = 1000 kg/m^3: tip
#: (u_x, u_y) in m by E in Pa (``fem_tissue`` table 3).
ELASTICA = {5.0e5: (-0.028131, -0.095344), 5.0e4: (-0.149047, -0.180917)}
#: The neo-Hookean mixed FEM (Bonet & Wood 2008, eq. 6.27) of the same cantilever: the end
#: face's centre (u_x, u_y) in m by (E, nu) (4 elements across, within 0.2 % of 2 across;
#: ``fem_tissue`` table 4).
NEO_HOOKEAN_FEM = {(5.0e5, 0.25): (-0.028174, -0.096188), (5.0e5, 0.45): (-0.027656, -0.095341),
                   (5.0e4, 0.25): (-0.151227, -0.187638), (5.0e4, 0.45): (-0.151024, -0.187826)}


def _material(nu: float) -> ElasticMaterial:
    return dataclasses.replace(MATERIAL, poissons_ratio=nu)


def _without_cells(system: SpringSystem, cells: bool) -> SpringSystem:
    return system if cells else dataclasses.replace(system, cells=None)


def cantilever_sag_ratio(across: int, nu: float, *, cells: bool = True) -> float:
    """The lattice cantilever's normalised sag over the mixed FEM's at ``nu`` (``cells`` False:
    the springs-only lattice of nu = 1/4 of the same E)."""
    case = lattice_case(WORKLOADS["cantilever"], across, _material(nu if cells else 0.25))
    case = dataclasses.replace(case, system=_without_cells(case.system, cells))
    size = WORKLOADS["cantilever"].size
    scale = MATERIAL.density * G * size[0] ** 4 / (MATERIAL.youngs_modulus * size[1] ** 2)
    # by multigrid CG: the cells' nearly incompressible blocks defeat the aggregation AMG would try
    # first, and at 17 across the direct solve took 30 s a case
    u = static_displacement(case.system, case.forces, method="multigrid")
    return lattice_value(case, u) / scale / CANTILEVER_FEM[nu]


def column_ratio(across: int, nu: float, *, cells: bool = True, side: float = 0.02,
                 pressure: float = 1.0e3) -> tuple[float, float, float]:
    """The lattice column's (axial strain, lateral strain, lateral / axial), see the module
    docstring (``cells`` False: the springs-only lattice of nu = 1/4 of the same E)."""
    h = side / (across - 1)
    grid = NodeGrid(np.zeros(3), h, np.ones((across,) * 3, bool))
    ijk = grid.ijk.astype(np.int64)
    system, _ = lattice_system(grid, _material(nu if cells else 0.25), fixed=ijk[:, 1] == 0, gravity=(0.0, 0.0, 0.0))
    f = np.zeros((grid.count, 3))
    top, area = face_weights(grid, 1, 1)
    f[top, 1] -= pressure * area
    u = static_displacement(_without_cells(system, cells), f, method="direct")
    axial = -float((area * u[top, 1]).sum() / area.sum()) / side
    wz = _trapezoid(across, h)
    face = ijk[:, 0] == across - 1
    profile = np.zeros(across)
    for j in range(across):
        row = face & (ijk[:, 1] == j)
        profile[j] = float((wz[ijk[row, 2]] * u[row, 0]).sum() / wz.sum())
    ys = np.linspace(0.0, side, across)
    band = np.linspace(0.4 * side, 0.6 * side, 401)
    values = np.interp(band, ys, profile)
    mean = float(((values[1:] + values[:-1]) * 0.5).mean())  # trapezoid over equal steps
    lateral = mean / (side / 2)
    return axial, lateral, lateral / axial


def _dof_order(system: SpringSystem) -> np.ndarray | None:
    """The free unknowns in the nested-dissection order of their grid nodes (None without a grid)."""
    if system.grid is None:
        return None
    ijk = system.grid.ijk[~system.fixed].astype(np.int64)
    nodes = np.concatenate(_dissection(ijk, np.arange(len(ijk))))
    return (3 * nodes[:, None] + np.arange(3)).ravel()


def _solve(a: sp.spmatrix, b: np.ndarray, order: np.ndarray | None) -> np.ndarray:
    """``a x = b`` by SuperLU, on the nested-dissection order where there is one (half the time
    of its own column ordering on the 9-across cantilever's 19,000 unknowns)."""
    if order is None:
        return np.asarray(spla.spsolve(a.tocsc(), b))
    x = np.empty_like(b)
    x[order] = spla.splu(a.tocsr()[order][:, order].tocsc(), permc_spec="NATURAL",
                         options={"SymmetricMode": True}).solve(b[order])
    return x


def static_equilibrium(system: SpringSystem, *, increments: int = 8, tolerance: float = 1e-7,
                       max_iterations: int = 200) -> np.ndarray:
    """Node positions (N, 3) in m at the static equilibrium of the nonlinear lattice (springs and
    cells) under its gravity, by Newton's method with the full Hessian (the springs' and cells'
    ``"full"`` geometric terms, :func:`deformgl.sim.implicit.assemble` with v = 0 and a step of
    1e3 s, whose mass term M / dt^2 only regularises), the gravity applied in ``increments``
    equal steps, Newton steps of at most 2h per node (h/2 took twice the steps to the same
    equilibrium; halved where a step would make a force non-finite). Converged when the largest
    free node's force is below ``tolerance`` times its largest weight (m g).

    Raises:
        DeformglError: an increment did not converge.
    """
    dt = 1.0e3
    x = system.rest_positions.astype(np.float64).copy()
    v = np.zeros_like(x)
    gravity = np.asarray(system.gravity, np.float64)
    free = ~system.fixed
    scale = float(np.max(system.mass) * np.linalg.norm(gravity))
    step_cap = 2.0 * system.spacing if system.spacing else np.inf  # no node moves more than 2h a step

    def residual(s: SpringSystem, y: np.ndarray) -> float:
        return float(np.abs(forces(s, y, v, 0.0)[free]).max())

    order = _dof_order(system)
    for k in range(1, increments + 1):
        s = dataclasses.replace(system, gravity=gravity * k / increments)
        r = residual(s, x)
        for _ in range(max_iterations):
            if r < tolerance * scale:
                break
            lin = assemble(s, x, v, 0.0, dt, geometric="full")
            dx = dt * _solve(lin.matrix, lin.rhs, order).reshape(-1, 3)
            alpha = min(1.0, step_cap / max(float(np.abs(dx).max()), 1e-300))
            while True:  # full Newton steps (the residual may grow first); halved only to stay finite
                y = x.copy()
                y[free] += alpha * dx
                ry = residual(s, y)
                if np.isfinite(ry) or alpha < 1e-3:
                    break
                alpha *= 0.5
            x, r = y, ry
        else:
            raise DeformglError(f"static equilibrium: increment {k} of {increments} did not converge "
                                f"(largest force {r / scale:.1e} of the largest weight)")
    return x


def large_deflection_tip(across: int, youngs_modulus: float, nu: float, *, cells: bool = True,
                         increments: int = 8) -> tuple[float, float]:
    """The 0.2 x 0.02 x 0.02 m cantilever's end-face centre displacement (u_x, u_y) in m at
    static equilibrium (``across`` odd: a node at the centre)."""
    if across % 2 == 0:
        raise ValueError(f"large_deflection_tip: across must be odd (a centre node), got {across}")
    h = 0.02 / (across - 1)
    grid = NodeGrid(np.array([0.0, -0.01, -0.01]), h, np.ones((int(round(0.2 / h)) + 1, across, across), bool))
    ijk = grid.ijk.astype(np.int64)
    material = ElasticMaterial(youngs_modulus, 1000.0, poissons_ratio=nu)
    system, _ = lattice_system(grid, material, fixed=ijk[:, 0] == 0, gravity=(0.0, -G, 0.0))
    x = static_equilibrium(_without_cells(system, cells), increments=increments)
    mid = (across - 1) // 2
    tip = np.flatnonzero((ijk[:, 0] == ijk[:, 0].max()) & (ijk[:, 1] == mid) & (ijk[:, 2] == mid))[0]
    u = x[tip] - grid.rest_positions[tip]
    return float(u[0]), float(u[1])


@dataclass(frozen=True)
class TipRow:
    """One large-deflection run: the lattice's tip and its relative errors against a reference."""

    youngs_modulus: float
    nu: float
    cells: bool
    across: int
    tip: tuple[float, float]
    reference: str
    error: tuple[float, float]
    seconds: float


def tip_row(across: int, youngs_modulus: float, nu: float, *, cells: bool = True,
            reference: str | None = None) -> TipRow:
    """The tip against ``reference``: "elastica" (:data:`ELASTICA`) or "neo-Hookean FEM"
    (:data:`NEO_HOOKEAN_FEM`); default the elastica at E = 500 kPa, the FEM at 50 kPa."""
    start = time.perf_counter()
    tip = large_deflection_tip(across, youngs_modulus, nu, cells=cells)
    name = reference or ("elastica" if youngs_modulus >= 5.0e5 else "neo-Hookean FEM")
    if name == "elastica":
        ref = ELASTICA[youngs_modulus]
    elif name == "neo-Hookean FEM":
        ref = NEO_HOOKEAN_FEM[(youngs_modulus, nu)]
    else:
        raise ValueError(f"tip_row: reference must be 'elastica' or 'neo-Hookean FEM', got {reference!r}")
    error = (tip[0] / ref[0] - 1.0, tip[1] / ref[1] - 1.0)
    return TipRow(youngs_modulus, nu, cells, across, tip, name, error, time.perf_counter() - start)


def workload_errors(name: str, nu: float, across: Sequence[int]) -> tuple[float, dict[int, float]]:
    """``studies.accuracy``'s workload ``name`` ("block" or "twist") at Poisson's ratio ``nu``: the
    displacement FEM's estimated relative error, and the lattice's |lattice / FEM - 1| (springs and
    cells at ``nu``) at each of ``across`` (:data:`deformgl.plan.planner.MEASURED_NU` holds them at 5,
    9 and 17). Needs the 'fem' extra."""
    from studies.accuracy import FEM_MESHES
    from deformgl.bench.fem import fem_reference

    w = WORKLOADS[name]
    value, estimate, _ = fem_reference(w, FEM_MESHES[name], nu=nu)
    return estimate, {n: abs(lattice_value(lattice_case(w, n, _material(nu))) / value - 1.0) for n in across}


def _errors(tip: tuple[float, float], ref: tuple[float, float]) -> str:
    return f"u_x {100 * (tip[0] / ref[0] - 1.0):+.2f} %, u_y {100 * (tip[1] / ref[1] - 1.0):+.2f} %"


def main(argv: list[str] | None = None) -> int:
    """Print the four tables."""
    parser = argparse.ArgumentParser(prog="python -m studies.tissue_accuracy",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="9 nodes across only (3 and 5 too in table 4)")
    parser.add_argument("--across", default=None, help="nodes across, comma separated (default 9,17; table 3 "
                        "at those up to 9 only)")
    args = parser.parse_args(argv)
    across = [int(a) for a in args.across.split(",")] if args.across else ([9] if args.quick else [9, 17])
    print(f"NumPy/SciPy float64 on {sys.platform}; ratios lattice / FEM (1 = exact)")
    print("\n1. Cantilever 1 x 0.1 x 0.1 m, clamped, own weight: end-face mean sag / mixed Q2/Q1 FEM")
    print(f"  {'nu':>5} {'across':>6} | {'springs+cells':>13} {'nu=1/4 springs':>14}")
    for n in across:
        for nu in CANTILEVER_FEM:
            print(f"  {nu:>5.2f} {n:>6} | {cantilever_sag_ratio(n, nu):>13.4f} "
                  f"{cantilever_sag_ratio(n, nu, cells=False):>13.4f}",
                  flush=True)
    print("\n2. Cube column 2 cm, bottom clamped, top pressure: (lateral / axial strain) / mixed FEM")
    print(f"  {'nu':>5} {'across':>6} | {'FEM':>7} {'springs+cells':>13} {'nu=1/4 springs':>14}")
    for n in across:
        for nu, ref in COLUMN_FEM.items():
            print(f"  {nu:>5.2f} {n:>6} | {ref:>7.4f} {column_ratio(n, nu)[2] / ref:>13.4f} "
                  f"{column_ratio(n, nu, cells=False)[2] / ref:>14.4f}", flush=True)
    tip_across = [n for n in across if n <= 9]  # (Newton on the nonlinear lattice: minutes at 9 across)
    if tip_across:
        print("\n3. Cantilever 0.2 x 0.02 x 0.02 m, rho 1000 kg/m^3, static equilibrium: end-face centre "
              "(u_x, u_y) in m and its relative error")
    for n in tip_across:
        for e, nu, cells in ((5.0e5, 0.25, True), (5.0e5, 0.45, True), (5.0e4, 0.25, True), (5.0e4, 0.45, True),
                             (5.0e4, 0.25, False)):
            r = tip_row(n, e, nu, cells=cells)
            print(f"  E={e:>8.0f} nu={nu:<4} {'cells' if cells else 'springs':<7} {n:>2} across: "
                  f"({r.tip[0]:+.6f}, {r.tip[1]:+.6f}); elastica {_errors(r.tip, ELASTICA[e])}; "
                  f"neo-Hookean FEM {_errors(r.tip, NEO_HOOKEAN_FEM[(e, nu)])}  [{r.seconds:.1f} s]", flush=True)
    print("\n4. studies.accuracy's block (compression) and bar (torsion) at the body's nu: |lattice / FEM - 1| "
          "(displacement Q2 FEM at that nu, Richardson-extrapolated; the plan's MEASURED_NU)")
    try:
        require_skfem()
    except DeformglError as missing:
        print(f"  skipped: {missing}")
        return 0
    for name in ("block", "twist"):
        for nu in (0.3, 0.45, 0.49):
            estimate, errors = workload_errors(name, nu, sorted({3, 5, *across}))
            cols = "  ".join(f"{n} across {e:.4f}" for n, e in errors.items())
            print(f"  {name:>5} nu={nu:<4} FEM est. error {estimate:.1e} | {cols}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
