"""What the cells' volumetric term costs per step: ``python -m studies.cells_cost --poisson 0.45[,0.49]``.

The same lattice block (E = 10 kPa, rho = 1000 kg/m^3, top layer fixed) on the fragment backend
at nu = 1/4 (the baseline: the springs and the cells' corner barrier, what every scene without a
``poissons_ratio`` runs), at each requested nu (springs, the centre term and the barrier) and with
the springs alone (``cells=None``: deformgl before the term), for position Verlet (the
foundation pass) and semi-implicit Euler (the integrator pass). Rounds alternate the variants in
one process; each round's ms per step and ratio to that round's baseline are kept, and the table
prints the median ratio with its spread (lowest to highest over the rounds).

:func:`cg_iterations` adds what the term costs implicit Euler: the conjugate-gradient iterations
per step (NumPy reference, Jacobi preconditioner, relative tolerance 1e-4, 30 steps of 1/60 s under
gravity from rest) on the same block at 9 nodes across, by nu.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from collections.abc import Sequence
from dataclasses import dataclass

import moderngl
import numpy as np

from deformgl.grid.nodes import NodeGrid
from deformgl.sim.materials import ElasticMaterial, lattice_system
from deformgl import make_simulation
from deformgl.sim.springs import SpringSystem, max_angular_frequency

__all__ = ["COST_GRIDS", "CostRow", "bench_poisson", "cost_rows", "format_poisson", "cg_iterations"]

#: Grids (nodes along x, y, z) of the cost table.
COST_GRIDS = ((27, 27, 27), (64, 64, 32))
INTEGRATORS = ("verlet", "semi-implicit")


@dataclass(frozen=True)
class CostRow:
    """One grid and integrator: the variant's name, its median ms per step, and its ratio to the
    nu = 1/4 baseline (median, lowest, highest over the rounds)."""

    grid: str
    nodes: int
    integrator: str
    variant: str
    ms: float
    ratio: tuple[float, float, float]


def _system(shape: tuple[int, int, int], nu: float, cells: bool) -> SpringSystem:
    grid = NodeGrid(np.zeros(3), 0.01, np.ones(shape, bool))
    material = ElasticMaterial(1.0e4, 1000.0, mass_damping=1.0, poissons_ratio=nu)
    system, _ = lattice_system(grid, material, fixed=grid.ijk[:, 1] == shape[1] - 1)
    return system if cells else dataclasses.replace(system, cells=None)


def bench_poisson(ctx: moderngl.Context, nus: Sequence[float], *, steps: int = 40, rounds: int = 7,
                  grids: Sequence[tuple[int, int, int]] = COST_GRIDS) -> list[CostRow]:
    """The table's rows (see the module docstring)."""
    rows = []
    for shape in grids:
        variants = {"nu=0.25": (0.25, True), **{f"nu={nu:g}": (nu, True) for nu in nus if nu != 0.25},
                    "springs only": (0.25, False)}
        systems = {name: _system(shape, nu, on) for name, (nu, on) in variants.items()}
        # one dt for all (the stiffest's half limit), so each variant does the same work per step
        dt = 0.5 * min(2.0 / max_angular_frequency(s).omega for s in systems.values())
        for integrator in INTEGRATORS:
            sims = {name: make_simulation(s, integrator, "fragment", dt=dt, ctx=ctx, grid=s.grid)
                    for name, s in systems.items()}
            rows += cost_rows(ctx, sims, "nu=0.25", "x".join(map(str, shape)), int(np.prod(shape)), integrator,
                              steps=steps, rounds=rounds)
    return rows


def cost_rows(ctx: moderngl.Context, sims: dict, baseline: str, label: str, nodes: int, integrator: str, *,
              steps: int, rounds: int) -> list[CostRow]:
    """Time the simulations ``sims`` (name -> simulation, released here) in ``rounds`` alternating
    rounds of ``steps`` steps after 3 warm-up steps: a row each, its median ms per step and its
    ratio to ``baseline``'s of the same round (median, lowest, highest)."""
    try:
        for sim in sims.values():
            sim.step(3)
        ctx.finish()
        per_round: dict[str, list[float]] = {name: [] for name in sims}
        for _ in range(rounds):
            for name, sim in sims.items():
                start = time.perf_counter()
                sim.step(steps)
                ctx.finish()
                per_round[name].append((time.perf_counter() - start) / steps * 1e3)
    finally:
        for sim in sims.values():
            sim.release()
    rows = []
    for name, ms in per_round.items():
        ratios = [a / b for a, b in zip(ms, per_round[baseline])]
        rows.append(CostRow(label, nodes, integrator, name, statistics.median(ms),
                            (statistics.median(ratios), min(ratios), max(ratios))))
    return rows


def format_poisson(rows: list[CostRow], machine: str, rounds: int = 7) -> str:
    """The table."""
    head = f"  {'grid':>9} {'nodes':>7} {'integrator':>13} {'variant':>13} | {'ms/step':>8} | {'vs nu=0.25 (spread)':>24}"
    lines = [machine, f"fragment backend, cost per step of the cells' term: {rounds} alternating rounds, "
             "medians; ratio to the nu = 1/4 lattice (springs + barrier) of the same round", head,
             "  " + "-" * (len(head) - 2)]
    for r in rows:
        lines.append(f"  {r.grid:>9} {r.nodes:>7} {r.integrator:>13} {r.variant:>13} | {r.ms:>8.3f} | "
                     f"{r.ratio[0]:>6.2f} ({r.ratio[1]:.2f} to {r.ratio[2]:.2f})")
    return "\n".join(lines)


def cg_iterations(nus: Sequence[float], *, across: int = 9, steps: int = 30) -> list[tuple[float, float, int]]:
    """(nu, mean, most) CG iterations per implicit-Euler step (see the module docstring)."""
    from deformgl.sim.implicit import ImplicitNumpySimulation

    out = []
    for nu in (0.25, *[n for n in nus if n != 0.25]):
        system = _system((across,) * 3, nu, True)
        sim = ImplicitNumpySimulation(system, 1.0 / 60.0, cg_iterations=400, cg_tolerance=1e-4)
        counts = []
        for _ in range(steps):
            sim.step(1)
            counts.append(sim.last_report.iterations)
        out.append((float(nu), float(np.mean(counts)), int(max(counts))))
    return out


def format_cg(rows: list[tuple[float, float, int]]) -> str:
    """The CG table."""
    base = rows[0][1]
    lines = ["implicit Euler (NumPy, Jacobi-preconditioned CG to 1e-4, 30 steps of 1/60 s, 9^3 block): "
             "CG iterations per step", f"  {'nu':>5} | {'mean':>6} {'most':>5} | {'vs nu=0.25':>10}"]
    lines += [f"  {nu:>5.2f} | {mean:>6.1f} {most:>5d} | {mean / base:>10.2f}" for nu, mean, most in rows]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """``python -m studies.cells_cost --poisson NU[,NU...] [--steps N]``."""
    from deformgl.bench.sim_speed import machine_line
    from deformgl.cli_bench import _nus
    from studies.common import gl_context, parse, parser

    p = parser("cells_cost", "the cost per step of the cells' volumetric term at these Poisson's ratios against "
                             "nu = 1/4 on the fragment backend, and implicit Euler's CG iterations")
    p.add_argument("--poisson", type=_nus, default=(0.45, 0.49), metavar="NU[,NU...]",
                   help="Poisson's ratios in [0.25, 0.499] (default 0.45,0.49)")
    p.add_argument("--steps", type=int, default=40, help="steps per timing (default 40)")
    args = parse(p, argv)
    with gl_context(args) as ctx:
        print(format_poisson(bench_poisson(ctx, args.poisson, steps=args.steps), machine_line(ctx)))
    print()
    print(format_cg(cg_iterations(args.poisson)))
    return 0


if __name__ == "__main__":
    from studies.common import run_main

    run_main(main)
