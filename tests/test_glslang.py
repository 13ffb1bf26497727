"""The shader pack against the Khronos reference compiler: every program deformgl builds, in a
covering set of its define variants (every value triple) (deformgl.pack.variants), preprocessed by deformgl's preprocessor in both profiles (GLSL 3.30
core and GLSL ES 3.00), compiles and links in glslangValidator without an error or a warning.
tests/conftest.py fails any test that builds a program not in the enumeration. Needs
glslangValidator (Debian glslang-tools, an optional system tool: installed by .ci/run)."""

from __future__ import annotations

import pytest

from deformgl.gl import preprocessor
from deformgl.pack import glslang
from deformgl.pack.variants import GROUPS, all_variants, covering_set, held_tuples, variant_key
from deformgl.sim.backends.implicit_passes import PASSES, TERM_PASSES

#: the tests that run glslangValidator: skipped with the reason where it is missing (tests/conftest.py)
needs_glslang = pytest.mark.glslang


def test_enumeration_covers_every_builder_and_its_switches():
    variants = all_variants()
    assert len(variants) == len({v.key for v in variants}) > 6000
    by_file = {(v.vertex, v.fragment) for v in variants}
    for pair in [("sim/fullscreen.vert", "sim/integrators/step.frag"), ("sim/fullscreen.vert", "sim/verlet.frag"),
                 ("feedback/rk4_stage.vert", None), ("render/mapped_mesh.vert", "render/mapped_mesh.frag"),
                 ("trilinear/transform.vert", None), ("sim/fullscreen.vert", "census/census.frag"),
                 ("sim/fullscreen.vert", "sim/node_normals.frag")]:
        assert pair in by_file
    assert all(len(list(g())) for g in GROUPS.values())


def test_variant_key_classes_counts_and_rows_but_not_switches():
    a = variant_key("v", "f", {"DRAGS": 2, "NODE_ROW": 64, "WIND": True, "X": False})
    assert a == variant_key("v", "f", {"DRAGS": 8, "NODE_ROW": 1024, "WIND": True})
    assert a != variant_key("v", "f", {"DRAGS": 1, "NODE_ROW": 64, "WIND": True})
    assert variant_key("v", "f", {"DRAGS": 9})[2] == (("DRAGS", 9),)  # beyond the limit: unknown
    known = {v.key for v in all_variants()}
    # a switch the enumeration does not know is not a known variant (the conftest check fails on it)
    assert variant_key("sim/fullscreen.vert", "census/census.frag", {"COPY": True}) in known
    assert variant_key("sim/fullscreen.vert", "census/census.frag", {"COPY": True, "NEW": 1}) not in known


@needs_glslang
def test_a_backslash_continuation_is_an_error_in_glsl_330(monkeypatch):
    """The fault this check found: a line continuation (GLSL 4.20; GLSL ES 3.00 has it) that
    Mesa accepts in a 3.30 shader and a strict driver would not."""
    read = preprocessor.read_shader_file

    def with_continuation(name):
        text = read(name)
        old = "const int FLAG_FIXED = 2;"
        return text.replace(old, "#define CONTINUED 1 \\\n    + 1\n" + old) if name == "lib/node_flags.glsl" else text

    monkeypatch.setattr(preprocessor, "read_shader_file", with_continuation)
    glslang._mentioned.cache_clear()
    try:
        variants = [v for v in all_variants() if v.fragment == "sim/verlet.frag"][:2]
        assert "const int FLAG_FIXED = 2;" in read("lib/node_flags.glsl")
        report = glslang.validate(variants, "core")
        assert report.problems and all("verlet.frag" in p or "link" in p for p in report.problems), report.problems
        assert not glslang.validate(variants, "es").problems
    finally:
        glslang._mentioned.cache_clear()


def test_the_covering_set_holds_every_value_triple_of_the_full_product():
    """What glslang runs: every combination of values of any three defines of a program that the
    full enumeration holds, in a set a tenth of its size (and a set missing one is caught)."""
    full = all_variants()
    cover = covering_set(full)
    assert len(cover) * 10 < len(full)
    by_file: dict[tuple, list] = {}
    for v in full:
        by_file.setdefault((v.vertex, v.fragment), []).append(v)
    held = set(cover)
    for files, group in by_file.items():
        mine = [v for v in group if v in held]
        assert mine and held_tuples(mine) == held_tuples(group), files
    implicit = [v for v in cover if v.fragment == "sim/implicit/implicit.frag"]
    # the pass with both cell terms (the nu = 0.45 programs), each pass
    both = {tuple(k for k, on in v.defines if on is True and k in PASSES) for v in implicit
            if v.define_map.get("CELL_CENTRE") and v.define_map.get("CELL_BARRIER")}
    assert {p for p in PASSES if p in TERM_PASSES} <= {k for t in both for k in t}
    assert held_tuples(implicit[1:]) != held_tuples(implicit)


@needs_glslang
@pytest.mark.slow
@pytest.mark.parametrize("profile", ["core", "es"])
def test_every_switch_triple_passes_glslang(profile):
    """Every combination of values of any three defines of every program (:func:`covering_set`;
    the full product's ~43,000 programs took over 4 minutes a profile on 2 cores)."""
    variants = covering_set(all_variants())
    report = glslang.validate(variants, profile)
    assert report.programs == len(variants)
    assert report.stage_sources > 3000 and report.linked >= 15
    assert not report.problems, f"{len(report.problems)} glslang findings, e.g.:\n" + "\n".join(report.problems[:10])
