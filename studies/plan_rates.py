"""``python -m studies.plan_rates``: the renderer's price of a pass, a texel fetch, a
reduction and a scalar read (:class:`deformgl.plan.cost.Rates`), fitted to timed steps.

Steps of the stiff block (:data:`~deformgl.bench.trade_stiff.BLOCK`, E = 1 MPa, nu = 1/4, and one
at nu = 0.45 for the cells' term) at several resolutions on the fragment backend: Verlet and
semi-implicit Euler, implicit Euler with Jacobi CG (10 and 30 iterations) and multigrid CG (3
and 8) at fixed iteration counts. All simulations are built first; each round times every
configuration once (``ctx.finish()`` around the steps), in turn; the median of the rounds is
the measured time per step. The rates are the non-negative least squares fit of ``seconds =
passes pass_s + sum_k fetches_k fetch_s[k] + reductions reduction_s`` (:func:`deformgl.plan.cost.work`)
relative to each measured time (every configuration weighs alike). A scalar read (a solve with a
tolerance) is timed apart: a 1 x 1 texture cleared and read back, less the clear alone. The table
gives each configuration's units, its measured and predicted time and their ratio, so the fit's
error is on the page.
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from deformgl.plan.cost import Rates, Work, coarse_counts, explicit_work, implicit_work

__all__ = ["Config", "configs", "measure", "read_seconds", "fit_rates", "format_rates", "main"]


@dataclass(frozen=True)
class Config:
    """One timed configuration and its units per step."""

    label: str
    across: int
    poissons_ratio: float
    integrator: str
    options: dict
    steps: int
    work: Work


def configs(across: tuple[int, ...] = (9, 17, 33)) -> list[Config]:
    """The configurations of the fit (module docstring)."""
    out = []
    for n in across:
        nodes = n ** 3
        coarse = coarse_counts((n, n, n))
        for nu in (0.25, 0.45) if n == across[len(across) // 2] else (0.25,):
            cells = nu > 0.25
            tag = f"{n} across, nu {nu:g}"
            steps = max(2, 4000 // n ** 2)
            out.append(Config(f"verlet, {tag}", n, nu, "verlet", {}, steps * 10,
                              explicit_work(nodes, "verlet", cells=cells)))
            if not cells:
                out.append(Config(f"semi-implicit, {tag}", n, nu, "semi-implicit", {}, steps * 10,
                                  explicit_work(nodes, "semi-implicit")))
            for its in (10, 30):
                out.append(Config(f"implicit jacobi {its} it, {tag}", n, nu, "implicit-euler",
                                  {"cg_iterations": its, "cg_preconditioner": "jacobi"}, steps,
                                  implicit_work(nodes, its, "jacobi", cells=cells)))
            for its in (3, 8):
                out.append(Config(f"implicit multigrid {its} it, {tag}", n, nu, "implicit-euler",
                                  {"cg_iterations": its, "cg_preconditioner": "multigrid"}, steps,
                                  implicit_work(nodes, its, "multigrid", coarse=coarse, cells=cells)))
    return out


def measure(ctx, cases: list[Config], rounds: int = 5) -> list[list[float]]:
    """Seconds per step of each configuration in each round (the configurations alternate)."""
    from deformgl.bench.trade_stiff import block_system
    from deformgl.sim.limits import dt_limit
    from deformgl import make_simulation

    sims = []
    try:
        for c in cases:
            system = block_system(c.across, poissons_ratio=c.poissons_ratio)
            dt = 1 / 60 if c.integrator == "implicit-euler" else 0.9 * dt_limit(system, c.integrator).dt
            sim = make_simulation(system, c.integrator, "fragment", dt=dt, ctx=ctx, **c.options)
            sims.append(sim)
            sim.step(1)  # (compiles)
        times: list[list[float]] = [[] for _ in cases]
        for _ in range(rounds):
            for i, (c, sim) in enumerate(zip(cases, sims)):
                ctx.finish()
                start = time.perf_counter()
                sim.step(c.steps)
                ctx.finish()
                times[i].append((time.perf_counter() - start) / c.steps)
        return times
    finally:
        for sim in sims:
            sim.release()


def read_seconds(ctx, reads: int = 200) -> float:
    """Seconds of one scalar read: a 1 x 1 RGBA32F texture cleared and read back, less the clear."""
    from deformgl.gl.es_context import read_texture

    tex = ctx.texture((1, 1), 4, dtype="f4")
    fbo = ctx.framebuffer(color_attachments=[tex])
    try:
        def run(read: bool) -> float:
            ctx.finish()
            start = time.perf_counter()
            for i in range(reads):
                fbo.clear(float(i), 0.0, 0.0, 0.0)
                if read:
                    read_texture(tex)
            ctx.finish()
            return (time.perf_counter() - start) / reads
        with_read = statistics.median(run(True) for _ in range(5))
        without = statistics.median(run(False) for _ in range(5))
        return max(with_read - without, 0.0)
    finally:
        fbo.release()
        tex.release()


def fit_rates(cases: list[Config], seconds: list[float], read_s: float = 0.0, renderer: str = "") -> Rates:
    """Non-negative least squares of the units against the measured seconds, relative to each."""
    a = np.array([[c.work.passes, *c.work.by_kind, c.work.reductions] for c in cases], float)
    t = np.asarray(seconds, float)
    scale = a.max(axis=0)
    scale[scale == 0] = 1.0
    x, _ = scipy.optimize.nnls(a / scale / t[:, None], np.ones(len(t)))
    x = x / scale
    return Rates(float(x[0]), (float(x[1]), float(x[2]), float(x[3])), float(x[4]), read_s, renderer)


def format_rates(cases: list[Config], times: list[list[float]], rates: Rates) -> str:
    f = rates.fetch_s
    lines = [f"fitted: pass {rates.pass_s * 1e6:.4g} us; texel fetch {f[0] * 1e9:.4g} ns (force), "
             f"{f[1] * 1e9:.4g} ns (product), {f[2] * 1e9:.4g} ns (other); reduction {rates.reduction_s * 1e6:.4g} us; "
             f"read {rates.read_s * 1e6:.4g} us (timed apart)",
             f"{'configuration':<40} {'passes':>7} {'Mfetch':>8} {'red.':>5} {'ms/step':>9} "
             f"{'spread':>7} {'model ms':>9} {'model/meas.':>11}"]
    for c, ts in zip(cases, times):
        med = statistics.median(ts)
        model = c.work.seconds(rates)
        lines.append(f"{c.label:<40} {c.work.passes:>7} {c.work.fetches / 1e6:>8.3g} {c.work.reductions:>5} "
                     f"{med * 1e3:>9.3g} {(max(ts) - min(ts)) / med:>7.0%} {model * 1e3:>9.3g} "
                     f"{model / med:>11.2f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies.plan_rates", description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--quick", action="store_true", help="5 and 9 across, 2 rounds (a smoke run)")
    args = parser.parse_args(argv)
    from deformgl.bench.sim_speed import machine_line
    from deformgl.gl.context import create_context

    ctx = create_context()
    try:
        cases = configs((5, 9) if args.quick else (9, 17, 33))
        times = measure(ctx, cases, 2 if args.quick else args.rounds)
        line = machine_line(ctx)
        rates = fit_rates(cases, [statistics.median(t) for t in times], read_seconds(ctx), line)
        print(line)
        print(format_rates(cases, times, rates))
    finally:
        ctx.release()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
