"""The files of ``deformgl bench trade --stiff --out DIR``: ``stiff.csv`` (every row of
:func:`deformgl.bench.trade_stiff.stiff_study`), ``stiff.json`` (the rows, the cases' headers and the
machine) and ``stiff.png`` (the chart, the 'plot' extra), each written atomically
(:mod:`deformgl.bench.report_files`, :func:`deformgl.bench.charts.save_png`)."""

from __future__ import annotations

import dataclasses
import math
import os
import textwrap
from collections.abc import Sequence

from deformgl.bench import report_files
from deformgl.bench.trade_stiff import REL, VISUAL, StiffCase, StiffRow

__all__ = ["FIELDS", "write_csv", "write_json", "write_chart"]

#: The CSV's columns, the fields of :class:`~deformgl.bench.trade_stiff.StiffRow` in order.
FIELDS = tuple(f.name for f in dataclasses.fields(StiffRow))


def write_csv(path: str | os.PathLike[str], rows: Sequence[StiffRow]) -> None:
    """One line per row (empty cells: not converged within the run)."""
    records = [{k: ("" if v is None else v) for k, v in dataclasses.asdict(r).items()} for r in rows]
    report_files.write_csv(path, records, FIELDS)


def _case_dict(c: StiffCase) -> dict[str, object]:
    return {"name": c.name, "youngs_modulus": c.youngs_modulus, "across": c.across, "nodes": c.system.count,
            "spacing_m": c.spacing, "sag_h": c.sag, "linear_gap_h": None if math.isnan(c.linear_gap) else c.linear_gap,
            "omega1_rad_s": c.omega1, "fem_top_sag_m": None if math.isnan(c.fem) else c.fem}


def write_json(path: str | os.PathLike[str], rows: Sequence[StiffRow], cases: Sequence[StiffCase],
               machine: str) -> None:
    """The rows, the cases and the machine line as JSON (NaN as null)."""
    def clean(v: object) -> object:
        return None if isinstance(v, float) and not math.isfinite(v) else v

    report_files.write_json(path, {"machine": machine, "visual_h": VISUAL, "relative": REL,
                                   "cases": [_case_dict(c) for c in cases],
                                   "rows": [{k: clean(v) for k, v in dataclasses.asdict(r).items()} for r in rows]})


#: (integrator, preconditioner) -> marker.
_MARKERS = {("verlet", ""): "o", ("semi-implicit", ""): "s", ("implicit-euler", "jacobi"): "^",
            ("implicit-euler", "block-jacobi"): "v", ("implicit-euler", "multigrid"): "P", ("xpbd", ""): "D"}


def write_chart(path: str | os.PathLike[str], rows: Sequence[StiffRow], machine: str) -> None:
    """PNG, one column per material: top, the top face's sag error against FEM statics; bottom,
    the largest node error against the lattice's equilibrium (in h, with the 0.05 h line); both
    against wall seconds per simulated second; a colour per resolution, a marker per method
    (implicit Euler and XPBD filled where they converged to 5 % of the sag, hollow where not).

    Raises:
        DeformglError: matplotlib is not installed (``pip install 'deformgl[plot]'``).
    """
    from deformgl.bench.charts import new_figure, save_png

    moduli = sorted({r.youngs_modulus for r in rows})
    fig, axes = new_figure(2, len(moduli), width=5.2, height=3.8, what="stiff")
    grids = sorted({r.across for r in rows})
    colours = {n: f"C{i}" for i, n in enumerate(grids)}
    for col, e in enumerate(moduli):
        top, bottom = axes[0][col], axes[1][col]
        for n in grids:
            for (name, pre), marker in _MARKERS.items():
                sel = [r for r in rows if r.youngs_modulus == e and r.across == n and r.integrator == name
                       and r.preconditioner == pre]
                if not sel:
                    continue
                for ax, value in ((top, lambda r: r.fem_error), (bottom, lambda r: r.final_error)):
                    done = [r for r in sel if r.converged_rel_at is not None]
                    rest = [r for r in sel if r.converged_rel_at is None]
                    for group, face in ((done, colours[n]), (rest, "none")):
                        pts = [(r.wall_per_sim_s, value(r)) for r in group if math.isfinite(value(r))]
                        if pts:
                            ax.plot([p[0] for p in pts], [max(p[1], 1e-12) for p in pts], ls="none",
                                    marker=marker, ms=5, color=colours[n], mfc=face, label=f"{n} across, {name}{f' ({pre})' if pre else ''}")
        bottom.axhline(VISUAL, color="k", lw=0.6, ls=":", label="0.05 h (visual)")
        top.set(xscale="log", yscale="log", ylabel="top-face sag error vs FEM statics (relative)",
                title=f"E = {e:g} Pa block: error vs FEM")
        bottom.set(xscale="log", yscale="log", xlabel="wall s per simulated s (fragment backend)",
                   ylabel="largest node error vs the lattice's equilibrium (h)",
                   title=f"E = {e:g} Pa block: error vs equilibrium")
        for ax in (top, bottom):
            ax.grid(True, which="both", lw=0.3, alpha=0.5)
            handles, labels = ax.get_legend_handles_labels()
            unique = dict(zip(labels, handles))
            ax.legend(unique.values(), unique.keys(), fontsize=5, ncol=2)
    fig.suptitle(textwrap.fill(f"bench trade --stiff: explicit at 0.9 of their limit, implicit Euler dt x CG "
                               f"iterations, XPBD iterations x substeps (filled: within {REL:g} of the sag at the "
                               f"end); {machine}", 140), fontsize=7)
    fig.tight_layout()
    save_png(fig, path)
