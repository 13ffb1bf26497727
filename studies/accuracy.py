"""``python -m studies.accuracy``: the calibrated lattice against converged finite elements
(issue 12, item 3).

For each workload of :mod:`deformgl.bench.fem` (cantilever under gravity, block under a
pressure, twisted bar) and each lattice resolution (nodes across the 0.1 m thickness), the static
equilibrium of the calibrated springs (:func:`~deformgl.bench.fem.static_displacement`) against
the FEM value (ElementHex2, Richardson-extrapolated from meshes refined by halving,
:func:`~deformgl.bench.fem.fem_reference`), with nu = 1/4 as the lattice. The rows give the
ratio deformgl / FEM and the relative error |ratio - 1|; the fitted order is the least-squares
slope of log(error) against log(h) over the resolutions. A second table puts the lattice with
the material's Poisson's ratio (springs + the cells' volumetric term, :mod:`deformgl.sim.terms.volume.energy`)
against FEM bodies of that ratio, beside the springs-only lattice of nu = 1/4 it replaces.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any

import numpy as np

from deformgl.bench import report_files
from deformgl.bench.fem import (MATERIAL, WORKLOADS, FemResult, Workload, beam_theory, fem_reference,
                                lattice_case, lattice_value, observed_order, require_skfem,
                                twist_theory)
from deformgl.bench.sim_speed import cpu_line
from deformgl.sim.materials import MIN_POISSON

__all__ = ["FEM_MESHES", "QUICK_ACROSS", "QUICK_FEM_MESHES", "POISSON", "AccuracyRow",
           "PoissonRow", "AccuracyReport", "fitted_order", "accuracy_study"]

#: FEM meshes (ElementHex2 elements across the thickness) of the full study, per workload.
FEM_MESHES = {"cantilever": (1, 2, 4), "block": (2, 4, 8), "twist": (1, 2, 4)}
QUICK_FEM_MESHES = (1, 2)
QUICK_ACROSS = (2, 3, 5, 9)
#: Poisson's ratios of the second table (FEM and lattice alike; below 1/4 the lattice stays at 1/4).
POISSON = (0.0, 0.3, 0.4, 0.45, 0.49)
QUICK_POISSON = (0.45,)


@dataclass(frozen=True)
class AccuracyRow:
    """One workload at one lattice resolution: values in m (rad for the twist)."""

    workload: str
    across: int
    spacing: float
    nodes: int
    fem: float
    deformgl: float
    ratio: float
    error: float
    seconds: float


@dataclass(frozen=True)
class PoissonRow:
    """The lattice at its finest resolution against FEM at Poisson's ratio ``nu``: with the same
    nu (``deformgl``, ``ratio``; nu = 1/4 where nu < 1/4, which the lattice cannot give) and the
    springs-only lattice of nu = 1/4 (``quarter``, ``quarter_ratio``)."""

    workload: str
    nu: float
    fem: float
    deformgl: float
    ratio: float
    quarter: float = math.nan
    quarter_ratio: float = math.nan


def fitted_order(spacings: Sequence[float], errors: Sequence[float]) -> float:
    """Least-squares slope of log(error) against log(h) (nan with fewer than 2 usable points)."""
    pts = [(math.log(h), math.log(e)) for h, e in zip(spacings, errors) if e > 0 and h > 0]
    if len(pts) < 2:
        return math.nan
    x, y = np.array(pts).T
    return float(np.polyfit(x, y, 1)[0])


@dataclass
class AccuracyReport:
    """What :func:`accuracy_study` measured."""

    rows: list[AccuracyRow]
    fem: dict[str, list[FemResult]]
    references: dict[str, tuple[float, float]]  # workload -> (FEM value, estimated rel. error)
    poisson: list[PoissonRow] = field(default_factory=list)
    machine: str = ""
    date: str = ""

    def order(self, workload: str) -> float:
        """The fitted order of the lattice's error for ``workload``."""
        rows = [r for r in self.rows if r.workload == workload]
        return fitted_order([r.spacing for r in rows], [r.error for r in rows])

    def row(self, workload: str, across: int) -> AccuracyRow:
        """The row of ``workload`` at ``across`` nodes across."""
        return next(r for r in self.rows if r.workload == workload and r.across == across)

    def format(self) -> str:
        """The terminal tables."""
        lines = [self.machine, f"date: {self.date}; static equilibrium of the calibrated lattice "
                 "(nu = 1/4) vs linear-elastic FEM (scikit-fem ElementHex2, nu = 1/4, Richardson-"
                 "extrapolated); E = 1e8 Pa, rho = 1000 kg/m^3"]
        for name, results in self.fem.items():
            w = WORKLOADS[name]
            ref, err = self.references[name]
            conv = ", ".join(f"{r.per_thickness} across ({r.dofs} dofs): {r.value:.6e}"
                             for r in results)
            lines.append(f"{name}: FEM {conv}; extrapolated {ref:.6e} {w.unit} (est. error "
                         f"{err:.1e}, observed order {observed_order(results):.2f})")
            if name == "cantilever":
                eb, timo = beam_theory(w)
                lines.append(f"  beam theory: Euler-Bernoulli {eb:.6e} m (FEM/EB {ref / eb:.4f}), "
                             f"Timoshenko {timo:.6e} m (FEM/Timoshenko {ref / timo:.4f})")
            if name == "twist":
                sv = twist_theory(w)
                lines.append(f"  Saint-Venant (free warping) {sv:.6e} rad (FEM/SV {ref / sv:.4f})")
        head = (f"  {'workload':>10} {'across':>6} {'h [m]':>9} {'nodes':>6} | {'FEM':>11} "
                f"{'deformgl':>11} | {'ratio':>7} {'error':>8}")
        lines += ["", head, "  " + "-" * (len(head) - 2)]
        for name in self.fem:
            for r in (r for r in self.rows if r.workload == name):
                lines.append(f"  {r.workload:>10} {r.across:>6} {r.spacing:>9.5f} {r.nodes:>6} | "
                             f"{r.fem:>11.5e} {r.deformgl:>11.5e} | {r.ratio:>7.4f} "
                             f"{r.error:>8.2e}")
            lines.append(f"  {name:>10} fitted order (least squares of log error vs log h): "
                         f"{self.order(name):.2f}")
        if self.poisson:
            lines += ["", "The lattice with the body's Poisson's ratio (springs + cells; 1/4 below 1/4) "
                      "and the springs-only lattice (nu = 1/4) against FEM bodies of that ratio, at "
                      "the finest lattice resolution:",
                      f"  {'workload':>10} {'nu':>5} | {'FEM':>11} {'deformgl':>11} | {'ratio':>7} | "
                      f"{'nu=1/4':>11} {'ratio':>7}"]
            lines += [f"  {p.workload:>10} {p.nu:>5.2f} | {p.fem:>11.5e} {p.deformgl:>11.5e} | "
                      f"{p.ratio:>7.4f} | {p.quarter:>11.5e} {p.quarter_ratio:>7.4f}" for p in self.poisson]
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {"machine": self.machine, "date": self.date,
                "references": {k: {"value": v, "error": e} for k, (v, e) in self.references.items()},
                "fem": {k: [dataclasses.asdict(r) for r in v] for k, v in self.fem.items()},
                "orders": {k: self.order(k) for k in self.fem},
                "rows": [dataclasses.asdict(r) for r in self.rows],
                "poisson": [dataclasses.asdict(p) for p in self.poisson]}

    def write_csv(self, path: str | os.PathLike) -> None:
        """The lattice rows, atomically."""
        report_files.write_csv(path, [dataclasses.asdict(r) for r in self.rows],
                               [f.name for f in dataclasses.fields(AccuracyRow)])

    def write_json(self, path: str | os.PathLike) -> None:
        """:meth:`to_dict` as JSON, atomically."""
        report_files.write_json(path, self.to_dict())


def accuracy_study(*, quick: bool = False, workloads: Sequence[str] = tuple(WORKLOADS),
                   across: Sequence[int] | None = None, poisson: Sequence[float] | None = None,
                   progress: Callable[[str], None] | None = None) -> AccuracyReport:
    """The lattice against FEM for each workload and resolution (see the module docstring).

    Args:
        quick: lattice resolutions :data:`QUICK_ACROSS`, FEM meshes :data:`QUICK_FEM_MESHES`
            (not extrapolated) and one Poisson's ratio.
        workloads: names in :data:`~deformgl.bench.fem.WORKLOADS`.
        across: the lattice resolutions (default: each workload's, or the quick ones).
        poisson: the FEM Poisson's ratios of the second table (default :data:`POISSON`).
        progress: called with a line before each FEM solve and lattice.

    Raises:
        DeformglError: scikit-fem is not installed.
    """
    require_skfem()
    rows: list[AccuracyRow] = []
    fem: dict[str, list[FemResult]] = {}
    refs: dict[str, tuple[float, float]] = {}
    poisson_rows: list[PoissonRow] = []
    nus = tuple(poisson if poisson is not None else (QUICK_POISSON if quick else POISSON))
    for name in workloads:
        w: Workload = WORKLOADS[name]
        meshes = QUICK_FEM_MESHES if quick else FEM_MESHES[name]
        if progress:
            progress(f"{name}: FEM on {', '.join(map(str, meshes))} elements across")
        value, err, results = fem_reference(w, meshes)
        fem[name], refs[name] = results, (value, err)
        finest, finest_n = 0.0, 0
        for n in across or (QUICK_ACROSS if quick else w.across):
            if progress:
                progress(f"{name}: lattice with {n} nodes across")
            start = time.perf_counter()
            case = lattice_case(w, n)
            v = lattice_value(case)
            rows.append(AccuracyRow(name, n, case.spacing, case.grid.count, value, v, v / value,
                                    abs(v / value - 1.0), time.perf_counter() - start))
            finest, finest_n = v, n
        for nu in nus:
            if progress:
                progress(f"{name}: FEM and the lattice at nu = {nu}")
            fv, _, _ = fem_reference(w, meshes, nu=nu)
            lattice_nu = max(nu, MIN_POISSON)
            lv = (finest if lattice_nu == MATERIAL.poissons_ratio else
                  lattice_value(lattice_case(w, finest_n, dataclasses.replace(MATERIAL, poissons_ratio=lattice_nu))))
            poisson_rows.append(PoissonRow(name, nu, fv, lv, lv / fv, finest, finest / fv))
    date = datetime.now(timezone.utc).isoformat(timespec="seconds")
    return AccuracyReport(rows, fem, refs, poisson_rows, cpu_line(), date)


def main(argv: list[str] | None = None) -> int:
    """``python -m studies.accuracy [--quick] [--quiet] [--out DIR]``: the tables, and with
    ``--out`` DIR/accuracy.csv and accuracy.json, written together or not at all."""
    from deformgl.files import OutputSet
    from studies.common import parse, parser, progress

    args = parse(parser("accuracy", "the calibrated lattice's static equilibrium against converged hexahedral FEM"), argv)
    require_skfem()
    out = args.out
    outputs = OutputSet([out / f"accuracy.{ext}" for ext in ("csv", "json")] if out else [])
    report = accuracy_study(quick=args.quick, progress=progress(args))
    print(report.format())
    if out is not None:
        with outputs:
            report.write_csv(out / "accuracy.csv")
            report.write_json(out / "accuracy.json")
    return 0


if __name__ == "__main__":
    from studies.common import run_main

    run_main(main)
