"""The integrator table (deformgl.sim.stages) is consistent, and both GPU backends build their
passes from it instead of comparing integrator names."""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

import pytest

from deformgl.sim import integrators as I
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS
from deformgl.sim.stages import BUFFERS, SPECS, IntegratorSpec, Stage, spec

ROOT = Path(__file__).resolve().parent.parent
BACKENDS = [ROOT / "deformgl/sim/backends/explicit_gpu.py", ROOT / "deformgl/sim/backends/feedback.py"]
SHADERS = ROOT / "shaders"
#: fragment outputs of step.frag, by location
OUTPUT_ORDER = [("x",), ("v",), ("sum", "x"), ("sum", "v")]


def _output(buffer: str) -> tuple[str, ...]:
    kind, quantity = BUFFERS[buffer]
    return ("sum", quantity) if kind == "sum" else (quantity,)


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_every_read_is_state_or_written_by_an_earlier_stage(name):
    s = spec(name)
    assert s.name == name and s.buffers == I.GPU_BUFFERS[name]
    assert set(s.state) == ({"x", "v"} if s.velocity else {"x", "x_prev"})
    available = set(s.state)
    for stage in s.stages:
        assert not set(stage.reads) & set(stage.writes), stage  # ping-pong
        assert set(stage.reads) <= available, (stage.name, set(stage.reads) - available)
        assert not set(stage.writes) & set(s.state), stage  # the state is never overwritten
        available |= set(stage.writes)
    used = set(s.state).union(*(set(st.reads) | set(st.writes) for st in s.stages))
    assert used == set(s.buffers)  # no buffer allocated for nothing


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_stages_write_in_output_order_and_only_the_last_is_final(name):
    s = spec(name)
    for stage in s.stages:
        order = [OUTPUT_ORDER.index(_output(b)) for b in stage.writes]
        assert order == list(range(len(order))), stage  # locations 0, 1, ... of step.frag
        assert 0.0 <= stage.time <= 1.0
    assert [st.final for st in s.stages] == [False] * (len(s.stages) - 1) + [True]
    assert s.final.name == "step" and len({st.name for st in s.stages}) == len(s.stages)
    assert s.final.time == (1.0 if name == "rk4" else 0.5 if name == "midpoint" else 0.0)
    assert s.stages[0].at(0.25, 0.1) == 0.25


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_rotation_is_a_permutation_that_makes_the_final_writes_the_state(name):
    s = spec(name)
    roles = list(range(len(s.buffers)))
    after = s.rotate(roles)
    assert sorted(after) == roles
    index = {b: i for i, b in enumerate(s.buffers)}
    if s.velocity:
        assert [after[index["x"]], after[index["v"]]] == [index[b] for b in s.final.writes[:2]]
    else:
        assert after[index["x"]] == index[s.final.writes[0]]
        assert after[index["x_prev"]] == index["x"]
    # each state buffer the step read is either kept as state or free to be written again
    assert all(s.before(b) in s.buffers for b in s.buffers)


def test_the_fragment_defines_are_those_the_shader_variants_always_had():
    expected = {
        "euler": [{"EULER": True}],
        "semi-implicit": [{"SEMI_IMPLICIT": True}],
        "midpoint": [{"MIDPOINT_HALF": True}, {"MIDPOINT_FULL": True, "EVAL_STAGE": True}],
        "rk4": [{"RK4_STAGE": 1, "WRITE_SUMS": True},
                {"RK4_STAGE": 2, "WRITE_SUMS": True, "EVAL_STAGE": True, "READ_SUMS": True},
                {"RK4_STAGE": 3, "WRITE_SUMS": True, "EVAL_STAGE": True, "READ_SUMS": True},
                {"RK4_FINAL": True, "EVAL_STAGE": True, "READ_SUMS": True}],
        "verlet": [{"VERLET": True}],
    }
    for name, defines in expected.items():
        assert [st.fragment_defines() for st in spec(name).stages] == defines, name
    feedback = {name: [(st.vertex, st.feedback_defines()) for st in s.stages]
                for name, s in SPECS.items()}
    assert feedback["euler"] == [("feedback/euler.vert", {})]
    assert feedback["semi-implicit"] == [("feedback/euler.vert", {"SEMI_IMPLICIT": True})]
    assert feedback["rk4"][1] == ("feedback/rk4_stage.vert", {"RK4_STAGE": 2})
    assert feedback["rk4"][3] == ("feedback/rk4_final.vert", {})


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_every_define_is_one_the_shader_knows(name):
    fragment = (SHADERS / "sim/integrators/step.frag").read_text()
    for stage in spec(name).stages:
        for define in stage.fragment_defines():
            assert re.search(rf"\b{define}\b", fragment), (stage.name, define)
        vertex = (SHADERS / stage.vertex).read_text()
        assert set(stage.vertex_defines) <= {k for k, _ in stage.defines}
        for define in stage.vertex_defines:
            assert re.search(rf"\b{define}\b", vertex), (stage.vertex, define)


def test_a_spec_that_is_not_consistent_is_refused():
    step = Stage("step", ("x", "v"), ("x_out", "v_out"), final=True)
    buffers = ("x", "v", "x_out", "v_out")
    with pytest.raises(ValueError, match="not in"):
        IntegratorSpec("bad", (Stage("step", ("x", "y"), ("x_out",), final=True),), buffers,
                       True, None)
    with pytest.raises(ValueError, match="last stage must be final"):
        IntegratorSpec("bad", (step, Stage("more", ("x",), ("x_out",))), buffers, True, None)
    with pytest.raises(ValueError, match="permutation"):
        IntegratorSpec("bad", (step,), buffers, True, None, (("x", "x_out"),))


def test_the_limit_formulas_follow_from_the_limit_factors():
    from deformgl.sim.spectrum import _FORMULA

    assert _FORMULA == {"semi-implicit": "2/w", "rk4": "2.83/w", "verlet": "2/w"}
    assert [n for n, s in SPECS.items() if s.limit_factor is None] == ["euler", "midpoint"]


def _string_literals(path: Path) -> list[tuple[int, str]]:
    """(line, value) of every string literal in the code (docstrings included)."""
    out = []
    for tok in tokenize.generate_tokens(io.StringIO(path.read_text()).readline):
        if tok.type == tokenize.STRING:
            try:
                value = ast.literal_eval(tok.string)
            except ValueError:  # f-string
                value = tok.string
            out.append((tok.start[0], value))
    return out


@pytest.mark.parametrize("path", BACKENDS, ids=lambda p: p.name)
def test_the_backends_compare_no_integrator_names(path):
    text = path.read_text()
    compared = []
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Compare):
            sides = [ast.unparse(o) for o in (node.left, *node.comparators)]
            if set(sides) & {"name", "integrator", "self.integrator"} and "EXPLICIT_INTEGRATORS" not in sides:
                compared.append((node.lineno, ast.unparse(node)))
    assert compared == []  # (only the check that the name is one of EXPLICIT_INTEGRATORS)
    assert not re.search(r"\.get\(\s*(name|integrator|self\.integrator)\b", text)
    assert not re.search(r"\bname\s*=\s*self\.integrator\b", text)
    named = [(line, v) for line, v in _string_literals(path) if v in EXPLICIT_INTEGRATORS]
    assert named == []  # not one integrator name as a string in the code
    # nor the old pass keys of particular integrators: every pass comes from spec().stages
    keys = {st.name for s in SPECS.values() for st in s.stages}
    assert [(line, v) for line, v in _string_literals(path) if v in keys] == []
