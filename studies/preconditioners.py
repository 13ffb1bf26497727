"""``python -m studies.preconditioners``: the implicit step's multigrid against Jacobi and
block-Jacobi (issue 29).

Three measurements, each printed with the machine line:

1. **Iterations** (:func:`iteration_rows`): CG iterations to a true relative residual of 1e-4 on
   the first step (dt = 1/60 s, from rest) of the stiff block (:data:`~deformgl.bench.trade_stiff.BLOCK`
   at E = 1 MPa) at 9, 17, 33 and 65 nodes across, at nu = 1/4 and 0.45, and of the heart scene's
   body (scenes/dragon_heart_scale.toml: the res3 dragon filled with the heart preset, fixed at its
   base) at 17, 33 and 65 along, per preconditioner (float64, :mod:`deformgl.sim.implicit`). The
   multigrid's set-up (its Galerkin levels) is timed apart.
2. **The stiff block against explicit** (:func:`stiff_rows`): the block at 33 across (and 17),
   wall time per simulated second on the fragment backend until every node stays within 5 % of
   the equilibrium's largest sag (:func:`deformgl.bench.trade_stiff.stiff_row`): Verlet and
   semi-implicit Euler at 0.9 of their limits, implicit Euler at dt = 1/60 s with a fixed number
   of CG iterations a step per preconditioner; the verdict is the cheapest converged row of each
   preconditioner against the cheapest explicit one.
3. **The heart frame** (:func:`heart_frames`): the heart scene at its default material and size
   with FXAA and back faces culled, one frame = one implicit step of 1/60 s whose solve stops at a
   relative residual of 1e-3 (at most 200 iterations), the curvature-corrected mapping and the
   draw, per preconditioner, the preconditioners alternating within each round; median and
   spread of the frames per second, iterations per step.
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import dataclass

import numpy as np

from deformgl.bench.sim_blocks import scene_path
from deformgl.bench.trade_stiff import FINE, QUICK_SIM_TIME, REL, StiffCase, block_system, stiff_cases, stiff_row
from deformgl.errors import DeformglError
from deformgl.sim.implicit import PRECONDITIONERS, ImplicitNumpySimulation, assemble, multigrid_levels, pcg, preconditioner
from deformgl.sim.integrators import initial_state
from deformgl.sim.limits import dt_limit
from deformgl.sim.springs import SpringSystem
from studies.heart_frame import heart_frame_setup

__all__ = ["IterationRow", "iteration_rows", "format_iterations", "stiff_rows", "format_stiff_rows",
           "heart_frames", "format_frames", "heart_body", "PreconditionerRow", "preconditioner_bodies",
           "preconditioner_iterations", "format_preconditioners"]

FRAME_DT = 1.0 / 60.0
TOLERANCE = 1e-4
FRAME_TOLERANCE = 1e-3


@dataclass(frozen=True)
class IterationRow:
    body: str
    nodes: int
    iterations: dict[str, int]
    setup_s: float   # the multigrid's levels (prolongations and Galerkin products)


def heart_body(along: int) -> SpringSystem:
    """The heart scene's body at ``along`` nodes along its longest side (its fixed base, the
    scene's gravity; its pull is a load of the run, not of the body)."""
    from deformgl.scene.pipeline import build_scene_model
    from deformgl.scene.schema import load_scene

    return build_scene_model(load_scene(scene_path(), {"grid.nodes_along_longest": along})).system


def _count(system: SpringSystem) -> tuple[dict[str, int], float]:
    st = initial_state(system, FRAME_DT)
    lin = assemble(system, st.x, st.v, 0.0, FRAME_DT)
    out = {}
    setup = 0.0
    for kind in PRECONDITIONERS:
        if kind == "multigrid":
            t0 = time.perf_counter()
            apply = multigrid_levels(system).cycle(lin.matrix)
            setup = time.perf_counter() - t0
        else:
            apply = preconditioner(lin.matrix, kind).__matmul__
        _, report = pcg(lin.matrix, lin.rhs, np.zeros_like(lin.rhs), iterations=5000, tolerance=TOLERANCE,
                        check_every=1, apply=apply)
        if not report.within_tolerance:
            raise DeformglError(f"bench multigrid: {kind} CG did not reach {TOLERANCE:g} in 5000 iterations "
                                f"({report.residual:.1e})")
        out[kind] = report.iterations
    return out, setup


def iteration_rows(across=(9, 17, 33, 65), nus=(0.25, 0.45), heart=(17, 33, 65)) -> list[IterationRow]:
    rows = []
    for nu in nus:
        for n in across:
            system = block_system(n, poissons_ratio=nu)
            counts, setup = _count(system)
            rows.append(IterationRow(f"block nu={nu:g}, {n} across", system.count, counts, setup))
    for n in heart:
        system = heart_body(n)
        counts, setup = _count(system)
        rows.append(IterationRow(f"heart body, {n} along", system.count, counts, setup))
    return rows


def format_iterations(rows: list[IterationRow]) -> str:
    lines = [f"CG iterations to a true relative residual of {TOLERANCE:g}, first step of dt = 1/60 s from rest "
             "(float64); multigrid set-up seconds apart",
             f"{'body':<28} {'nodes':>7} " + " ".join(f"{k:>12}" for k in PRECONDITIONERS) + f" {'MG set-up s':>11}"]
    for r in rows:
        lines.append(f"{r.body:<28} {r.nodes:>7} " + " ".join(f"{r.iterations[k]:>12}" for k in PRECONDITIONERS)
                     + f" {r.setup_s:>11.2f}")
    return "\n".join(lines)


def stiff_rows(ctx, across=(17, 33), sim_time: float = 0.5,
               iterations: dict[str, tuple[int, ...]] | None = None) -> list[tuple[str, object]]:
    """(label, :class:`~deformgl.bench.trade_stiff.StiffRow`) of the stiff block at each resolution."""
    iterations = iterations or {"jacobi": (10, 30), "block-jacobi": (10, 30), "multigrid": (1, 2, 3, 5)}
    out: list[tuple[str, object]] = []
    for case in stiff_cases(cases=tuple((1.0e6, n) for n in across)):
        for name in ("verlet", "semi-implicit"):
            dt = 0.9 * dt_limit(case.system, name).dt
            out.append((name, stiff_row(ctx, case, name, dt, 0, sim_time)))
        for kind, counts in iterations.items():
            for its in counts:
                out.append((f"implicit {kind}", stiff_row(ctx, case, "implicit-euler", FRAME_DT, its, sim_time,
                                                          preconditioner=kind)))
    return out


def format_stiff_rows(rows: list[tuple[str, object]]) -> str:
    lines = [f"the stiff block (E = 1 MPa) on the fragment backend: wall s per simulated s, and the simulated s "
             f"after which every node stays within {REL:g} of the equilibrium's largest sag",
             f"{'case':<26} {'method':<24} {'dt s':>9} {'it':>4} {'wall/sim s':>10} {'rel. at s':>9} {'/sag':>9}"]
    for label, r in rows:
        lines.append(f"{r.case:<26} {label:<24} {r.dt:>9.3g} {r.iterations or '-':>4} {r.wall_per_sim_s:>10.3g} "  # type: ignore[attr-defined]
                     f"{'-' if r.converged_rel_at is None else format(r.converged_rel_at, '.3f'):>9} "  # type: ignore[attr-defined]
                     f"{r.relative_error:>9.3g}")  # type: ignore[attr-defined]
    for case in dict.fromkeys(r.case for _, r in rows):  # type: ignore[attr-defined]
        done = [(label, r) for label, r in rows if r.case == case and r.converged_rel_at is not None]  # type: ignore[attr-defined]
        explicit = [r for label, r in done if not label.startswith("implicit")]
        if not explicit:
            continue
        best = min(explicit, key=lambda r: r.wall_per_sim_s)  # type: ignore[attr-defined]
        for kind in ("jacobi", "block-jacobi", "multigrid"):
            mine = [r for label, r in done if label == f"implicit {kind}"]
            if mine:
                m = min(mine, key=lambda r: r.wall_per_sim_s)  # type: ignore[attr-defined]
                lines.append(f"{case}: implicit {kind} ({m.iterations} it) {best.wall_per_sim_s / m.wall_per_sim_s:.3g}x "  # type: ignore[attr-defined]
                             f"cheaper per simulated s than {best.integrator} to {REL:g} of the sag")  # type: ignore[attr-defined]
            else:
                lines.append(f"{case}: implicit {kind}: no row reached {REL:g} of the sag")
    return "\n".join(lines)


def heart_frames(ctx, rounds: int = 7, kinds=PRECONDITIONERS) -> dict[str, tuple[list[float], float]]:
    """{preconditioner: (frames per second of each round, mean CG iterations per step)} of the
    heart frame (module docstring)."""
    from deformgl.render.passes import RenderTarget
    from deformgl.sim.backends.implicit_gpu import ImplicitFragment

    frame = heart_frame_setup()
    built, view, lighting = frame.built, frame.view, frame.lighting
    sims = {k: ImplicitFragment(ctx, built.system, None, FRAME_DT, loads=built.loads, cg_preconditioner=k,
                                cg_tolerance=FRAME_TOLERANCE, cg_iterations=200, cg_check_every=1) for k in kinds}
    width, height = frame.scene.render.size
    target = RenderTarget(ctx, (int(width), int(height)), 0, fxaa=True)
    passes = {k: frame.mapped_pass(ctx, sims[k].layout) for k in kinds}
    fps: dict[str, list[float]] = {k: [] for k in kinds}
    try:
        for k in kinds:  # compile and warm up
            sims[k].step(1)
        for r in range(rounds):
            for k in (list(kinds) if r % 2 == 0 else list(reversed(kinds))):
                ctx.finish()
                t0 = time.perf_counter()
                sims[k].step(1)
                target.begin((0.96, 0.96, 0.94))
                passes[k].draw(sims[k].position_texture, view, lighting)
                target.resolve()
                ctx.finish()
                fps[k].append(1.0 / (time.perf_counter() - t0))
        return {k: (fps[k], sims[k].stats.iterations_total / max(sims[k].stats.steps, 1)) for k in kinds}
    finally:
        target.release()
        for p in passes.values():
            p.release()
        for s in sims.values():
            s.release()


def format_frames(frames: dict[str, tuple[list[float], float]]) -> str:
    lines = ["the heart frame (640x480, FXAA, back faces culled): one implicit step of 1/60 s to a relative "
             f"residual of {FRAME_TOLERANCE:g}, the curvature-corrected mapping and the draw",
             f"{'preconditioner':<14} {'frames/s':>9} {'spread':>15} {'CG it/step':>10}"]
    for k, (values, its) in frames.items():
        lines.append(f"{k:<14} {statistics.median(values):>9.2f} {min(values):>7.2f}-{max(values):<7.2f} {its:>10.1f}")
    return "\n".join(lines)


@dataclass(frozen=True)
class PreconditionerRow:
    """CG iterations to a relative tolerance, per preconditioner, on one case at one dt."""

    case: str
    dt: float
    tolerance: float
    first: dict[str, int]     # the first step's solve from dv = 0
    warm: dict[str, float]    # mean per step over QUICK_SIM_TIME (deformgl.bench.trade_stiff) of warm-started steps


def preconditioner_bodies(cases: list[StiffCase], quick: bool = False) -> list[tuple[str, SpringSystem]]:
    """The study's blocks up to :data:`FINE` across and the FEM-checked cantilever (E = 1e8 Pa,
    3 or 5 nodes across)."""
    from deformgl.bench.fem import MATERIAL, WORKLOADS, lattice_case

    across = 3 if quick else 5
    beam = lattice_case(WORKLOADS["cantilever"], across, MATERIAL).system
    return ([(c.name, c.system) for c in cases if c.across <= FINE]
            + [(f"cantilever E=1e8 Pa, {across} across", beam)])


def preconditioner_iterations(bodies: list[tuple[str, SpringSystem]], *,
                              dts: tuple[float, ...] = (1 / 60, 1 / 1000),
                              tolerance: float = 1e-4) -> list[PreconditionerRow]:
    """Jacobi, block-Jacobi and multigrid (:data:`~deformgl.sim.implicit.PRECONDITIONERS`) on (name,
    system) bodies: CG iterations to ``tolerance`` (the float64 reference, the GPU's iteration)
    on the first step from rest and averaged over the warm-started steps of
    :data:`QUICK_SIM_TIME` s."""
    rows = []
    for name, system in bodies:
        for dt in dts:
            first: dict[str, int] = {}
            warm: dict[str, float] = {}
            for kind in PRECONDITIONERS:
                sim = ImplicitNumpySimulation(system, dt, cg_iterations=5000, cg_tolerance=tolerance,
                                              cg_check_every=1, cg_preconditioner=kind)
                steps = max(1, round(QUICK_SIM_TIME / dt))
                counts = []
                for _ in range(steps):
                    sim.step()
                    counts.append(sim.last_report.iterations)
                first[kind], warm[kind] = counts[0], float(np.mean(counts[1:] if steps > 1 else counts))
            rows.append(PreconditionerRow(name, dt, tolerance, first, warm))
    return rows


def format_preconditioners(rows: list[PreconditionerRow]) -> str:
    kinds = {"jacobi": "J", "block-jacobi": "BJ", "multigrid": "MG"}
    lines = ["CG iterations to a true relative residual, Jacobi vs block-Jacobi vs multigrid (float64 reference): "
             f"first step from dv = 0, and the mean over {QUICK_SIM_TIME:g} s of warm-started steps",
             f"{'case':<32} {'dt s':>8} {'tol':>6} "
             + " ".join(f"{'first ' + k:>8}" for k in kinds.values()) + " "
             + " ".join(f"{'warm ' + k:>8}" for k in kinds.values())]
    for r in rows:
        lines.append(f"{r.case:<32} {r.dt:>8.3g} {r.tolerance:>6.0e} "
                     + " ".join(f"{r.first[k]:>8}" for k in kinds) + " "
                     + " ".join(f"{r.warm[k]:>8.3g}" for k in kinds))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies.preconditioners", description=__doc__.splitlines()[0])
    parser.add_argument("--only", choices=["iterations", "stiff", "heart", "trade"], default=None,
                        help="one table: trade is the CG iterations on the blocks of `deformgl bench trade --stiff` "
                             "and the FEM-checked cantilever")
    parser.add_argument("--quick", action="store_true", help="smaller sizes (the tests')")
    args = parser.parse_args(argv)
    from deformgl.bench.sim_speed import machine_line
    from deformgl.gl.context import create_context

    ctx = create_context()
    print(machine_line(ctx))
    if args.only in (None, "iterations"):
        rows = (iteration_rows((9, 17), (0.25,), (17,)) if args.quick else iteration_rows())
        print(format_iterations(rows), flush=True)
    if args.only in (None, "stiff"):
        print(format_stiff_rows(stiff_rows(ctx, (9,) if args.quick else (17, 33),
                                           0.25 if args.quick else 0.5)), flush=True)
    if args.only in (None, "heart"):
        print(format_frames(heart_frames(ctx, 2 if args.quick else 7)), flush=True)
    if args.only in (None, "trade"):
        print(format_preconditioners(preconditioner_iterations(preconditioner_bodies(stiff_cases(args.quick),
                                                                                     args.quick))), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
