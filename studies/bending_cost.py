"""What a sheet's bending stiffness costs per step: ``python -m studies.bending_cost``.

The same cloth (a square sheet, Y = 50 N/m, rho_A = 0.2 kg/m^2, two corners pinned) on the
fragment backend with its three ways to bend: the flexion springs of Movania & Feng 2012
(``flexion_ratio`` 0.1, the baseline: the paper's cloth), the plate term (``bending_stiffness``,
:mod:`deformgl.sim.terms.bending`) and none (a membrane), for semi-implicit Euler (the integrator pass)
and implicit Euler (20 CG iterations a step). Rounds alternate the variants in one process, as
:mod:`studies.cells_cost`; each round's ms per step and ratio to that round's baseline are
kept, and the table prints the median ratio with its spread.
"""

from __future__ import annotations

from collections.abc import Sequence

import moderngl
import numpy as np

from studies.cells_cost import CostRow, cost_rows
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.materials import SheetMaterial, sheet_system
from deformgl import make_simulation
from deformgl.sim.springs import SpringSystem, max_angular_frequency

__all__ = ["SHEETS", "bench_bending", "format_bending"]

#: Nodes along each side of the cost table's sheets.
SHEETS = (64, 256)
INTEGRATORS = ("semi-implicit", "implicit-euler")
VARIANTS = {"flexion springs": {"flexion_ratio": 0.1}, "plate D": {"bending_stiffness": 1e-4}, "membrane": {}}


def _system(n: int, options: dict[str, float]) -> SpringSystem:
    grid = NodeGrid(np.zeros(3), 1.0 / (n - 1), np.ones((n, 1, n), bool))
    ijk = grid.ijk
    pinned = (ijk[:, 0] == 0) & ((ijk[:, 2] == 0) | (ijk[:, 2] == n - 1))
    material = SheetMaterial(50.0, 0.2, mass_damping=0.5, flexion_ratio=options.get("flexion_ratio", 0.0),
                             bending_stiffness=options.get("bending_stiffness", 0.0))
    system, _ = sheet_system(grid, material, fixed=pinned)
    return system


def bench_bending(ctx: moderngl.Context, *, steps: int = 40, rounds: int = 7,
                  sheets: Sequence[int] = SHEETS) -> list[CostRow]:
    """The table's rows (see the module docstring)."""
    rows = []
    for n in sheets:
        systems = {name: _system(n, options) for name, options in VARIANTS.items()}
        dt = 0.5 * min(2.0 / max_angular_frequency(s).omega for s in systems.values())
        for integrator in INTEGRATORS:
            extra = {"cg_iterations": 20} if integrator == "implicit-euler" else {}
            sims = {name: make_simulation(s, integrator, "fragment", dt=dt, ctx=ctx, grid=s.grid, **extra)
                    for name, s in systems.items()}
            rows += cost_rows(ctx, sims, "flexion springs", f"{n}x{n}", n * n, integrator, steps=steps, rounds=rounds)
    return rows


def format_bending(rows: list[CostRow], machine: str, rounds: int = 7) -> str:
    """The table."""
    head = (f"  {'sheet':>9} {'nodes':>7} {'integrator':>14} {'variant':>15} | {'ms/step':>8} | "
            f"{'vs flexion springs (spread)':>28}")
    lines = [machine, f"fragment backend, cost per step of a cloth's bending: {rounds} alternating rounds, "
             "medians; ratio to the flexion springs of the same round", head, "  " + "-" * (len(head) - 2)]
    for r in rows:
        lines.append(f"  {r.grid:>9} {r.nodes:>7} {r.integrator:>14} {r.variant:>15} | {r.ms:>8.3f} | "
                     f"{r.ratio[0]:>6.2f} ({r.ratio[1]:.2f} to {r.ratio[2]:.2f})")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """``python -m studies.bending_cost [--steps N]``."""
    from deformgl.bench.sim_speed import machine_line
    from studies.common import gl_context, parse, parser

    p = parser("bending_cost", "the cost per step of a cloth's bending stiffness (the plate term) against "
                               "flexion springs and a membrane on the fragment backend")
    p.add_argument("--steps", type=int, default=40, help="steps per timing (default 40)")
    args = parse(p, argv)
    with gl_context(args) as ctx:
        print(format_bending(bench_bending(ctx, steps=args.steps), machine_line(ctx)))
    return 0


if __name__ == "__main__":
    from studies.common import run_main

    run_main(main)
