"""``python -m studies.xpbd_hierarchy``: does the grid hierarchy pay for XPBD? (issue 29, item 6)

Hierarchical XPBD in the manner of Müller 2008 ("Hierarchical Position Based Dynamics", section 4):
each substep, after the prediction, the same body's constraints on the coarser lattices (the
calibrated lattice rediscretised at 2h, 4h, ..., :func:`deformgl.sim.materials.lattice_system` of
the coarse grid: its springs, its masses) are projected first, coarsest first, from the fine
prediction injected into the level (the coarse nodes are every other fine node); each level's
correction is prolongated trilinearly to the level above and added to its injected start, and
the fine level's Jacobi sweeps (:class:`deformgl.sim.xpbd.XpbdSolver`'s sweep, the same formula)
finish. Float64, springs only (nu = 1/4, the stiff block of ``bench trade --stiff``: E = 1 MPa,
0.1 m, clamped at its base, Rayleigh mass damping 20/s), one substep per step of dt = 1/60 s.

Measured per configuration: the largest node distance from the lattice's equilibrium after
:data:`SIM_TIME` s, relative to the equilibrium's largest sag, and the cost in sweeps: fine-level
sweeps plus every coarse sweep (each a pass on the GPU: the fixed cost of a pass dominates
llvmpipe, docs/PERFORMANCE.md "Pricing the plan") and in fine-sweep equivalents (a coarse sweep
weighed by its node count). Plain XPBD at the same budgets is the baseline. The prolongation is
the multigrid's (:func:`deformgl.sim.multigrid.prolongation`).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from deformgl.bench.trade_stiff import block_system
from deformgl.sim.multigrid import prolongation
from deformgl.sim.springs import SpringSystem
from deformgl.sim.xpbd import OMEGA, node_terms

__all__ = ["SIM_TIME", "BUDGETS", "Level", "levels", "run", "HierarchyRow", "rows", "format_rows", "main"]

SIM_TIME = 1.0
DT = 1.0 / 60.0


@dataclass(frozen=True)
class Level:
    """One level: its springs, inverse masses, fine-node index of each of its nodes, and the
    prolongation from the level below it (None on the coarsest)."""

    system: SpringSystem
    inject: np.ndarray                  # (N_l,) index into the level above of each node (finest: arange)
    prolong: sp.csr_matrix | None       # (N_l, N_{l+1}) from the next coarser level


def levels(across: int, depth: int) -> list[Level]:
    """The block at ``across`` (odd) and ``depth`` coarser lattices of it (finest first)."""
    out: list[Level] = []
    n = across
    system = block_system(n)
    for level in range(depth + 1):
        coarse_n = (n + 1) // 2
        prolong = None
        if level < depth:
            box = np.ones((n, n, n), bool)
            p, _ = prolongation(box, np.argwhere(box))
            prolong = sp.csr_matrix(p)
        inject = np.arange(system.count)
        if out:
            fine_n = 2 * n - 1
            ijk = np.argwhere(np.ones((n, n, n), bool)) * 2
            inject = (ijk[:, 0] * fine_n + ijk[:, 1]) * fine_n + ijk[:, 2]
        out.append(Level(system, inject, prolong))
        if level < depth:
            n = coarse_n
            system = block_system(n)
    return out


def _sweeps(system: SpringSystem, p: np.ndarray, xn: np.ndarray, h: float, iterations: int) -> np.ndarray:
    """``iterations`` Jacobi XPBD sweeps of ``system``'s springs from p (x^n = xn), as
    :meth:`deformgl.sim.xpbd.XpbdSolver.substep` (springs only)."""
    from deformgl.sim.xpbd import constraint_counts

    w, _ = node_terms(system)
    live = system.stiffness > 0
    i, j, k, rest = system.i[live], system.j[live], system.stiffness[live], system.rest_length[live]
    counts = constraint_counts(system)
    count = np.maximum(counts[i], counts[j])
    ratio = system.damping[live] / k
    at, gs = 1.0 / (k * h * h), ratio / h
    lam = np.zeros(len(k))
    fixed = system.fixed[:, None]
    wi, wj = w[i], w[j]
    for _ in range(iterations):
        d = p[i] - p[j]
        length = np.linalg.norm(d, axis=1)
        u = d / np.where(length > 0, length, 1.0)[:, None]
        moved = np.einsum("sk,sk->s", u, (p[i] - xn[i]) - (p[j] - xn[j]))
        dl = -OMEGA * (length - rest + at * lam + gs * moved) / ((1.0 + gs) * count * (wi + wj) + at)
        lam += dl
        dx = np.zeros_like(p)
        np.add.at(dx, i, (wi * dl)[:, None] * u)
        np.add.at(dx, j, -(wj * dl)[:, None] * u)
        p = np.where(fixed, xn, p + dx)
    return p


def run(hierarchy: list[Level], fine_iterations: int, coarse_iterations: int, sim_time: float = SIM_TIME,
        dt: float = DT) -> np.ndarray:
    """The fine positions after ``sim_time`` of hierarchical XPBD (``coarse_iterations`` sweeps on
    every coarse level; 0: plain XPBD)."""
    fine = hierarchy[0].system
    x = fine.rest_positions.astype(np.float64).copy()
    v = np.zeros_like(x)
    w, g = node_terms(fine)
    fixed = fine.fixed[:, None]
    # injection from the finest level into each level: compose the per-level indices
    index = [np.arange(fine.count)]
    for level in hierarchy[1:]:
        index.append(index[-1][level.inject])
    for _ in range(round(sim_time / dt)):
        v_star = v / (1.0 + dt * g)[:, None] + dt * fine.gravity
        xn = x
        p = np.where(fixed, x, x + dt * v_star)
        if coarse_iterations and len(hierarchy) > 1:
            correction = None
            for depth in range(len(hierarchy) - 1, 0, -1):
                level = hierarchy[depth]
                start = p[index[depth]]
                if correction is not None:
                    start = start + correction
                start = np.where(level.system.fixed[:, None], xn[index[depth]], start)
                moved = _sweeps(level.system, start, xn[index[depth]], dt, coarse_iterations)
                delta = moved - p[index[depth]]
                correction = hierarchy[depth - 1].prolong @ delta
            assert correction is not None
            p = np.where(fixed, xn, p + correction)
        p = _sweeps(fine, p, xn, dt, fine_iterations)
        v = np.where(fixed, 0.0, (p - xn) / dt)
        x = p
    return x


@dataclass(frozen=True)
class HierarchyRow:
    across: int
    depth: int               # coarse levels used (0: plain XPBD)
    fine_iterations: int
    coarse_iterations: int
    sweeps: int              # passes per step: fine + coarse sweeps
    fine_equivalents: float  # coarse sweeps weighed by their node count
    error: float             # largest node distance from the equilibrium / its largest sag
    seconds: float           # float64 wall time of the run (NumPy, for orientation)


#: (fine, coarse) sweeps a step of the full table.
BUDGETS = ((10, 0), (30, 0), (100, 0), (300, 0), (10, 10), (10, 30), (30, 30), (30, 100), (100, 100))


def rows(across: int = 17, depth: int = 2, budgets: tuple[tuple[int, int], ...] = BUDGETS) -> list[HierarchyRow]:
    """Plain XPBD and hierarchical XPBD on the block at ``across`` (``budgets``: (fine, coarse)
    sweeps a step), against its equilibrium (``bench trade --stiff``'s static)."""
    from deformgl.bench.trade_stiff import stiff_cases

    case = stiff_cases(cases=((1.0e6, across),))[0]
    sag = case.sag * case.spacing
    hierarchy = levels(across, depth)
    counts = [lv.system.count for lv in hierarchy]
    out = []
    for fine_its, coarse_its in budgets:
        start = time.perf_counter()
        x = run(hierarchy, fine_its, coarse_its)
        used = depth if coarse_its else 0
        error = float(np.linalg.norm(x - case.static, axis=1).max()) / sag
        out.append(HierarchyRow(across, used, fine_its, coarse_its, fine_its + used * coarse_its,
                                fine_its + coarse_its * sum(counts[1:used + 1]) / counts[0], error,
                                time.perf_counter() - start))
    return out


def format_rows(out: list[HierarchyRow]) -> str:
    lines = ["XPBD on the 1 MPa block (dt 1/60 s, 1 substep, float64, springs at nu = 1/4): the largest node "
             f"distance from the equilibrium after {SIM_TIME:g} s / its largest sag",
             f"{'across':>6} {'levels':>6} {'fine it':>7} {'coarse it':>9} {'sweeps':>6} {'fine-equiv.':>11} "
             f"{'error/sag':>10}"]
    for r in out:
        lines.append(f"{r.across:>6} {r.depth + 1:>6} {r.fine_iterations:>7} {r.coarse_iterations or '-':>9} "
                     f"{r.sweeps:>6} {r.fine_equivalents:>11.4g} {r.error:>10.3g}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies.xpbd_hierarchy", description=__doc__.split("\n\n")[0])
    parser.add_argument("--across", default="9,17", help="nodes across the block, odd, comma-separated (default 9,17)")
    parser.add_argument("--quick", action="store_true", help="9 across, two budgets (the tests' smoke run)")
    args = parser.parse_args(argv)
    if args.quick:
        print(format_rows(rows(9, 2, ((30, 0), (10, 20)))))
        return 0
    out = []
    for n in (int(a) for a in args.across.split(",")):
        if n < 5 or n % 2 == 0:
            parser.error(f"--across: odd node counts of at least 5 (every other node is a coarse node), got {n}")
        out += rows(n, 2)
    print(format_rows(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
