"""``deformgl bench trade --stiff``: implicit Euler and XPBD against the explicit integrators on
stiff bodies.

Workloads (:data:`CASES`): a 0.1 m tissue cube (:data:`BLOCK`) of the calibrated lattice, clamped
at its base and sagging under gravity, at E = 3 kPa and 1 MPa and several resolutions. The
target is the lattice's equilibrium (:func:`~deformgl.bench.fem.static_displacement`, refined by
the float64 implicit reference where the system has at most
:data:`~deformgl.bench.fem.DIRECT_DOFS` free unknowns). Each run steps the fragment backend in
chunks of ``CHUNK`` s; after each chunk the largest node distance from the equilibrium is
compared with 0.05 h (:data:`VISUAL`) and with 5 % of the largest sag (:data:`REL`). Rows:
implicit Euler (Jacobi and multigrid CG), XPBD, and Verlet / semi-implicit Euler at 0.9 of their
limit; columns: wall s per simulated s, time to each criterion, the error at the end and against
FEM statics (:func:`~deformgl.bench.fem.fem_reference`, the 'fem' extra; NaN without it), and
implicit Euler's damping of the lowest mode, ``(1 + (w1 dt)^2)^(-1/(2 dt))`` per simulated second.
A scene in 60 Hz frames, implicit against explicit, is ``python -m studies.realtime``."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as spla

from deformgl.bench.fem import DIRECT_DOFS, LatticeCase, Workload, lattice_case, lattice_value, stiffness_matrix, \
    static_displacement
from deformgl.sim.implicit import ImplicitNumpySimulation
from deformgl.sim.integrators import State
from deformgl.sim.limits import dt_limit
from deformgl.sim.materials import ElasticMaterial
from deformgl.sim.simulation import make_simulation
from deformgl.sim.springs import SpringSystem

__all__ = ["BLOCK", "CASES", "block_material", "block_system", "StiffCase", "StiffRow", "stiff_cases", "stiff_study", "stiff_row", "format_stiff", "lowest_frequency",
           "fem_sag"]

CHUNK = 1.0 / 60.0
SIM_TIME, QUICK_SIM_TIME, FINE_SIM_TIME = 1.0, 0.25, 0.5
VISUAL = 0.05  # grid spacings
REL = 0.05     # of the equilibrium's largest sag
ALPHA = 20.0   # 1/s, Rayleigh mass damping of both materials
#: The 0.1 m cube clamped at its base (y = 0) under gravity; the top face's mean sag is measured.
BLOCK = Workload("block", (0.1, 0.1, 0.1), "gravity", 9.81, (1, 0), (1, 1), (5, 9, 17), "m")
#: (Young's modulus in Pa, nodes across) of the full and the quick study.
CASES = ((3.0e3, 5), (3.0e3, 9), (1.0e6, 5), (1.0e6, 9), (1.0e6, 17), (1.0e6, 25), (1.0e6, 33))
QUICK_CASES = ((3.0e3, 5), (1.0e6, 5))
FINE = 17
IMPLICIT_DTS, QUICK_IMPLICIT_DTS = (1 / 60, 1 / 250, 1 / 1000), (1 / 60,)
ITERATIONS, QUICK_ITERATIONS = (10, 30, 100), (10, 30)
#: (dt, CG iterations) of the finer grids.
FINE_IMPLICIT = ((1 / 60, 5), (1 / 60, 10), (1 / 60, 30), (1 / 250, 10))
#: (dt, CG iterations) of implicit Euler with the multigrid preconditioner (issue 29: its
#: iterations to a given residual do not grow with the grid, so the fine grids run the same set).
MULTIGRID, QUICK_MULTIGRID = ((1 / 60, 2), (1 / 60, 3), (1 / 60, 5)), ((1 / 60, 3),)
#: (iterations, substeps) of XPBD at dt = 1/60 s.
XPBD, QUICK_XPBD, FINE_XPBD = ((10, 1), (10, 10), (30, 30)), ((10, 4),), ((10, 10),)
EXPLICIT = ("verlet", "semi-implicit")


@dataclass(frozen=True)
class StiffCase:
    """A block of one material at one resolution, its equilibrium and its lowest mode."""

    name: str
    youngs_modulus: float
    across: int
    system: SpringSystem
    static: np.ndarray   # (N, 3) the equilibrium positions
    omega1: float        # rad/s, lowest undamped mode of the linearised lattice
    linear_gap: float    # grid spacings, the equilibrium's largest distance from the linear static solve (NaN: not refined)
    sag: float           # grid spacings, largest node displacement at equilibrium
    lattice: LatticeCase
    fem: float           # m, FEM's top-face mean sag (NaN without the 'fem' extra)

    @property
    def spacing(self) -> float:
        return float(self.system.spacing)


@dataclass(frozen=True)
class StiffRow:
    """One integrator x dt (x CG iterations, x XPBD iterations and substeps) on one case."""

    case: str
    youngs_modulus: float
    across: int
    nodes: int
    integrator: str
    dt: float
    iterations: int               # CG (implicit) or constraint (XPBD) iterations; 0 explicit
    substeps: int                 # XPBD substeps; 1 otherwise
    preconditioner: str           # implicit Euler's CG preconditioner (jacobi, block-jacobi, multigrid); "" otherwise
    wall_per_sim_s: float
    converged_at: float | None    # simulated s at which the error stays <= 0.05 h; None: not within the run
    wall_to_converge: float | None
    converged_rel_at: float | None  # the same for error <= REL x the equilibrium's sag
    wall_to_converge_rel: float | None
    final_error: float            # grid spacings, against the equilibrium
    relative_error: float         # final_error / the equilibrium's sag
    fem_error: float              # relative, top-face mean sag against FEM (NaN without it)
    mode_decay: float             # amplitude of the lowest mode left after 1 s of undamped stepping (NaN: XPBD)


def lowest_frequency(system: SpringSystem) -> float:
    """w1 in rad/s of the linearised lattice (free nodes; shift-invert Lanczos up to
    :data:`~deformgl.bench.fem.DIRECT_DOFS` unknowns, LOBPCG with an AMG preconditioner above)."""
    import scipy.sparse as sp

    dof = np.repeat(~system.fixed, 3)
    k = stiffness_matrix(system)[dof][:, dof].tocsr()
    m = np.repeat(system.mass, 3)[dof]
    if k.shape[0] <= DIRECT_DOFS:
        vals = spla.eigsh(k.tocsc(), k=1, M=sp.diags(m).tocsc(), sigma=0.0, which="LM", return_eigenvectors=False)
        return float(math.sqrt(max(float(vals[0]), 0.0)))
    import pyamg  # type: ignore[import-untyped,import-not-found,unused-ignore]

    ml = pyamg.smoothed_aggregation_solver(k.tobsr(blocksize=(3, 3)), symmetry="symmetric", max_coarse=1000)
    import warnings

    x0 = np.random.default_rng(0).normal(size=(k.shape[0], 2))
    with warnings.catch_warnings():  # (a residual above tol after maxiter: w1 to a few digits is enough here)
        warnings.simplefilter("ignore")
        vals, _ = spla.lobpcg(k, x0, B=sp.diags(m).tocsr(), M=ml.aspreconditioner(), largest=False, tol=1e-5,
                              maxiter=200)
    return float(math.sqrt(max(float(np.min(vals)), 0.0)))


def fem_sag(youngs_modulus: float, quick: bool = False) -> float:
    """FEM's top-face mean sag in m of :data:`BLOCK` (linear elasticity, nu = 0.25: solved once at
    1 MPa and scaled by 1 MPa / E; NaN without the 'fem' extra)."""
    key = bool(quick)
    if key not in _FEM_1MPA:
        from deformgl.bench.fem import fem_reference
        from deformgl.errors import DeformglError

        try:
            _FEM_1MPA[key], _, _ = fem_reference(BLOCK, (1, 2, 4) if quick else (2, 4, 8),
                                                 material=ElasticMaterial(1.0e6, 1060.0))
        except DeformglError:
            return math.nan
    return _FEM_1MPA[key] * 1.0e6 / youngs_modulus


_FEM_1MPA: dict[bool, float] = {}


def _equilibrium(system: SpringSystem, h: float) -> tuple[np.ndarray, float]:
    """(positions, distance in h from the linear static solve; NaN: not refined) (module docstring)."""
    u = static_displacement(system, system.mass[:, None] * system.gravity)
    linear = system.rest_positions + u
    if 3 * int(np.count_nonzero(~system.fixed)) > DIRECT_DOFS:
        return linear, math.nan
    ref = ImplicitNumpySimulation(system, CHUNK, solver="direct", state=State(linear, np.zeros_like(linear), linear))
    for _ in range(2000):
        ref.step()
        if ref.last_moved < 1e-6 * h:
            break
    x = ref.positions()
    return x, float(np.max(np.linalg.norm(x - linear, axis=1))) / h


def block_material(youngs_modulus: float = 1.0e6, poissons_ratio: float = 0.25) -> ElasticMaterial:
    """The study's tissue: ``youngs_modulus`` Pa, rho = 1060 kg/m^3, Rayleigh mass damping :data:`ALPHA`."""
    return ElasticMaterial(youngs_modulus, 1060.0, poissons_ratio=poissons_ratio, mass_damping=ALPHA,
                           name=f"E = {youngs_modulus:g} Pa")


def block_system(across: int, youngs_modulus: float = 1.0e6, poissons_ratio: float = 0.25) -> SpringSystem:
    """:data:`BLOCK` of :func:`block_material` on the lattice at ``across`` nodes across."""
    return lattice_case(BLOCK, across, block_material(youngs_modulus, poissons_ratio)).system


def stiff_cases(quick: bool = False, cases: tuple[tuple[float, int], ...] | None = None) -> list[StiffCase]:
    """The blocks of the study (module docstring): :data:`CASES` (``quick``: :data:`QUICK_CASES`)."""
    out = []
    for e, across in (cases if cases is not None else QUICK_CASES if quick else CASES):
        lattice = lattice_case(BLOCK, across, block_material(e))
        system = lattice.system
        h = float(system.spacing)
        x, gap = _equilibrium(system, h)
        sag = float(np.max(np.linalg.norm(x - system.rest_positions, axis=1))) / h
        out.append(StiffCase(f"block E={e:g} Pa, {across} across", e, across, system, x,
                             lowest_frequency(system), gap, sag, lattice, fem_sag(e, quick)))
    return out


def _run(ctx, case: StiffCase, integrator: str, dt: float, iterations: int, sim_time: float,
         substeps: int = 1, preconditioner: str = "jacobi") -> StiffRow:
    options: dict[str, object] = {}
    if integrator == "implicit-euler":
        options = {"cg_iterations": iterations, "cg_preconditioner": preconditioner}
    elif integrator == "xpbd":
        options = {"iterations": iterations, "substeps": substeps}
    per_chunk = max(1, round(CHUNK / dt))
    chunks = max(1, round(sim_time / (per_chunk * dt)))
    wall, error = 0.0, float("inf")
    at: dict[str, tuple[float, float] | None] = {"visual": None, "relative": None}
    limits = {"visual": VISUAL, "relative": REL * case.sag}
    x = case.system.rest_positions
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
            for key, limit in limits.items():
                if error <= limit:
                    if at[key] is None:
                        at[key] = (((c + 1) * per_chunk + 1) * dt, wall)
                else:
                    at[key] = None
    simulated = chunks * per_chunk * dt  # (the timed steps)
    decay = ((1.0 + (case.omega1 * dt) ** 2) ** (-0.5 / dt) if integrator == "implicit-euler"
             else math.nan if integrator == "xpbd" else 1.0)
    fem_error = (abs(lattice_value(case.lattice, x - case.system.rest_positions) - case.fem) / case.fem
                 if np.all(np.isfinite(x)) else math.inf)
    v, r = at["visual"], at["relative"]
    return StiffRow(case.name, case.youngs_modulus, case.across, case.system.count, integrator, dt, iterations,
                    substeps, preconditioner if integrator == "implicit-euler" else "", wall / simulated,
                    v and v[0], v and v[1], r and r[0], r and r[1], error,
                    error / case.sag if case.sag > 0 else math.nan, fem_error, decay)


def stiff_row(ctx, case: StiffCase, integrator: str, dt: float, iterations: int, sim_time: float, *,
              substeps: int = 1, preconditioner: str = "jacobi") -> StiffRow:
    """One row of the study: ``integrator`` at ``dt`` (implicit Euler: ``iterations`` CG
    iterations a step with ``preconditioner``; XPBD: ``iterations`` x ``substeps``) on ``case``
    for ``sim_time`` s, timed per chunk of :data:`CHUNK` s."""
    return _run(ctx, case, integrator, dt, iterations, sim_time, substeps, preconditioner)


def stiff_study(ctx, *, quick: bool = False, progress: Callable[[str], None] | None = None,
                cases: list[StiffCase] | None = None) -> list[StiffRow]:
    """Every case x (explicit at 0.9 of its limit, implicit dt x iterations with Jacobi and with
    multigrid (:data:`MULTIGRID`), XPBD iterations x substeps)."""
    rows = []
    for case in (stiff_cases(quick) if cases is None else cases):
        fine = not quick and case.across >= FINE
        sim_time = QUICK_SIM_TIME if quick else FINE_SIM_TIME if fine else SIM_TIME
        for name in EXPLICIT:
            dt = 0.9 * dt_limit(case.system, name).dt
            if progress:
                progress(f"{case.name}: {name} dt {dt:.3g} s")
            rows.append(_run(ctx, case, name, dt, 0, sim_time))
        implicit = (FINE_IMPLICIT if fine else
                    [(dt, its) for dt in (QUICK_IMPLICIT_DTS if quick else IMPLICIT_DTS)
                     for its in (QUICK_ITERATIONS if quick else ITERATIONS)])
        for kind, runs in (("jacobi", implicit), ("multigrid", QUICK_MULTIGRID if quick else MULTIGRID)):
            for dt, its in runs:
                if progress:
                    progress(f"{case.name}: implicit-euler ({kind}) dt {dt:.3g} s x {its} CG iterations")
                rows.append(_run(ctx, case, "implicit-euler", dt, its, sim_time, preconditioner=kind))
        for its, sub in (QUICK_XPBD if quick else FINE_XPBD if fine else XPBD):
            if progress:
                progress(f"{case.name}: xpbd dt {CHUNK:.3g} s x {its} iterations x {sub} substeps")
            rows.append(_run(ctx, case, "xpbd", CHUNK, its, sim_time, sub))
    return rows


def _best(rows: list[StiffRow], case: str, kind: str, relative: bool = False,
          preconditioner: str | None = None) -> StiffRow | None:
    done = [r for r in rows if r.case == case and _kind(r.integrator) == kind
            and (preconditioner is None or r.preconditioner == preconditioner)
            and (r.wall_to_converge_rel if relative else r.wall_to_converge) is not None]
    return min(done, key=lambda r: r.wall_per_sim_s) if done else None


def _kind(integrator: str) -> str:
    return integrator if integrator in ("implicit-euler", "xpbd") else "explicit"


def format_stiff(rows: list[StiffRow], machine: str = "", cases: list[StiffCase] | None = None) -> str:
    """The table and, per case and criterion, the cheapest converged implicit and XPBD rows
    against the cheapest explicit one."""
    head = [f"{c.name}: equilibrium sag {c.sag:.3g} h, {c.linear_gap:.3g} h from the linear static solve, "
            f"w1 {c.omega1:.4g} rad/s, {c.system.count} nodes, FEM top sag {c.fem:.4g} m" for c in (cases or [])]
    lines = [*head, f"Implicit Euler (Jacobi and multigrid CG) and XPBD vs explicit on stiff blocks (fragment backend)"
                    f"{'; ' + machine if machine else ''}",
             f"converged: every node within 0.05 h (visual) / within {REL:g} of the sag (rel.) of the "
             "lattice's equilibrium, staying there; FEM err: the top face's mean sag against FEM",
             f"{'case':<28} {'integrator':<15} {'precond.':<10} {'dt s':>9} {'it':>4} {'sub':>4} {'wall/sim s':>10} "
             f"{'visual at s':>11} {'wall':>7} {'rel. at s':>9} {'wall':>7} {'final err h':>11} {'/sag':>8} "
             f"{'FEM err':>8} {'mode left/s':>11}"]

    def opt(v: float | None, fmt: str) -> str:
        return "-" if v is None else format(v, fmt)

    for r in rows:
        its = "-" if r.integrator not in ("implicit-euler", "xpbd") else str(r.iterations)
        sub = str(r.substeps) if r.integrator == "xpbd" else "-"
        lines.append(f"{r.case:<28} {r.integrator:<15} {r.preconditioner or '-':<10} {r.dt:>9.3g} {its:>4} {sub:>4} "
                     f"{r.wall_per_sim_s:>10.3g} "
                     f"{opt(r.converged_at, '.3f'):>11} {opt(r.wall_to_converge, '.3g'):>7} "
                     f"{opt(r.converged_rel_at, '.3f'):>9} {opt(r.wall_to_converge_rel, '.3g'):>7} "
                     f"{r.final_error:>11.3g} {r.relative_error:>8.3g} {r.fem_error:>8.3g} {r.mode_decay:>11.3g}")
    lines.append("")
    lines.extend(verdicts(rows))
    return "\n".join(lines)


def verdicts(rows: list[StiffRow]) -> list[str]:
    """Per case and criterion: the cheapest converged implicit-Euler and XPBD rows against the
    cheapest converged explicit row, as a ratio of wall time per simulated second."""
    lines = []
    for case in dict.fromkeys(r.case for r in rows):
        for relative, label in ((False, "visual"), (True, f"{REL:g} of sag")):
            exp = _best(rows, case, "explicit", relative)
            methods = [("implicit-euler", p, f"implicit-euler ({p})") for p in
                       dict.fromkeys(r.preconditioner for r in rows if r.integrator == "implicit-euler")]
            for kind, pre, name in (*methods, ("xpbd", None, "xpbd")):
                best = _best(rows, case, kind, relative, pre)
                if best and exp:
                    ratio = exp.wall_per_sim_s / best.wall_per_sim_s
                    better = name if ratio > 1 else "explicit"
                    setting = (f"{best.iterations} it" if kind == "implicit-euler"
                               else f"{best.iterations} it x {best.substeps} sub")
                    lines.append(f"{case} ({label}): cheapest converged {name} (dt {best.dt:.3g} s, {setting}) "
                                 f"{best.wall_per_sim_s:.3g} s/sim s vs {exp.integrator} {exp.wall_per_sim_s:.3g}: "
                                 f"{max(ratio, 1 / ratio):.3g}x in favour of {better}")
                elif any(r.case == case and r.integrator == kind and (pre is None or r.preconditioner == pre)
                         for r in rows):
                    lines.append(f"{case} ({label}): {name} converged: {best is not None}, "
                                 f"explicit converged: {exp is not None}")
    return lines
