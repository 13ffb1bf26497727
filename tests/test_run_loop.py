"""The one run (deformgl.sim.run.run): the dt check, a simulation built for the
plan's step, the run loop with the blow-up watch and the convergence stop, the restarts of
"subdivide"; one RunResult; messages worded for the caller (scene keys or API arguments)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from deformgl.errors import ArgumentError, SimulationError
from deformgl.grid.nodes import NodeGrid
from deformgl.sim import springs
from deformgl.sim.guards import API_WORDING, MAX_SUBSTEPS, SCENE_WORDING, BlowUp, StepPlan, retry_with_substeps
from deformgl.sim.run import RunResult, run
from deformgl.sim.simulation import BACKENDS, Simulation, make_simulation
from deformgl.sim.limits import dt_limit


@dataclass(frozen=True)
class Policy:
    unstable: str = "refuse"


@dataclass(frozen=True)
class Settings:
    """A :class:`~deformgl.sim.guards.StepSettings` of the tests."""

    dt: float
    steps: int
    integrator: str = "semi-implicit"
    safety: Policy = field(default_factory=Policy)


def small(gravity=(0.0, -9.81, 0.0)):
    grid = NodeGrid(np.array([0.2, 0.5, -0.1]), 0.1, np.ones((3, 3, 3), bool))
    fixed = np.zeros(grid.count, bool)
    fixed[0] = True
    system = springs.from_grid(grid, k_structural=50.0, k_shear=20.0, mass=0.1, fixed=fixed, gravity=gravity,
                               velocity_damping=0.02)
    return system, grid


class Maker:
    """``make(dt)`` that records the steps asked for and every simulation it made; the test
    releases them (run releases none)."""

    def __init__(self, ctx, system, grid, backend, integrator="semi-implicit"):
        self.ctx, self.system, self.grid, self.backend, self.integrator = ctx, system, grid, backend, integrator
        self.dts: list[float] = []
        self.made: list[Simulation] = []

    def __call__(self, dt: float) -> Simulation:
        self.dts.append(dt)
        sim = make_simulation(self.system, self.integrator, self.backend, dt=dt,
                              ctx=None if self.backend == "numpy" else self.ctx, grid=self.grid)
        self.made.append(sim)
        return sim

    def release(self) -> None:
        for sim in self.made:
            sim.release()


def guarded(maker, settings, **kw):
    kw.setdefault("source", "t.toml")
    kw.setdefault("limit", 10.0)
    kw.setdefault("check_every", 20)
    kw.setdefault("wording", SCENE_WORDING)
    return run(maker, settings=settings, system=maker.system, ctx=None if maker.backend == "numpy" else maker.ctx,
               grid=maker.grid, **kw)


def test_one_run_result_whose_old_constructions_still_work():
    assert RunResult(20, True) == RunResult(20, True, substeps=1, dt=None, time=None, notes=())
    assert RunResult(5, None, 2, 0.01, 0.05, ("x",)).notes == ("x",)


def test_a_stable_run_is_planned_built_and_run_once():
    system, grid = small()
    maker = Maker(None, system, grid, "numpy")
    try:
        result = guarded(maker, Settings(1e-3, 30))
        assert maker.dts == [1e-3] and len(maker.made) == 1
        assert result == RunResult(30, None, 1, 1e-3, pytest.approx(0.03), ())
        assert maker.made[0].time == pytest.approx(result.time)
    finally:
        maker.release()


def test_a_refused_dt_builds_nothing_and_is_worded_for_its_caller():
    system, grid = small()
    limit = dt_limit(system, "semi-implicit").dt
    maker = Maker(None, system, grid, "numpy")
    with pytest.raises(SimulationError) as scene:
        guarded(maker, Settings(1.5 * limit, 10))
    assert str(scene.value).startswith("t.toml: physics.dt: dt ")
    assert "--allow-unstable" in str(scene.value) and "(physics.safety.unstable)" in str(scene.value)
    with pytest.raises(SimulationError) as api:
        guarded(maker, Settings(1.5 * limit, 10), source="<arrays>", wording=API_WORDING)
    text = str(api.value)
    assert text.startswith("<arrays>: dt ") and 'unstable="run"' in text and 'unstable="subdivide"' in text
    assert "physics." not in text and "--" not in text
    assert maker.dts == []  # refused before any simulation


def test_a_subdivided_plan_runs_its_substeps_and_notes_it():
    system, grid = small()
    limit = dt_limit(system, "semi-implicit").dt
    maker = Maker(None, system, grid, "numpy")
    notes = ["earlier"]
    try:
        result = guarded(maker, Settings(2.5 * limit, 10, safety=Policy("subdivide")), notes=notes)
        k = result.substeps
        assert k >= 3 and maker.dts == [pytest.approx(2.5 * limit / k)]
        assert result.steps == 10 * k and result.dt == pytest.approx(2.5 * limit / k)
        assert result.time == pytest.approx(10 * 2.5 * limit)
        assert len(result.notes) == 1 and f"{k} substeps" in result.notes[0]
        assert notes == ["earlier", *result.notes]  # the caller's list gets them, the result only this run's
    finally:
        maker.release()


@pytest.mark.parametrize("backend", BACKENDS)
def test_convergence_is_per_step_asked_for_on_every_backend(ctx, backend):
    """``converge`` is per step asked for: with k substeps, threshold / k every ``every * k``."""
    system, grid = small(gravity=(0.0, 0.0, 0.0))  # at rest, no load: converged at the first test
    maker = Maker(ctx, system, grid, backend)
    try:
        result = guarded(maker, Settings(1e-3, 100), converge=(1e-9, 20))
        assert (result.steps, result.converged) == (20, True)
        plan = StepPlan(1e-3, 100, 4)
        result = guarded(maker, Settings(1e-3, 100), converge=(1e-9, 20), plan=plan)
        assert (result.steps, result.converged, result.substeps) == (80, True, 4)
        assert maker.dts[-1] == pytest.approx(2.5e-4)
        sagging, _ = small()
        maker.system = sagging
        result = guarded(maker, Settings(1e-3, 40), converge=(0.0, 20))
        assert (result.steps, result.converged) == (40, False)
    finally:
        maker.release()


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the blown-up NumPy runs overflow on purpose
@pytest.mark.parametrize("backend", BACKENDS)
def test_a_blow_up_restarts_with_twice_the_substeps_on_every_backend(ctx, backend):
    """A plan forced past the dt check (1 substep at 4x the Gershgorin limit): the watch sees the
    blow-up, each restart gets a fresh simulation at half the step, until one holds."""
    system, grid = small()
    limit = dt_limit(system, "semi-implicit", exact=False).dt
    maker = Maker(ctx, system, grid, backend)
    try:
        result = guarded(maker, Settings(4 * limit, 60, safety=Policy("subdivide")), plan=StepPlan(4 * limit, 60))
        k = len(result.notes)
        assert 2 <= k <= 3, result.notes
        assert maker.dts == [pytest.approx(4 * limit / 2 ** i) for i in range(k + 1)]
        assert result.substeps == 2 ** k and result.steps == 60 * 2 ** k
        assert result.time == pytest.approx(60 * 4 * limit)
        assert "blew up" in result.notes[0] and f"restarted with {2 ** k} substeps" in result.notes[-1]
        assert np.isfinite(maker.made[-1].positions()).all()
        with pytest.raises(BlowUp) as err:  # under "run" the first blow-up is the error
            guarded(maker, Settings(4 * limit, 60, safety=Policy("run")), plan=StepPlan(4 * limit, 60),
                    source="<arrays>", wording=API_WORDING)
        assert 'reduce dt or stiffness, or pass unstable="subdivide"' in str(err.value)
    finally:
        maker.release()


def test_retries_stop_at_the_cap_in_the_callers_words():
    def boom(plan: StepPlan) -> None:
        raise BlowUp("s: simulation blew up", 1, 1)

    for wording, words in ((SCENE_WORDING, "the most --subdivide uses"),
                           (API_WORDING, 'the most unstable="subdivide" uses')):
        notes: list[str] = []
        with pytest.raises(SimulationError, match=f"still at {MAX_SUBSTEPS} substeps per step, {words}"):
            retry_with_substeps(StepPlan(0.01, 10), "subdivide", boom, notes, wording=wording)
        assert len(notes) == 4  # 1 -> 2 -> 4 -> 8 -> 16
    with pytest.raises(SimulationError, match="the most --subdivide uses"):
        retry_with_substeps(StepPlan(0.01, 10), "subdivide", boom, [])  # the scene's words by default


def test_the_api_wrapper_is_a_simulation_and_runs_on_the_one_run():
    from deformgl.sim import restartable as stepping

    system, grid = small()
    with stepping.GuardedSimulation(system, "semi-implicit", "numpy", dt=1e-3) as sim:
        assert isinstance(sim, stepping.GuardedSimulation) and isinstance(sim, Simulation)
        assert not hasattr(stepping, "Simulation")  # one class of that name: the protocol
        result = run(sim, 25, check_every=10)
        assert type(result) is RunResult and (result.steps, result.dt, result.substeps) == (25, 1e-3, 1)
        assert result.time == pytest.approx(0.025) == sim.time


def test_a_plain_simulation_runs_guarded_but_is_not_restarted():
    """``run`` guards a backend's own simulation too; a smaller step would need a restart, which
    only a GuardedSimulation does: refused in one line before any step."""
    system, grid = small()
    limit = dt_limit(system, "semi-implicit").dt
    with make_simulation(system, "semi-implicit", "numpy", dt=2.5 * limit) as sim:
        with pytest.raises(ArgumentError, match=r"^run: <arrays>: a restart at a step of .* needs a restartable "
                                                r"simulation: deformgl\.GuardedSimulation\(\.\.\.\)$"):
            run(sim, 10, unstable="subdivide", source="<arrays>")
        assert sim.time == 0.0
    with make_simulation(system, "semi-implicit", "numpy", dt=1e-3) as sim:
        result = run(sim, 10, check_every=5)
        assert (result.steps, result.substeps, result.dt, result.notes) == (10, 1, 1e-3, ())
        assert result.time == pytest.approx(0.01) == sim.time


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the blown-up NumPy runs overflow on purpose
def test_retries_bound_the_restarts_after_a_blow_up():
    """``retries`` is the retry policy apart from the dt check's: 0 keeps the first blow-up, 1
    restarts once (still too coarse here: the blow-up of the second attempt), and restarts come under
    "run" too when asked for."""
    system, grid = small()
    limit = dt_limit(system, "semi-implicit", exact=False).dt
    maker = Maker(None, system, grid, "numpy")
    try:
        for retries, attempts in ((0, 1), (1, 2)):
            maker.dts.clear()
            with pytest.raises(BlowUp):
                guarded(maker, Settings(4 * limit, 60, safety=Policy("subdivide")), plan=StepPlan(4 * limit, 60),
                        retries=retries)
            assert maker.dts == [pytest.approx(4 * limit / 2 ** i) for i in range(attempts)]
        maker.dts.clear()
        result = guarded(maker, Settings(4 * limit, 60, safety=Policy("run")), plan=StepPlan(4 * limit, 60), retries=8)
        assert result.substeps >= 4 and len(maker.dts) == len(result.notes) + 1
        with pytest.raises(ArgumentError, match="run: retries must be None or an integer >= 0, got -1"):
            guarded(maker, Settings(1e-3, 10), retries=-1)
    finally:
        maker.release()
