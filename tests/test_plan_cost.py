"""The plan's cost model (deformgl.plan.cost) against the passes the backends really draw."""

from __future__ import annotations

import numpy as np
import pytest

from deformgl.grid.nodes import NodeGrid
from deformgl.plan.cost import (RATES, Work, coarse_counts, explicit_passes, explicit_work, implicit_passes,
                                implicit_work, layout_texels)

STIFF = dict(youngs_modulus=1.0e6, density=1060.0)


def _block(across: int, poissons_ratio: float = 0.25):
    from deformgl.sim.materials import ElasticMaterial, lattice_system

    grid = NodeGrid(np.zeros(3), 0.1 / (across - 1), np.ones((across, across, across), bool))
    material = ElasticMaterial(**STIFF, poissons_ratio=poissons_ratio)
    system, _ = lattice_system(grid, material, fixed=grid.ijk[:, 1] == 0)
    return system


def _record(sim, monkeypatch) -> tuple[list[tuple[str, int]], list[str]]:
    """Run one step of an implicit fragment simulation, recording (pass, texels drawn) and the sums."""
    drawn: list[tuple[str, int]] = []
    sums: list[str] = []
    ctx = sim.ctx

    def texels() -> int:
        _, _, w, h = ctx.fbo.viewport
        return int(w * h)

    draw, total = sim._draw, sim._sum

    def record_draw(name, reads, writes):
        draw(name, reads, writes)
        drawn.append((name, texels()))

    def record_sum(target):
        sums.append(target)
        total(target)

    monkeypatch.setattr(sim, "_draw", record_draw)
    monkeypatch.setattr(sim, "_sum", record_sum)
    if sim.mg is not None:
        mg_draw = sim.mg._draw

        def record_mg(name, uniforms, reads, *targets, **defines):
            mg_draw(name, uniforms, reads, *targets, **defines)
            drawn.append((name + ("_ZERO" if defines.get("FROM_ZERO") else ""), texels()))

        monkeypatch.setattr(sim.mg, "_draw", record_mg)
    sim.step(1)
    return drawn, sums


@pytest.mark.parametrize("preconditioner,tolerance", [("jacobi", 0.0), ("multigrid", 0.0), ("multigrid", 1e-30)])
def test_the_implicit_model_lists_the_passes_a_step_draws(ctx, monkeypatch, preconditioner, tolerance) -> None:
    """One implicit step of a 9-across block draws exactly the model's passes, in order, each
    over the model's texels, and sums as many times as the model's reductions."""
    from deformgl.sim.simulation import make_simulation

    system = _block(9)
    iterations = 3
    with make_simulation(system, "implicit-euler", "fragment", dt=1 / 60, ctx=ctx, cg_iterations=iterations,
                         cg_preconditioner=preconditioner, cg_tolerance=tolerance, cg_check_every=1) as sim:
        drawn, sums = _record(sim, monkeypatch)
        coarse = [int(lv["count"]) for lv in sim.mg.levels] if sim.mg is not None else None
    model, reductions, reads = implicit_passes(system.count, iterations, preconditioner, coarse=coarse,
                                               tolerance=tolerance > 0)
    assert coarse is None or coarse == coarse_counts((9, 9, 9)), coarse
    assert [(p.name, p.texels) for p in model] == drawn
    assert reductions == len(sums)
    assert reads == (iterations + 2 if tolerance > 0 else 0)


@pytest.mark.parametrize("integrator", ["verlet", "semi-implicit", "rk4"])
def test_the_explicit_model_lists_the_passes_a_step_draws(ctx, monkeypatch, integrator) -> None:
    """One explicit step draws the model's passes (Verlet the foundation pass, the others their
    stages), each over the compact layout's texels."""
    import moderngl

    from deformgl.sim.simulation import make_simulation

    system = _block(9)
    drawn: list[int] = []
    render = moderngl.VertexArray.render

    def record(self, *args, **kwargs):
        render(self, *args, **kwargs)
        _, _, w, h = ctx.fbo.viewport
        drawn.append(int(w * h))

    with make_simulation(system, integrator, "fragment", dt=1e-5, ctx=ctx) as sim:
        sim.step(1)   # (compiles)
        monkeypatch.setattr(moderngl.VertexArray, "render", record)
        sim.step(1)
        monkeypatch.undo()
    model = explicit_passes(system.count, integrator)
    assert [p.texels for p in model] == drawn


def test_work_prices_units_and_the_multigrid_step_grows_slower_than_jacobis() -> None:
    """The units add and price linearly; a V-cycle costs several fine passes, so a multigrid
    iteration is dearer than a Jacobi one, but the iterations Jacobi needs grow with the grid
    (issue 29's measurements, 29 -> 245 from 9 to 65 across) and multigrid's do not (6 -> 8):
    at 65 across the multigrid solve is the cheaper one, at 9 across the dearer."""
    a = Work(2, (100, 10, 1), 1, 0)
    assert a + a == a.times(2) == Work(4, (200, 20, 2), 2, 0) and a.fetches == 111
    assert a.seconds() == pytest.approx(2 * RATES.pass_s + 100 * RATES.fetch_s[0] + 10 * RATES.fetch_s[1]
                                        + RATES.fetch_s[2] + RATES.reduction_s)
    assert coarse_counts((3, 3, 3)) == [8] and coarse_counts((2, 2, 2)) == []
    assert coarse_counts((65, 65, 65)) == [33 ** 3, 17 ** 3, 9 ** 3, 125, 27]
    # every box, even and odd sides, as the multigrid coarsens it (grid_levels on the full box)
    from deformgl.sim.multigrid import grid_levels
    for shape in ((4, 4, 4), (10, 10, 10), (20, 5, 5), (9, 6, 7), (16, 16, 16), (3, 2, 2)):
        box = np.ones(shape, bool)
        assert coarse_counts(shape) == [p.shape[1] for p in grid_levels(box, np.argwhere(box))], shape
    assert layout_texels(9 ** 3) == 32 * 23 and layout_texels(1) == 16

    def solve(across: int, iterations: int, preconditioner: str) -> float:
        n = across ** 3
        coarse = coarse_counts((across,) * 3) if preconditioner == "multigrid" else None
        return implicit_work(n, iterations, preconditioner, coarse=coarse).seconds()

    assert solve(65, 8, "multigrid") < solve(65, 245, "jacobi") / 3
    assert solve(9, 6, "multigrid") < solve(9, 29, "jacobi") * 2
    # the cells' term adds fetches to the force and product passes only
    assert explicit_work(729, "verlet", cells=True).fetches > explicit_work(729, "verlet").fetches
    assert explicit_work(729, "verlet", cells=True).passes == 1
    with pytest.raises(ValueError, match="coarse levels"):
        implicit_passes(729, 3, "multigrid")


def test_the_rates_fit_recovers_known_rates_and_prints_its_error(ctx) -> None:
    """``python -m studies.plan_rates``'s fit: times made from known rates give those rates
    back (every unit is determined by the configurations), and the table shows model/measured 1.00;
    a read is timed apart and costs something."""
    from studies.plan_rates import configs, fit_rates, format_rates, read_seconds
    from deformgl.plan.cost import Rates

    cases = configs((5, 9, 17))
    known = Rates(2e-4, (2e-9, 1.5e-9, 1.5e-8), 4e-4, 0.0)
    seconds = [c.work.seconds(known) for c in cases]
    fitted = fit_rates(cases, seconds)
    assert fitted.pass_s == pytest.approx(known.pass_s, rel=1e-6)
    assert fitted.fetch_s == pytest.approx(known.fetch_s, rel=1e-6)
    assert fitted.reduction_s == pytest.approx(known.reduction_s, rel=1e-6)
    text = format_rates(cases, [[t, t] for t in seconds], fitted)
    assert text.count(" 1.00\n") == len(cases) - 1 and "pass 200 us" in text
    assert read_seconds(ctx, reads=20) >= 0.0
