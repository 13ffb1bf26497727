"""Guards of a scene run: the dt check before it (refuse, run anyway, subdivide) and the GPU
blow-up census during it (every N steps, the step and a node named, restarts with --subdivide)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from deformgl.errors import SceneError, SimulationError
from deformgl.scene.pipeline import NodeState, build_scene_model, render_to_png
from deformgl.sim.guards import (API_WORDING, MAX_SUBSTEPS, SAFETY_MARGIN, SCENE_WORDING, BlowUp, StepPlan,
                                 describe_bad_node, plan_steps, retry_with_substeps)
from deformgl.scene.schema import load_scene
from deformgl.scene.spec import Safety
from deformgl.scene.physics import SceneBox, simulate_scene, scene_system
from deformgl.sim.limits import check_dt, dt_limit

SCENES = Path(__file__).resolve().parent.parent / "scenes"


@pytest.fixture(scope="module")
def jelly():
    scene = load_scene(SCENES / "jelly_springs.toml")
    built = build_scene_model(scene)
    return scene, built, scene_system(built.grid, scene.physics, built.bbox)


def with_physics(scene, **physics):
    return dataclasses.replace(scene, physics=dataclasses.replace(scene.physics, **physics))


def test_plan_accepts_a_stable_dt_and_refuses_one_above_the_limit(jelly):
    scene, _, system = jelly
    plan = plan_steps(system, scene.physics, scene.source)
    assert plan == StepPlan(scene.physics.dt, scene.physics.steps) and plan.note == ""
    # 378 nodes: above the dense solve's 300, so the limit is the Lanczos estimate
    limit = check_dt(system, "verlet", 1.0).limit
    assert limit.bound == "lanczos" and limit.dt > 1.5 * dt_limit(system, "verlet", exact=False).dt
    over = with_physics(scene, dt=1.2 * limit.dt).physics
    with pytest.raises(SimulationError) as err:
        plan_steps(system, over, scene.source)
    text = str(err.value)
    assert text.startswith(f"{scene.source}: physics.dt: dt ")
    assert f"verlet limit {limit.dt:.4g} s" in text and f"node {limit.node} (spring {limit.spring}," in text
    assert "--allow-unstable" in text and "--subdivide" in text and "lanczos bound" in text
    # beyond 30,000 free nodes only the Gershgorin bound is used, and the message says it is conservative
    gershgorin = dt_limit(system, "verlet", exact=False).dt
    from deformgl.sim import guards as safety

    refusal = check_dt(system, "verlet", 1.2 * gershgorin, lanczos_up_to=0)
    assert refusal is not None and refusal.limit.bound == "gershgorin"
    with pytest.MonkeyPatch.context() as m:
        m.setattr(safety, "check_dt", lambda *a: refusal)
        with pytest.raises(SimulationError, match="conservative bound, used above 30,000 free nodes"):
            plan_steps(system, with_physics(scene, dt=1.2 * gershgorin).physics, scene.source)


def test_run_anyway_notes_the_limit_and_subdivide_splits_below_it(jelly):
    scene, _, system = jelly
    limit = check_dt(system, "verlet", 1.0).limit.dt
    run = plan_steps(system, with_physics(scene, dt=1.2 * limit, safety=Safety("run")).physics, "s.toml")
    assert run.substeps == 1 and run.note.startswith("running anyway: dt")
    for factor in (1.2, 3.0, 7.5):
        plan = plan_steps(system, with_physics(scene, dt=factor * limit, safety=Safety("subdivide")).physics, "s")
        assert plan.substeps == math.ceil(factor / SAFETY_MARGIN)
        assert plan.step_dt <= SAFETY_MARGIN * limit * (1 + 1e-12)
        assert plan.step_count == plan.steps * plan.substeps
    with pytest.raises(SimulationError, match=f"more than --subdivide's {MAX_SUBSTEPS}"):
        plan_steps(system, with_physics(scene, dt=20 * limit, safety=Safety("subdivide")).physics, "s")


def test_undamped_forward_euler_cannot_be_subdivided(jelly):
    scene, _, _ = jelly
    physics = with_physics(scene, damping=0.0, integrator="euler", safety=Safety("subdivide")).physics
    built = build_scene_model(with_physics(scene, damping=0.0))
    system = scene_system(built.grid, physics, built.bbox)
    with pytest.raises(SimulationError, match="every dt.*no substep is stable"):
        plan_steps(system, physics, "s.toml")


def test_plan_messages_are_worded_for_the_python_api_when_asked(jelly):
    """The same checks, the same numbers; the API's words (``dt``, ``unstable="..."``) where a scene's
    are its keys and the CLI's flags (the default, :data:`SCENE_WORDING`)."""
    scene, _, system = jelly
    limit = check_dt(system, "verlet", 1.0).limit.dt
    over = with_physics(scene, dt=1.2 * limit).physics
    with pytest.raises(SimulationError) as cli:
        plan_steps(system, over, scene.source, wording=SCENE_WORDING)
    with pytest.raises(SimulationError) as default:
        plan_steps(system, over, scene.source)
    assert str(cli.value) == str(default.value)
    with pytest.raises(SimulationError) as api:
        plan_steps(system, over, "<arrays>", wording=API_WORDING)
    text = str(api.value)
    assert text.startswith("<arrays>: dt ") and f"verlet limit {limit:.4g} s" in text
    assert text.endswith('Lower it, or pass unstable="subdivide" to split each step or unstable="run" to run it anyway')
    assert "physics." not in text and "--" not in text
    with pytest.raises(SimulationError, match=f'more than the {MAX_SUBSTEPS} that unstable="subdivide" uses: '
                                              f"reduce dt$"):
        plan_steps(system, with_physics(scene, dt=20 * limit, safety=Safety("subdivide")).physics, "<arrays>",
                   wording=API_WORDING)
    physics = with_physics(scene, damping=0.0, integrator="euler", safety=Safety("subdivide")).physics
    built = build_scene_model(with_physics(scene, damping=0.0))
    undamped = scene_system(built.grid, physics, built.bbox)
    with pytest.raises(SimulationError, match='no substep is stable, so unstable="subdivide" cannot help'):
        plan_steps(undamped, physics, "<arrays>", wording=API_WORDING)
    plan = plan_steps(system, with_physics(scene, dt=1.2 * limit, safety=Safety("subdivide")).physics, "<arrays>",
                      wording=API_WORDING)
    assert plan == plan_steps(system, with_physics(scene, dt=1.2 * limit, safety=Safety("subdivide")).physics,
                              "<arrays>")  # the wording changes no plan


def test_retries_double_the_substeps_up_to_the_cap():
    plans = []

    def attempt(plan: StepPlan) -> int:
        plans.append(plan.substeps)
        if plan.substeps < 4:
            raise BlowUp("s.toml: simulation blew up: at step 7", 7, 3)
        return plan.substeps

    notes: list[str] = []
    result, plan = retry_with_substeps(StepPlan(0.01, 10), "subdivide", attempt, notes)
    assert result == 4 and plans == [1, 2, 4] and plan.step_count == 40
    assert len(notes) == 2 and "restarted with 4 substeps per step (dt 0.0025 s)" in notes[1]
    with pytest.raises(BlowUp):
        retry_with_substeps(StepPlan(0.01, 10), "run", attempt, [])
    with pytest.raises(SimulationError, match=f"still at {MAX_SUBSTEPS} substeps"):
        retry_with_substeps(StepPlan(0.01, 10), "subdivide",
                         lambda p: (_ for _ in ()).throw(BlowUp("boom", 1, 1)), [])


@pytest.mark.parametrize("backend", ["fragment", "feedback", "numpy"])
def test_a_blow_up_the_dt_check_missed_restarts_with_smaller_steps(ctx, jelly, backend):
    """The plan is forced past the check (substeps 1 at 4x the limit): the census sees the blow-up,
    the run restarts with 2, 4, ... substeps until it holds, the same simulated time."""
    scene, built, system = jelly
    limit = dt_limit(system, "semi-implicit", exact=False).dt
    scene = with_physics(scene, dt=4 * limit, steps=60, integrator="semi-implicit", backend=backend,
                         safety=Safety("subdivide", check_every=20))
    notes: list[str] = []
    out = simulate_scene(ctx, scene, built.grid, scene_system(built.grid, scene.physics, built.bbox), built.loads,
                    SceneBox(*built.bbox), progress=False, plan=StepPlan(scene.physics.dt, 60), notes=notes)
    k = len(notes)  # at 4x the (conservative) Gershgorin limit: 2 restarts, maybe 3
    assert 2 <= k <= 3, notes
    assert [n.split("; ")[-1].split(" per step")[0] for n in notes] == [
        f"restarted with {2 ** i} substeps" for i in range(1, k + 1)]
    assert "blew up: at step 20 " in notes[0]
    assert out.steps == 60 * 2 ** k and out.time == pytest.approx(60 * 4 * limit)
    assert np.isfinite(out.positions).all()


def test_the_foundation_pass_is_watched_too_and_reads_nothing_back(ctx, jelly, monkeypatch):
    import moderngl

    scene, built, system = jelly
    reads = []
    original = moderngl.Texture.read
    monkeypatch.setattr(moderngl.Texture, "read", lambda self, *a, **k: reads.append(self) or original(self, *a, **k))
    state = NodeState(ctx, scene.with_overrides(steps=50, check_every=10), built, progress=False)
    state.release()
    assert reads == []  # five checks and the final one: occlusion-query counts only
    limit = dt_limit(system, "verlet", exact=False).dt
    bad = with_physics(scene, dt=6 * limit, safety=Safety("run", check_every=10))
    with pytest.raises(BlowUp, match=r"at step (10|20|30) .* first node \d+ \(grid"):
        NodeState(ctx, bad, built, progress=False)


def test_a_far_away_finite_node_counts_as_blown_up(ctx, jelly):
    """A node flung beyond bad_distance box lengths is caught before it overflows: a drag pulls
    one node 50 box lengths away, with bad_distance 10."""
    from deformgl.scene.spec import DragSpec, Keyframes

    scene, built, _ = jelly

    drag = DragSpec(Keyframes(((0.5, 1.0, 0.5), (50.0, 1.0, 0.5)), (0.0, 0.01)), 50.0)
    scene = with_physics(scene, drag=(drag,), steps=200, backend="feedback",
                         safety=Safety("run", check_every=50, bad_distance=10.0))
    with pytest.raises(BlowUp) as err:
        simulate_scene(ctx, scene, built.grid, scene_system(built.grid, scene.physics, built.bbox), built.loads,
                  SceneBox(*built.bbox), progress=False)
    assert "beyond 10 from the centre" not in str(err.value)  # box lengths, not world units
    assert "beyond" in str(err.value) and "nan" not in str(err.value) and "inf" not in str(err.value)


def test_png_is_not_written_when_the_run_blows_up(ctx, jelly, tmp_path):
    scene, _, system = jelly
    limit = dt_limit(system, "verlet", exact=False).dt
    out = tmp_path / "x.png"
    with pytest.raises(BlowUp):
        render_to_png(ctx, with_physics(scene, dt=6 * limit, safety=Safety("run", check_every=25)), out)
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_describe_bad_node_names_the_first_bad_one():
    x = np.zeros((4, 3))
    assert describe_bad_node(x, None, 1.0) == ""
    x[2] = (0.0, 5.0, 0.0)
    x[3, 0] = np.nan
    assert describe_bad_node(x, None, 1.0) == "node 2 at (0, 5, 0)"
    assert describe_bad_node(x, None, 10.0) == "node 3 at (nan, 0, 0)"


@pytest.mark.parametrize("text, key", [
    ('unstable = "maybe"', "physics.safety.unstable"),
    ("check_every = -1", "physics.safety.check_every"),
    ("bad_distance = 0", "physics.safety.bad_distance"),
])
def test_bad_safety_keys_name_the_key(tmp_path, text, key):
    src = (SCENES / "jelly_springs.toml").read_text().replace('path = "assets/', f'path = "{SCENES}/assets/')
    path = tmp_path / "s.toml"
    path.write_text(src + f"\n[physics.safety]\n{text}\n")
    with pytest.raises(SceneError, match=rf"s.toml: {key}: "):
        load_scene(path)


def test_the_blow_up_message_names_the_last_clean_check_and_halving_reaches_the_cap():
    """Checks fall every 100 steps and at the end: a blow-up seen at the final check (250) names
    step 200 as the last clean one; from 9 substeps a restart tries the cap, 16."""
    from deformgl.sim.guards import BlowUpWatch

    class Census:
        def __init__(self):
            self.counts = iter([0, 0, 3])

        def bad(self, texture, limit, slot=0):
            return next(self.counts)

    class Sim:
        count = 2

        def position_slot(self):
            return None, 2, 1, 0

        def positions(self):
            return np.array([[0.0, 0.0, 0.0], [np.inf, 0.0, 0.0]])

    watch = BlowUpWatch.__new__(BlowUpWatch)
    watch.sim, watch.every, watch.limit, watch.grid, watch.source, watch.dt = Sim(), 100, 10.0, None, "s.toml", 0.01
    watch.census, watch.last_clean = Census(), None
    watch.check(100)
    watch.check(200)
    with pytest.raises(BlowUp, match=r"at step 250 \(dt 0.01 s; none at step 200\) 3 node\(s\) .* first node 1 at \(inf"):
        watch.check(250)
    assert StepPlan(0.1, 10, 9).halved().substeps == 16 and StepPlan(0.1, 10, 16).halved() is None
