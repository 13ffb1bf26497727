"""The physics-term interface (deformgl.sim.terms): the shipped term list, the composed chunk list,
the declarations' checks, and a sheet's bending as one term among the system's terms."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from deformgl.grid.nodes import NodeGrid
from deformgl.sim import materials, springs
from deformgl.sim.terms.bending import SheetBending
from deformgl.sim.terms import GlslTerm, NodeTable, Term
from deformgl.sim.terms.glsl import ACTIVE, PassTerms, compose, pass_terms
from deformgl.sim.terms.registry import (FEEDBACK_SHIPPED, SHIPPED, XPBD_SHIPPED, shipped_active, shipped_feedback,
                                         shipped_xpbd)

ROOT = Path(__file__).resolve().parents[1]


def test_the_shipped_term_list_is_the_registrys():
    """shaders/terms/active.glsl is written by `python -m deformgl.sim.terms.registry` from SHIPPED."""
    assert (ROOT / "shaders" / "terms" / "active.glsl").read_text(encoding="utf-8") == shipped_active()
    for form in SHIPPED:
        assert form.file is not None and (ROOT / "shaders" / form.file).is_file()
        assert f"#ifdef TERM_{form.prefix.upper()}" in shipped_active()
    assert (ROOT / "shaders" / "terms" / "feedback.glsl").read_text(encoding="utf-8") == shipped_feedback()
    for feedback in FEEDBACK_SHIPPED:
        assert (ROOT / "shaders" / feedback.file).is_file()
        assert f"{feedback.prefix}_feedback(f, i, xi);" in shipped_feedback()
    assert (ROOT / "shaders" / "terms" / "xpbd.glsl").read_text(encoding="utf-8") == shipped_xpbd()
    for chunk in XPBD_SHIPPED:
        assert all((ROOT / "shaders" / f).is_file() for f in (chunk.file, *chunk.passes))
        assert f"{chunk.prefix}_xpbd(dx, counts, texel, flags, wi);" in shipped_xpbd()


def test_no_shared_pass_shader_names_a_shipped_term():
    """The passes know the hooks (terms_force, terms_neighbour, ...), not the terms: no shader
    outside shaders/terms/ holds a shipped term's prefix, define or uniform."""
    for path in (ROOT / "shaders").rglob("*"):
        if path.suffix not in (".glsl", ".frag", ".vert") or path.parent.name == "terms":
            continue
        text = path.read_text(encoding="utf-8")
        for form in SHIPPED:
            for word in (f"TERM_{form.prefix.upper()}", f"u_{form.prefix}", f"{form.prefix}_"):
                assert re.search(rf"\b{re.escape(word)}", text) is None, (path, word)


def test_compose_calls_each_term_in_order():
    a = GlslTerm("first", source="", implicit=True)
    b = GlslTerm("second", source="", neighbours=18)
    text = compose((a, b))
    assert text.index("first_force(f, n)") < text.index("second_force(f, n)")
    assert "second_neighbour(f, n, j, d)" in text and "first_neighbour" not in text
    assert "first_product(q, n, y)" in text and "second_product" not in text
    chunks = PassTerms((a, b)).chunks()
    assert set(chunks) == {ACTIVE, "terms/first.glsl", "terms/second.glsl"}
    defines = PassTerms((a, b), implicit=True).defines()
    assert {k for k, v in defines.items() if v} == {"TERMS", "TERMS_IMPLICIT", "TERMS_NEIGHBOURS", "TERM_FIRST",
                                                    "TERM_SECOND"}
    assert PassTerms(()).defines() == {} and PassTerms(()).chunks() == {}


def test_declarations_are_checked():
    with pytest.raises(ValueError, match="must start with u_good"):
        GlslTerm("good", source="", uniforms={"u_other": 1.0})
    with pytest.raises(ValueError, match="not both"):
        GlslTerm("good", source="x", file="terms/x.glsl")
    with pytest.raises(ValueError, match="neighbours must be 0, 18 or 24"):
        GlslTerm("good", source="", neighbours=6)
    with pytest.raises(ValueError, match="expected"):
        NodeTable("u_good_t", np.zeros((4, 3)))
    with pytest.raises(ValueError, match="not finite"):
        NodeTable("u_good_t", np.full((4, 4), np.inf))
    assert NodeTable("u_good_t", np.zeros((4, 8))).layers == 2
    grid = NodeGrid(np.zeros(3), 0.1, np.ones((2, 2, 2), bool))
    system = springs.from_grid(grid, k_structural=1.0, k_shear=1.0)
    with pytest.raises(ValueError, match=r"extra_terms\[0\]: str is not a deformgl.sim.terms.Term"):
        dataclasses.replace(system, extra_terms=("springs",))


class _Plain(Term):
    name = "plain things"

    def add_forces(self, x, v, t, out):
        pass

    def energy(self, x):
        return 0.0

    def stiffness(self, x):
        import scipy.sparse as sp

        return sp.csr_matrix((3 * len(x), 3 * len(x)))


def test_a_term_without_a_glsl_form_is_refused_by_the_gpu_backends_in_one_line():
    with pytest.raises(ValueError, match="^FragmentIntegrator: plain things have no GLSL form$"):
        pass_terms((_Plain(),), "fragment", "FragmentIntegrator", None)
    with pytest.raises(ValueError, match="^x: plain things have no transform-feedback form$"):
        pass_terms((_Plain(),), "feedback", "x", None)
    two = GlslTerm("same", source="")
    with pytest.raises(ValueError, match="share a GLSL prefix"):
        pass_terms((_Glsl(two), _Glsl(two)), "fragment", "x", None)
    with pytest.raises(ValueError, match="^x: plain things have no implicit product in GLSL$"):
        pass_terms((_Glsl(two),), "implicit", "x", None, implicit=True)


class _Glsl(_Plain):
    def __init__(self, form):
        self.form = form

    def glsl(self, grid):
        return self.form


def test_a_sheets_bending_is_one_of_its_terms():
    sheet, _ = materials.sheet_system(NodeGrid(np.zeros(3), 0.01, np.ones((5, 1, 4), bool)),
                                      materials.SheetMaterial(stretch_modulus=50.0, areal_density=0.2,
                                                              bending_stiffness=1e-4))
    assert isinstance(sheet.bending, SheetBending) and sheet.terms == (sheet.bending,)
    plain = dataclasses.replace(sheet, bending=None)
    assert plain.terms == ()
    assert dataclasses.replace(plain, bending=sheet.bending).terms == (sheet.bending,)
    with pytest.raises(ValueError, match=r"^SpringSystem.extra_terms\[0\]: a sheet's bending go in the system's own field \(bending=term\)$"):
        dataclasses.replace(plain, extra_terms=(sheet.bending,))  # (not silently dropped, nor counted twice)
    # the fragment backend's form: its coefficients on the 24-neighbour table
    form = sheet.bending.glsl(sheet.grid)
    assert form.neighbours == 24 and form.tables[0].values.shape == (sheet.count, 24)
