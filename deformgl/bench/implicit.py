"""Implicit Euler against the explicit integrators on stiff bodies: ``deformgl bench trade --stiff``.

Workloads: a tissue block (0.1 m cube, clamped at its base, sagging under gravity) of the calibrated
lattice (:func:`~deformgl.sim.materials.lattice_system`) at E = 3 kPa and E = 1 MPa (rho = 1060
kg/m^3, Rayleigh mass damping alpha), at two resolutions (nodes across the cube). The target is the
lattice's equilibrium under gravity, converged by the float64 implicit reference with a direct
solve (:mod:`deformgl.sim.implicit`, run until no node moves 1e-6 h in a step): at E = 3 kPa the
sag is a large strain and the nonlinear equilibrium differs from the linear static solve
(:func:`~deformgl.bench.fem.static_displacement`, what FEM statics is compared with in
docs/ACCURACY.md); the table's header line gives that difference and the static sag in h. Each run is on the fragment backend, stepped in chunks of ``CHUNK`` s of simulated
time; after each chunk the positions are read (not timed) and the largest node distance from the
static solution compared with ``0.05 h`` ("visually converged").

Rows: implicit Euler (:mod:`deformgl.sim.backends.implicit_gpu`) at dt = 1/60 ... 1/1000 s x CG
iterations per step, and Verlet / semi-implicit Euler at 0.9 of their stability limit
(:func:`~deformgl.sim.limits.dt_limit`). Columns: wall seconds per simulated second (GPU time
of the steps, ``ctx.finish()`` before the clock stops), the simulated time until the error stays
at or below 0.05 h, the wall time to get there, the error at the end, and for implicit Euler the
numerical damping of the lowest mode: ``|R|^(1/dt) = (1 + (w1 dt)^2)^(-1/(2 dt))`` per simulated
second, the amplitude left after one second by an exactly solved undamped backward-Euler step
(the explicit integrators at their limits keep it: |R| = 1 undamped).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as spla

from deformgl.bench.fem import stiffness_matrix, static_displacement
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.implicit import ImplicitNumpySimulation
from deformgl.sim.limits import dt_limit
from deformgl.sim.materials import ElasticMaterial, lattice_system
from deformgl.sim.simulation import make_simulation
from deformgl.sim.springs import SpringSystem

__all__ = ["StiffCase", "StiffRow", "stiff_cases", "stiff_study", "format_stiff", "lowest_frequency",
           "PreconditionerRow", "preconditioner_bodies", "preconditioner_iterations", "format_preconditioners"]

CHUNK = 1.0 / 60.0
SIM_TIME, QUICK_SIM_TIME = 1.0, 0.25
VISUAL = 0.05  # grid spacings
ALPHA = 20.0   # 1/s, Rayleigh mass damping of both materials
MODULI = (3.0e3, 1.0e6)
ACROSS, QUICK_ACROSS = (5, 9), (5,)
IMPLICIT_DTS, QUICK_IMPLICIT_DTS = (1 / 60, 1 / 250, 1 / 1000), (1 / 60,)
ITERATIONS, QUICK_ITERATIONS = (10, 30, 100), (10, 30)
EXPLICIT = ("verlet", "semi-implicit")


@dataclass(frozen=True)
class StiffCase:
    """A block of one material at one resolution, its static solution and its lowest mode."""

    name: str
    youngs_modulus: float
    across: int
    system: SpringSystem
    static: np.ndarray   # (N, 3) the converged equilibrium positions
    omega1: float        # rad/s, lowest undamped mode of the linearised lattice
    linear_gap: float    # grid spacings, largest node distance of the equilibrium from the linear static solve
    sag: float           # grid spacings, largest node displacement at equilibrium

    @property
    def spacing(self) -> float:
        return float(self.system.spacing)


@dataclass(frozen=True)
class StiffRow:
    """One integrator x dt (x CG iterations) on one case."""

    case: str
    integrator: str
    dt: float
    iterations: int
    wall_per_sim_s: float
    converged_at: float | None    # simulated s at which the error stays <= 0.05 h; None: not within the run
    wall_to_converge: float | None
    final_error: float            # grid spacings
    mode_decay: float             # amplitude of the lowest mode left after 1 s of undamped stepping


def lowest_frequency(system: SpringSystem) -> float:
    """w1 in rad/s of the linearised lattice (free nodes; shift-invert Lanczos)."""
    dof = np.repeat(~system.fixed, 3)
    k = stiffness_matrix(system)[dof][:, dof].tocsc()
    m = np.repeat(system.mass, 3)[dof]
    import scipy.sparse as sp

    vals = spla.eigsh(k, k=1, M=sp.diags(m).tocsc(), sigma=0.0, which="LM", return_eigenvectors=False)
    return float(math.sqrt(max(float(vals[0]), 0.0)))


def stiff_cases(quick: bool = False) -> list[StiffCase]:
    """The blocks of the study (module docstring)."""
    cases = []
    for e in MODULI:
        material = ElasticMaterial(e, 1060.0, mass_damping=ALPHA, name=f"E = {e:g} Pa")
        for across in (QUICK_ACROSS if quick else ACROSS):
            h = 0.1 / (across - 1)
            grid = NodeGrid(np.zeros(3), h, np.ones((across,) * 3, bool))
            fixed = grid.ijk[:, 1] == 0
            system, _ = lattice_system(grid, material, fixed=fixed)
            u = static_displacement(system, system.mass[:, None] * system.gravity)
            ref = ImplicitNumpySimulation(system, CHUNK, solver="direct")
            for _ in range(2000):
                ref.step()
                if ref.last_moved < 1e-6 * h:
                    break
            x = ref.positions()
            gap = float(np.max(np.linalg.norm(x - system.rest_positions - u, axis=1))) / h
            sag = float(np.max(np.linalg.norm(x - system.rest_positions, axis=1))) / h
            cases.append(StiffCase(f"block E={e:g} Pa, {across} across", e, across, system, x,
                                   lowest_frequency(system), gap, sag))
    return cases


def _run(ctx, case: StiffCase, integrator: str, dt: float, iterations: int, sim_time: float) -> StiffRow:
    options = {"cg_iterations": iterations} if integrator == "implicit-euler" else {}
    per_chunk = max(1, round(CHUNK / dt))
    chunks = max(1, round(sim_time / (per_chunk * dt)))
    wall, converged_at, wall_at, error = 0.0, None, None, float("inf")
    with make_simulation(case.system, integrator, "fragment", dt=dt, ctx=ctx, **options) as sim:
        sim.step(1)  # untimed: the passes compile on their first draw (llvmpipe)
        for c in range(chunks):
            ctx.finish()
            start = time.perf_counter()
            sim.step(per_chunk)
            ctx.finish()
            wall += time.perf_counter() - start
            x = sim.positions().astype(np.float64)
            error = float(np.max(np.linalg.norm(x - case.static, axis=1))) / case.spacing \
                if np.all(np.isfinite(x)) else float("inf")
            if error <= VISUAL:
                if converged_at is None:
                    converged_at, wall_at = ((c + 1) * per_chunk + 1) * dt, wall
            else:
                converged_at = wall_at = None
    simulated = chunks * per_chunk * dt  # (the timed steps)
    decay = (1.0 + (case.omega1 * dt) ** 2) ** (-0.5 / dt) if integrator == "implicit-euler" else 1.0
    return StiffRow(case.name, integrator, dt, iterations, wall / simulated, converged_at, wall_at, error, decay)


def stiff_study(ctx, *, quick: bool = False, progress: Callable[[str], None] | None = None,
                cases: list[StiffCase] | None = None) -> list[StiffRow]:
    """Every case x (implicit dt x iterations, explicit at 0.9 of its limit)."""
    sim_time = QUICK_SIM_TIME if quick else SIM_TIME
    rows = []
    for case in (stiff_cases(quick) if cases is None else cases):
        for name in EXPLICIT:
            dt = 0.9 * dt_limit(case.system, name).dt
            if progress:
                progress(f"{case.name}: {name} dt {dt:.3g} s")
            rows.append(_run(ctx, case, name, dt, 0, sim_time))
        for dt in (QUICK_IMPLICIT_DTS if quick else IMPLICIT_DTS):
            for its in (QUICK_ITERATIONS if quick else ITERATIONS):
                if progress:
                    progress(f"{case.name}: implicit-euler dt {dt:.3g} s x {its} CG iterations")
                rows.append(_run(ctx, case, "implicit-euler", dt, its, sim_time))
    return rows


def _best(rows: list[StiffRow], case: str, implicit: bool) -> StiffRow | None:
    done = [r for r in rows if r.case == case and (r.integrator == "implicit-euler") == implicit
            and r.wall_to_converge is not None]
    return min(done, key=lambda r: r.wall_per_sim_s) if done else None


def format_stiff(rows: list[StiffRow], machine: str = "", cases: list[StiffCase] | None = None) -> str:
    """The table and, per case, the cheapest converged implicit row against the cheapest explicit one."""
    head = [f"{c.name}: equilibrium sag {c.sag:.3g} h, {c.linear_gap:.3g} h from the linear static solve, "
            f"w1 {c.omega1:.4g} rad/s, {c.system.count} nodes" for c in (cases or [])]
    lines = [*head, f"Implicit Euler vs explicit on stiff blocks (fragment backend){'; ' + machine if machine else ''}",
             "visually converged: every node within 0.05 h of the lattice's static solution, staying there",
             f"{'case':<28} {'integrator':<15} {'dt s':>9} {'CG it':>5} {'wall/sim s':>10} {'conv. at s':>10} "
             f"{'wall to conv.':>13} {'final err h':>11} {'mode left/s':>11}"]
    for r in rows:
        conv = "-" if r.converged_at is None else f"{r.converged_at:.3f}"
        wall = "-" if r.wall_to_converge is None else f"{r.wall_to_converge:.3g}"
        its = "-" if r.integrator != "implicit-euler" else str(r.iterations)
        lines.append(f"{r.case:<28} {r.integrator:<15} {r.dt:>9.3g} {its:>5} {r.wall_per_sim_s:>10.3g} {conv:>10} "
                     f"{wall:>13} {r.final_error:>11.3g} {r.mode_decay:>11.3g}")
    lines.append("")
    for case in dict.fromkeys(r.case for r in rows):
        imp, exp = _best(rows, case, True), _best(rows, case, False)
        if imp and exp:
            ratio = exp.wall_per_sim_s / imp.wall_per_sim_s
            better = "implicit" if ratio > 1 else "explicit"
            lines.append(f"{case}: cheapest converged implicit (dt {imp.dt:.3g} s, {imp.iterations} it) "
                         f"{imp.wall_per_sim_s:.3g} s/sim s vs {exp.integrator} {exp.wall_per_sim_s:.3g}: "
                         f"{max(ratio, 1 / ratio):.3g}x in favour of {better}")
        else:
            lines.append(f"{case}: implicit converged: {imp is not None}, explicit converged: {exp is not None}")
    return "\n".join(lines)


@dataclass(frozen=True)
class PreconditionerRow:
    """CG iterations to a relative tolerance, per preconditioner, on one case at one dt."""

    case: str
    dt: float
    tolerance: float
    first: dict[str, int]     # the first step's solve from dv = 0
    warm: dict[str, float]    # mean per step over QUICK_SIM_TIME of warm-started steps


def preconditioner_bodies(cases: list[StiffCase], quick: bool = False) -> list[tuple[str, SpringSystem]]:
    """The study's blocks and the FEM-checked cantilever (E = 1e8 Pa, 3 or 5 nodes across)."""
    from deformgl.bench.fem import MATERIAL, WORKLOADS, lattice_case

    across = 3 if quick else 5
    beam = lattice_case(WORKLOADS["cantilever"], across, MATERIAL).system
    return [(c.name, c.system) for c in cases] + [(f"cantilever E=1e8 Pa, {across} across", beam)]


def preconditioner_iterations(bodies: list[tuple[str, SpringSystem]], *,
                              dts: tuple[float, ...] = (1 / 60, 1 / 1000),
                              tolerance: float = 1e-4) -> list[PreconditionerRow]:
    """Jacobi against block-Jacobi (:data:`~deformgl.sim.implicit.PRECONDITIONERS`) on (name,
    system) bodies: CG iterations to ``tolerance`` (the float64 reference, the GPU's iteration)
    on the first step from rest and averaged over the warm-started steps of
    :data:`QUICK_SIM_TIME` s."""
    from deformgl.sim.implicit import PRECONDITIONERS

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
    lines = ["CG iterations to a relative residual, Jacobi vs block-Jacobi (float64 reference): first step "
             f"from dv = 0, and the mean over {QUICK_SIM_TIME:g} s of warm-started steps",
             f"{'case':<32} {'dt s':>8} {'tol':>6} {'first J':>8} {'first BJ':>8} {'warm J':>8} {'warm BJ':>8}"]
    for r in rows:
        lines.append(f"{r.case:<32} {r.dt:>8.3g} {r.tolerance:>6.0e} {r.first['jacobi']:>8} "
                     f"{r.first['block-jacobi']:>8} {r.warm['jacobi']:>8.3g} {r.warm['block-jacobi']:>8.3g}")
    return "\n".join(lines)


@dataclass(frozen=True)
class RealtimeRow:
    """One integrator on a scene: frames of 1/60 s of simulated time per wall second."""

    integrator: str
    dt: float
    steps_per_frame: int
    iterations: int
    fps: float
    residual: float | None   # implicit: the last step's relative CG residual


def realtime(ctx, scene: str = "heart.toml", *, frames: int = 10,
             iterations: tuple[int, ...] = (10, 20), progress: Callable[[str], None] | None = None
             ) -> tuple[list[RealtimeRow], float, int]:
    """Implicit Euler at dt = 1/60 s (one step per 60 Hz frame) against the scene's explicit
    integrator at its dt, on the fragment backend, ``frames`` frames each (GPU time of the steps,
    after one untimed step). Returns the rows, the largest node distance in grid spacings between
    the implicit (most iterations) and explicit positions after the frames, and the node count."""
    from deformgl.data import scene_file
    from deformgl.scene.pipeline import build_scene_model
    from deformgl.scene.schema import load_scene

    spec = load_scene(scene_file(scene))
    model = build_scene_model(spec)
    physics = spec.physics
    rows: list[RealtimeRow] = []
    ends: dict[str, np.ndarray] = {}

    def timed(name: str, dt: float, per_frame: int, its: int) -> None:
        options = {"cg_iterations": its} if name == "implicit-euler" else {}
        if progress:
            progress(f"{spec.source.name}: {name} dt {dt:.3g} s x {per_frame} steps per frame"
                     + (f", {its} CG iterations" if its else ""))
        with make_simulation(model.system, name, "fragment", dt=dt, ctx=ctx, loads=model.loads, **options) as sim:
            sim.step(1)
            ctx.finish()
            start = time.perf_counter()
            sim.step(frames * per_frame - 1)
            ctx.finish()
            wall = time.perf_counter() - start
            residual = sim.residual() if name == "implicit-euler" else None  # type: ignore[attr-defined]
            ends[name] = sim.positions().astype(np.float64)
        rows.append(RealtimeRow(name, dt, per_frame, its, (frames - 1 / per_frame) / wall, residual))

    for its in iterations:
        timed("implicit-euler", CHUNK, 1, its)
    timed(physics.integrator, physics.dt, max(1, round(CHUNK / physics.dt)), 0)
    gap = float(np.max(np.linalg.norm(ends["implicit-euler"] - ends[physics.integrator], axis=1))) / model.grid.spacing
    return rows, gap, model.system.count


def format_realtime(rows: list[RealtimeRow], gap: float, nodes: int, scene: str, machine: str = "") -> str:
    lines = [f"Real time on {scene} ({nodes} nodes, fragment backend){'; ' + machine if machine else ''}: "
             "frames of 1/60 s simulated per wall second",
             f"{'integrator':<15} {'dt s':>9} {'steps/frame':>11} {'CG it':>5} {'fps':>8} {'CG residual':>11}"]
    for r in rows:
        res = "-" if r.residual is None else f"{r.residual:.2g}"
        its = str(r.iterations) if r.iterations else "-"
        lines.append(f"{r.integrator:<15} {r.dt:>9.3g} {r.steps_per_frame:>11} {its:>5} {r.fps:>8.3g} {res:>11}")
    lines.append(f"largest node distance implicit vs explicit after the frames: {gap:.3g} h")
    return "\n".join(lines)
