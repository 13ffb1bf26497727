"""Large strain without inversion (issue 27, item 2): ``python -m studies.inversion``.

Three runs that invert cells of a springs-only lattice, each with the lattice's cells (the
volumetric term and the corner barrier of :mod:`deformgl.sim.terms.volume.energy`) and, for comparison,
without them (``cells=None``: the springs alone, what deformgl had before):

* **hang**: a 0.2 x 0.02 x 0.02 m cantilever (rho = 1000 kg/m^3, nu = 1/4, E = 5 kPa or 50 kPa)
  clamped at x = 0, left to hang under its own weight (mass damping 2 w_1, ``HANG_SECONDS``);
* **drop**: a 4 cm cube of a 2 kPa jelly (rho = 1000 kg/m^3) dropped from 2 cm onto the ground;
* **crush**: the same cube on the ground, pressed 30 % of its height by a sphere of radius 5 cm
  (0.4 s down, 0.3 s held), then released (0.2 s up, 0.5 s to settle).

Each run reports the inversion census (cells with a corner Jacobian <= 0,
:func:`~deformgl.sim.terms.volume.energy.describe_inverted`) at the end (and for the crush also while held)
and whether every node stayed finite. Semi-implicit Euler at half the Gershgorin dt limit of the
system (springs and cells), on the fragment backend by default.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from dataclasses import dataclass

import numpy as np

from deformgl.grid.nodes import NodeGrid
from deformgl.sim.integrators import Constraints, Sphere
from deformgl.sim.materials import ElasticMaterial, lattice_system
from deformgl import make_simulation
from deformgl.sim.springs import SpringSystem, max_angular_frequency
from deformgl.sim.terms.volume.energy import inverted_cells

__all__ = ["Case", "InversionRow", "hang_case", "drop_case", "crush_case", "run_case", "format_rows", "main"]

HANG_SECONDS = {5.0e3: 10.0, 5.0e4: 4.0}
DROP_SECONDS = 1.0
#: the crush's schedule (s): down, held, up, settle
CRUSH = (0.4, 0.3, 0.2, 0.5)
CRUSH_DEPTH = 0.3


@dataclass(frozen=True, eq=False)
class Case:
    """A run: the system, its obstacles, the simulated seconds and when to take a census
    before the end (``held``, s, or None)."""

    name: str
    system: SpringSystem
    seconds: float
    constraints: Constraints | None = None
    held: float | None = None


@dataclass(frozen=True)
class InversionRow:
    """One run: inverted cells (of ``cells``) at the end and while held (-1: not measured),
    whether every node stayed finite, steps and wall seconds."""

    case: str
    cells_on: bool
    cells: int
    inverted_end: int
    inverted_held: int
    finite: bool
    steps: int
    wall_s: float


def _material(e: float, nu: float, alpha: float) -> ElasticMaterial:
    return ElasticMaterial(e, 1000.0, mass_damping=alpha, poissons_ratio=nu)


def hang_case(youngs_modulus: float, across: int, nu: float = 0.25) -> Case:
    """The hanging cantilever (see the module docstring)."""
    h = 0.02 / (across - 1)
    grid = NodeGrid(np.array([0.0, -0.01, -0.01]), h, np.ones((int(round(0.2 / h)) + 1, across, across), bool))
    # w_1 of the Euler-Bernoulli cantilever: 1.875^2 sqrt(E I / (rho A)) / L^2 with I / A = w^2 / 12
    w1 = 1.875 ** 2 * math.sqrt(youngs_modulus * 0.02 ** 2 / 12.0 / 1000.0) / 0.2 ** 2
    system, _ = lattice_system(grid, _material(youngs_modulus, nu, 2.0 * w1), fixed=grid.ijk[:, 0] == 0)
    return Case(f"hang E={youngs_modulus:g} Pa nu={nu:g} {across} across", system,
                HANG_SECONDS.get(youngs_modulus, 6.0))


def _cube(across: int, nu: float, lift: float) -> tuple[SpringSystem, float]:
    h = 0.04 / (across - 1)
    grid = NodeGrid(np.array([-0.02, lift, -0.02]), h, np.ones((across,) * 3, bool))
    system, _ = lattice_system(grid, _material(2.0e3, nu, 5.0))
    return system, h


def drop_case(nu: float, across: int = 9) -> Case:
    """The jelly dropped from 2 cm onto the ground at y = 0."""
    system, _ = _cube(across, nu, 0.02)
    return Case(f"drop nu={nu:g} {across} across", system, DROP_SECONDS, Constraints(ground=0.0))


def crush_case(nu: float, across: int = 9) -> Case:
    """The jelly on the ground pressed by 30 % of its 4 cm height and released."""
    system, _ = _cube(across, nu, 0.0)
    radius = 0.05
    down, held, up, settle = CRUSH
    top = 0.04 + radius  # the sphere's centre when it touches the top face

    def centre(t: float) -> tuple[float, float, float]:
        depth = CRUSH_DEPTH * 0.04
        if t < down:
            s = t / down
        elif t < down + held:
            s = 1.0
        else:
            s = max(0.0, 1.0 - (t - down - held) / up)
        return (0.0, top - depth * 0.5 * (1.0 - math.cos(math.pi * s)), 0.0)

    return Case(f"crush 30% nu={nu:g} {across} across", system, sum(CRUSH),
                Constraints(ground=0.0, spheres=(Sphere(centre, radius),)), held=down + held)


def run_case(case: Case, *, cells: bool = True, backend: str = "fragment", ctx=None) -> InversionRow:
    """Run ``case`` (with or without its cells) and take the census."""
    if case.system.cells is None:
        raise ValueError(f"{case.name}: the case's system has no cells to take a census of")
    system = case.system if cells else dataclasses.replace(case.system, cells=None)
    corners = case.system.cells.corners
    dt = 0.5 * 2.0 / max_angular_frequency(system).omega
    steps = int(math.ceil(case.seconds / dt))
    dt = case.seconds / steps
    held_steps = -1 if case.held is None else int(round(case.held / dt))
    start = time.perf_counter()
    inverted_held = -1
    with make_simulation(system, "semi-implicit", backend, dt=dt, ctx=ctx, grid=system.grid,
                         constraints=case.constraints) as sim:
        if held_steps > 0:
            sim.step(held_steps)
            inverted_held = int(inverted_cells(corners, system.spacing, sim.positions()).sum())
            sim.step(steps - held_steps)
        else:
            sim.step(steps)
        x = np.asarray(sim.positions(), np.float64)
    wall = time.perf_counter() - start
    return InversionRow(case.name, cells, len(corners), int(inverted_cells(corners, system.spacing, x).sum()),
                        inverted_held, bool(np.isfinite(x).all()), steps, wall)


def standard_cases(quick: bool = False) -> list[Case]:
    """The hanging cantilevers at 5 and 9 across (E = 5 and 50 kPa), the drop and the crush at
    nu = 0.25, 0.45, 0.49 (``quick``: 5 across, 5-node cubes, nu 0.25 and 0.49)."""
    across = (5,) if quick else (5, 9)
    cube = 5 if quick else 9
    nus = (0.25, 0.49) if quick else (0.25, 0.45, 0.49)
    cases = [hang_case(e, n) for e in (5.0e3, 5.0e4) for n in across]
    cases += [drop_case(nu, cube) for nu in nus]
    cases += [crush_case(nu, cube) for nu in nus]
    return cases


def format_rows(rows: list[InversionRow], machine: str = "") -> str:
    """The table."""
    head = f"  {'case':<34} {'cells':>5} | {'inverted':>8} {'held':>6} {'finite':>6} | {'steps':>6} {'wall s':>7}"
    lines = [machine, "semi-implicit Euler at half the Gershgorin limit; inverted: cells with a corner "
             "Jacobian <= 0 at the end (held: while the sphere presses)", head, "  " + "-" * (len(head) - 2)]
    for r in rows:
        held = "" if r.inverted_held < 0 else str(r.inverted_held)
        lines.append(f"  {r.case:<34} {'on' if r.cells_on else 'off':>5} | {r.inverted_end:>8} {held:>6} "
                     f"{'yes' if r.finite else 'NO':>6} | {r.steps:>6} {r.wall_s:>7.1f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """``python -m studies.inversion [--quick] [--backend B] [--springs-too]``."""
    parser = argparse.ArgumentParser(prog="python -m studies.inversion", description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="coarser grids, two Poisson's ratios")
    parser.add_argument("--backend", default="fragment", choices=("fragment", "feedback", "numpy"))
    parser.add_argument("--springs-too", action="store_true", help="also run each case without its cells")
    args = parser.parse_args(argv)
    ctx = None
    machine = "NumPy float64"
    if args.backend != "numpy":
        from deformgl.bench.sim_speed import machine_line
        from deformgl.gl.context import create_context

        ctx = create_context()
        machine = machine_line(ctx)
    rows = []
    for case in standard_cases(args.quick):
        for on in ((True, False) if args.springs_too else (True,)):
            rows.append(run_case(case, cells=on, backend=args.backend, ctx=ctx))
            print(format_rows(rows[-1:]).splitlines()[-1], file=sys.stderr, flush=True)
    print(format_rows(rows, machine))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
