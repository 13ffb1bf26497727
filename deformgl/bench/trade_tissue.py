"""Poisson's ratio as a workload axis of ``deformgl bench trade --poisson`` (issue 27): the
liver block of :func:`tissue_workloads`, on the same chart as :mod:`deformgl.bench.trade`'s
standard workloads."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from deformgl.bench.trade import SIM_TIME, Workload, _ramp
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.materials import PRESETS, lattice_system
from deformgl.sim.springs import max_angular_frequency
from deformgl.sim.scripted import Drag

__all__ = ["TISSUE_POISSON", "tissue_workloads"]

#: Poisson's ratios of the tissue block by default: the springs' own and a tissue's
TISSUE_POISSON = (0.25, 0.45)


def tissue_workloads(nus: Sequence[float] = TISSUE_POISSON, sim_time: float = SIM_TIME) -> tuple[Workload, ...]:
    """Poisson's ratio as a workload axis: a 6x6x6-node block of liver (E = 4 kPa, rho =
    1060 kg/m^3, the ``liver`` preset's values, h = 1 cm) at each ``nu``, bottom layer fixed, its top
    corner dragged 3 spacings sideways and 1 up like the volume workload (a drag of twice the
    lattice's spring constant). Rayleigh beta = 1 / w (w the springs' Gershgorin top frequency)
    damps the springs' top mode with ratio 0.5 and alpha = 2 /s every mode a little; the cells'
    volumetric term is not damped (:mod:`deformgl.sim.terms.volume.energy`), so at nu > 1/4 forward Euler and
    midpoint find less damping at the top of the spectrum."""
    h, n = 0.01, 6
    grid = NodeGrid(np.array([-(n - 1) * h / 2, 0.0, -(n - 1) * h / 2]), h, np.ones((n,) * 3, bool))
    liver = PRESETS["liver"]
    top = int(grid.index[n - 1, n - 1, n - 1])
    out = []
    for nu in nus:
        material = dataclasses.replace(liver, poissons_ratio=float(nu), mass_damping=2.0, name="")
        springs, _ = lattice_system(grid, material, fixed=grid.ijk[:, 1] == 0, gravity=(0.0, 0.0, 0.0))
        beta = 1.0 / max_angular_frequency(dataclasses.replace(springs, cells=None)).omega
        system, _ = lattice_system(grid, dataclasses.replace(material, stiffness_damping=beta),
                                   fixed=grid.ijk[:, 1] == 0, gravity=(0.0, 0.0, 0.0))
        drag = Drag(top, _ramp(grid.rest_positions[top], np.array([3 * h, h, 0.0]), sim_time),
                    2.0 * material.shear_modulus * h)
        out.append(Workload(f"liver block, nu = {nu:g}", system, grid, drags=(drag,), time=sim_time))
    return tuple(out)
