"""The sheet's bending term (:mod:`deformgl.sim.terms.bending`) against the analytic plate:
``python -m studies.cloth_bending`` prints docs/ACCURACY.md's "Cloth bending" tables.

Every check is a flat sheet of :class:`~deformgl.sim.materials.SheetMaterial` with a plate
bending stiffness D (N·m), in NumPy/SciPy float64:

1. the simply supported square plate under uniform pressure q, its centre deflection against
   Navier's double series (Timoshenko & Woinowsky-Krieger 1959, section 30, eq. 138:
   ``w = 0.00406 q a^4 / D``): the border nodes held (w = 0, free to rotate), a linear solve of
   the out-of-plane problem ``B w = q A_n`` (a flat membrane has no first-order stiffness out
   of its plane, so B alone carries the load);
2. the twisted plate: a square plate held at three corners and pulled by P at the fourth, whose
   exact solution is the pure twist ``w = P x y / (2 D (1 - nu))`` (Timoshenko &
   Woinowsky-Krieger 1959, section 11): the lattice's twist stencil reproduces it exactly;
3. the cantilever strip under uniform load: ``q L^4 / (8 D (1 - nu^2))`` (its free edges carry no
   moment, so it curls anticlastically and bends as a narrow plate, ``E t^3 / 12`` per width); the
   clamp is two fixed node columns, which act at their midpoint, so L runs from there (L + h/2
   from the second column); two nodes wide and, 0.1 m wide, at 3 to 17 nodes across;
4. large deflection: the same strip, inextensible (a stiff membrane), under its own weight by
   Newton's method on the full nonlinear sheet (:func:`studies.tissue_accuracy.static_equilibrium`),
   its tip against the heavy elastica (:func:`studies.fem_tissue.elastica_tip`) of rigidity
   ``D (1 - nu^2)`` at ``rho_A g L^3 / D`` = 5 and 30 (a tip sag of about half and 0.9 of the length).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
import scipy.sparse.linalg as spla

from deformgl.grid.nodes import NodeGrid
from deformgl.sim.terms.bending import SHEET_BENDING_POISSON, node_weights, sheet_bending
from deformgl.sim.materials import SheetMaterial, sheet_system

__all__ = ["elastica_errors", "navier_centre", "plate_ratio", "strip_ratio", "twisted_plate_ratio"]

G = 9.81


def navier_centre(terms: int = 201) -> float:
    """The simply supported square plate's centre deflection under uniform pressure, in units of
    ``q a^4 / D``: Navier's series ``16 / pi^6 sum_{m,n odd} (-1)^((m+n)/2 - 1) / (m n (m^2 + n^2)^2)``
    (0.00406235)."""
    odd = np.arange(1, terms + 1, 2, dtype=np.float64)
    m, n = np.meshgrid(odd, odd)
    sign = (-1.0) ** ((m + n) / 2.0 - 1.0)
    return float(16.0 / math.pi ** 6 * np.sum(sign / (m * n * (m * m + n * n) ** 2)))


def _square(n: int, side: float = 1.0) -> NodeGrid:
    return NodeGrid(np.zeros(3), side / (n - 1), np.ones((n, 1, n), bool))


def _solve(grid: NodeGrid, stiffness: float, free: np.ndarray, load: np.ndarray) -> np.ndarray:
    """Out-of-plane displacement (N,) of the free nodes under nodal forces ``load`` (N,), N."""
    b = sheet_bending(grid, stiffness).matrix.tocsr()
    w = np.zeros(grid.count)
    w[free] = spla.spsolve(b[free][:, free].tocsc(), load[free])
    return w


def _node_areas(grid: NodeGrid) -> np.ndarray:
    """(N,) each node's share of the sheet's area in m^2 (a quarter of each full cell at it)."""
    return node_weights(grid, (0, 2))[0] * grid.spacing ** 2


def plate_ratio(n: int) -> float:
    """Simply supported square plate, ``n`` nodes across: centre deflection / Navier's (n odd)."""
    grid = _square(n)
    i, k = grid.ijk[:, 0], grid.ijk[:, 2]
    free = (i > 0) & (i < n - 1) & (k > 0) & (k < n - 1)
    w = _solve(grid, 1.0, free, _node_areas(grid))
    centre = np.flatnonzero((i == n // 2) & (k == n // 2))[0]
    return float(w[centre] / navier_centre())


def twisted_plate_ratio(n: int) -> float:
    """Square plate held at three corners, P at the fourth: its deflection / ``P a^2 / (2 D (1 - nu))``."""
    grid = _square(n)
    i, k = grid.ijk[:, 0], grid.ijk[:, 2]
    corner = {(a, b): int(np.flatnonzero((i == a) & (k == b))[0]) for a in (0, n - 1) for b in (0, n - 1)}
    free = np.ones(grid.count, bool)
    free[[corner[0, 0], corner[n - 1, 0], corner[0, n - 1]]] = False
    load = np.zeros(grid.count)
    load[corner[n - 1, n - 1]] = 1.0
    w = _solve(grid, 1.0, free, load)
    return float(w[corner[n - 1, n - 1]] / (1.0 / (2.0 * (1.0 - SHEET_BENDING_POISSON))))


def _strip(n: int, length: float, across: int = 2) -> NodeGrid:
    """A strip ``across`` nodes wide: ``n`` nodes from x = 0 to ``length`` and a clamp column at x = -h."""
    h = length / (n - 1)
    return NodeGrid(np.array([-h, 0.0, 0.0]), h, np.ones((n + 1, 1, across), bool))


#: a free strip's rigidity per width over D: its edges carry no moment, so it curls
#: anticlastically (k_across = -nu k_along) and bends as a narrow plate, D (1 - nu^2) = E t^3 / 12
STRIP_RIGIDITY = 1.0 - SHEET_BENDING_POISSON ** 2


def strip_ratio(n: int, across: int = 2) -> float:
    """Cantilever strip ``across`` nodes wide, ``n`` nodes along 1 m, uniform load: tip deflection
    / ``q L^4 / (8 D (1 - nu^2))`` with L from the clamp's midpoint (1 + h/2)."""
    grid = _strip(n, 1.0, across)
    free = grid.ijk[:, 0] >= 2
    w = _solve(grid, 1.0, free, _node_areas(grid))
    tip = grid.ijk[:, 0] == n
    effective = 1.0 + grid.spacing / 2.0
    return float(w[tip].mean() / (effective ** 4 / (8.0 * STRIP_RIGIDITY)))  # q = 1 Pa, D = 1 N m


def elastica_errors(n: int, load: float, *, length: float = 0.2, areal_density: float = 0.2) -> tuple[float, float]:
    """The inextensible strip of ``n`` nodes along ``length`` under its weight at ``rho_A g L^3 / D
    = load``: its tip's (u_x, u_y) relative to the heavy elastica's (L from the clamp's midpoint)."""
    from studies.fem_tissue import elastica_tip
    from studies.tissue_accuracy import static_equilibrium

    stiffness = areal_density * G * length ** 3 / load
    grid = _strip(n, length)
    material = SheetMaterial(1.0e4, areal_density, bending_stiffness=stiffness)
    system, _ = sheet_system(grid, material, fixed=grid.ijk[:, 0] <= 1, gravity=(0.0, -G, 0.0))
    x = static_equilibrium(system, increments=8)
    tip = grid.ijk[:, 0] == n
    u = (x[tip] - grid.rest_positions[tip]).mean(axis=0)
    # elastica_tip takes a beam of E and a square section: E w^4 / 12 = D (1 - nu^2) and rho w^2 = rho_A at w = 1
    ref = elastica_tip(length + grid.spacing / 2.0, 1.0, 12.0 * STRIP_RIGIDITY * stiffness, areal_density, G)
    return float(u[0] / ref[0] - 1.0), float(u[1] / ref[1] - 1.0)


def main(argv: list[str] | None = None) -> int:
    """Print the four tables."""
    parser = argparse.ArgumentParser(prog="python -m studies.cloth_bending",
                                     description=__doc__.split("\n\n")[0])
    parser.parse_args(argv)
    print("NumPy/SciPy float64; lattice / analytic (1 = exact)")
    print(f"\n1. Simply supported square plate, uniform pressure: centre deflection / Navier "
          f"({navier_centre():.8f} q a^4 / D)")
    for n in (5, 9, 17, 33):
        print(f"  {n:>3} across: {plate_ratio(n):.5f}")
    print(f"\n2. Twisted plate (three corners held, P at the fourth): / (P a^2 / (2 D (1 - nu))), "
          f"nu = {SHEET_BENDING_POISSON:.4f}")
    for n in (3, 9, 17):
        print(f"  {n:>3} across: {twisted_plate_ratio(n):.12f}")
    print("\n3. Cantilever strip, uniform load: tip / (q L^4 / (8 D (1 - nu^2))), the free strip's rigidity")
    for n in (9, 17, 33, 65):
        print(f"  2 across, {n:>3} along: {strip_ratio(n):.5f}")
    for across in (3, 5, 9, 17):  # 0.1 m wide, 1 m long: the clamp holds the curl near the root
        print(f"  {across:>2} across (0.1 m), {10 * (across - 1) + 1:>3} along: {strip_ratio(10 * (across - 1) + 1, across):.5f}")
    print("\n4. Inextensible strip under its weight, static equilibrium: tip (u_x, u_y) / heavy elastica - 1")
    for load in (5.0, 30.0):
        for n in (11, 21, 41):
            start = time.perf_counter()
            ex, ey = elastica_errors(n, load)
            print(f"  rho_A g L^3 / D = {load:>4.0f}, {n:>3} along: u_x {100 * ex:+.3f} %, u_y {100 * ey:+.3f} %"
                  f"  [{time.perf_counter() - start:.1f} s]", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
