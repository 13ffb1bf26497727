"""A pass's physics terms as GLSL: the chunk list it compiles, the uniforms it sets and the node
tables it binds, for every term of the system that has a GLSL form (:class:`~deformgl.sim.terms.base.GlslTerm`).

The shared passes know one hook each, under ``#ifdef TERMS`` (``sim/integrators/forces.glsl``
``terms_force``; ``sim/verlet_node.glsl`` the same; ``sim/implicit/system.glsl``
``terms_product`` and ``terms_diagonal`` with ``TERMS_IMPLICIT``), and include
``terms/active.glsl``, which :meth:`PassTerms.chunks` composes here of the terms' chunks: a pass
compiles only the terms its system holds, and no pass names one.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from typing import TYPE_CHECKING

import numpy as np

from deformgl.errors import ShaderError
from deformgl.gl.preprocessor import read_shader_file
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.terms.base import FeedbackTerm, GlslTerm, NodeTable, Term
from deformgl.sim.terms.constraints import XpbdChunk

if TYPE_CHECKING:
    import moderngl

__all__ = ["ACTIVE", "FEEDBACK", "XPBD", "PassTerms", "check_inline", "compose", "compose_feedback", "compose_xpbd",
           "feedback_terms", "pass_terms", "refuse_terms"]

#: The include name of the composed term list.
ACTIVE = "terms/active.glsl"
#: The include name of the composed transform-feedback term list.
FEEDBACK = "terms/feedback.glsl"
#: The include name of the composed XPBD node-sweep term list.
XPBD = "terms/xpbd.glsl"
#: The first bit of the terms' node bits in the node data's flag word (lib/node_flags.glsl).
TERM_SHIFT = 6
_NODE = "lib/term_node.glsl"


def check_inline(include: str, source: str | None, caller: str) -> None:
    """A one-line ValueError where a term's chunk given inline (``source``) would take the include
    name of a shipped shader or of a composed term list: the inline text would replace it in every
    file of the pass that includes it."""
    if source is None:
        return
    shipped = include in (ACTIVE, FEEDBACK, XPBD)
    if not shipped:
        try:
            read_shader_file(include)
            shipped = True
        except ShaderError:
            pass
    if shipped:
        raise ValueError(f"{caller}: a term's inline chunk is named {include!r}, a shipped shader's name; give it a name "
                         f"of its own")


def refuse_terms(terms: Sequence[Term], backend: str, caller: str) -> None:
    """A one-line ValueError naming the first term ``backend`` cannot run, if any."""
    for term in terms:
        why = term.refusal(backend)
        if why is not None:
            raise ValueError(f"{caller}: {why}")


@dataclass(frozen=True)
class PassTerms:
    """The GLSL forms of a system's terms, as one pass compiles them."""

    forms: tuple[GlslTerm, ...]
    implicit: bool = False

    def __bool__(self) -> bool:
        return bool(self.forms)

    def defines(self) -> dict[str, object]:
        """``TERMS``, ``TERM_<PREFIX>`` per term, ``TERMS_NEIGHBOURS`` where a term reads the grid
        neighbours and ``TERMS_IMPLICIT`` in implicit passes; none without terms."""
        if not self.forms:
            return {}
        out: dict[str, object] = {"TERMS": True, "TERMS_IMPLICIT": self.implicit,
                                  "TERMS_NEIGHBOURS": any(f.neighbours for f in self.forms),
                                  "TERMS_HOOD": self.hood > 0, "HOOD_DIAGONALS": self.hood > 1,
                                  "TERMS_HELD": self.implicit and any(f.held for f in self.forms)}
        for f in self.forms:
            out[f"TERM_{f.prefix.upper()}"] = True
            out.update(f.defines)
        return out

    @property
    def hood(self) -> int:
        """How much of the node's 3x3x3 neighbourhood the pass keeps for its terms (0, 1: the 18
        neighbours, 2: and the body diagonals)."""
        return max((f.hood for f in self.forms), default=0)

    def node_bits(self, count: int) -> np.ndarray:
        """(N,) int64 the terms' node bits, shifted into the node data's flag word (bits 6-13,
        ``shaders/lib/node_flags.glsl`` TERM_SHIFT); 0 without."""
        for form in self.forms:
            if form.node_bits is not None:
                return np.asarray(form.node_bits, np.int64) << TERM_SHIFT
        return np.zeros(count, np.int64)

    def chunks(self) -> dict[str, str]:
        """The include files given as text: each inline chunk, and ``terms/active.glsl``."""
        if not self.forms:
            return {}
        out = {ACTIVE: compose(self.forms)}
        for form in self.forms:
            if form.source is not None:
                out[form.include] = form.source
        return out

    @property
    def others(self) -> tuple[GlslTerm, ...]:
        """The terms that read other nodes' state by number (the compact layouts only)."""
        return tuple(f for f in self.forms if f.others)

    @property
    def tables(self) -> tuple[NodeTable, ...]:
        """Every node table the pass samples, in order."""
        return tuple(t for form in self.forms for t in form.tables)

    @property
    def prepasses(self) -> tuple[GlslTerm, ...]:
        """The terms with a pass of their own before each force evaluation (:attr:`GlslTerm.prepass`)."""
        return tuple(f for f in self.forms if f.prepass is not None)

    @property
    def samplers(self) -> tuple[str, ...]:
        """Every sampler of the terms' chunks, in the order units are given: the tables', then the
        pre-passes' outputs."""
        return (*(t.sampler for t in self.tables), *(s for f in self.forms for s in f.prepass_samplers))

    def uniforms(self, units: Sequence[int]) -> dict[str, object]:
        """The terms' uniform values and their samplers on ``units`` (one each, in the order of
        :attr:`samplers`: the node tables, then the pre-passes' outputs)."""
        samplers = self.samplers
        if len(samplers) > len(units):
            raise ValueError(f"the terms sample {len(samplers)} textures; this pass has {len(units)} texture units "
                             f"left for them")
        out: dict[str, object] = {}
        for form in self.forms:
            out.update(form.uniforms)
        out.update(dict(zip(samplers, units)))
        return out

    def textures(self, make: Callable[[NodeTable], "moderngl.TextureArray"]) -> list["moderngl.TextureArray"]:
        """One texture array per table, made by the backend in its node layout."""
        return [make(t) for t in self.tables]


def compose(forms: Sequence[GlslTerm], *, guarded: bool = False) -> str:
    """``terms/active.glsl`` of ``forms``: each chunk's include, then ``terms_force`` (and
    ``terms_begin``, ``terms_neighbour``; under TERMS_IMPLICIT ``terms_product``,
    ``terms_diagonal``, ``terms_neighbour_product``) calling each term's function in turn.
    ``guarded``: each term under ``#ifdef TERM_<PREFIX>`` (the shipped file of every shipped term,
    which the shader pack compiles with the defines alone)."""
    lines = ["// The physics terms of a pass (deformgl/sim/terms). Composed by deformgl/sim/terms/glsl.py",
             "// compose(); do not edit: `python -m deformgl.sim.terms.registry` writes the shipped one.",
             f'#include "{_NODE}"']

    def each(form: GlslTerm, text: str) -> None:
        lines.extend([f"#ifdef TERM_{form.prefix.upper()}", text, "#endif"] if guarded else [text])

    for form in forms:
        each(form, f'#include "{form.include}"')

    def function(signature: str, call: str, which: Sequence[GlslTerm]) -> None:
        lines.append(signature + " {")
        for form in which:
            each(form, "    " + call.replace("PREFIX", form.prefix))
        lines.append("}")

    function("void terms_force(inout vec3 f, TermNode n)", "PREFIX_force(f, n);", forms)
    near = [f for f in forms if f.neighbours]
    if near:
        lines.append("#ifdef TERMS_NEIGHBOURS")
        function("void terms_begin(TermNode n)", "PREFIX_begin(n);", near)
        function("void terms_neighbour(inout vec3 f, TermNode n, int j, vec3 d)", "PREFIX_neighbour(f, n, j, d);", near)
        lines.append("#endif")
    implicit = [f for f in forms if f.implicit]
    if implicit:
        lines.append("#ifdef TERMS_IMPLICIT")
        function("void terms_product(inout vec3 q, TermNode n, vec3 y)", "PREFIX_product(q, n, y);", implicit)
        function("void terms_diagonal(inout vec3 d, inout vec3 off, inout float held, TermNode n)",
                 "PREFIX_diagonal(d, off, held, n);", implicit)
        near_implicit = [f for f in implicit if f.neighbours]
        if near_implicit:
            lines.append("#ifdef TERMS_NEIGHBOURS")
            function("void terms_neighbour_product(inout vec3 sk, inout vec3 dk, TermNode n, int j, vec3 dy)",
                     "PREFIX_neighbour_product(sk, dk, n, j, dy);", near_implicit)
            lines.append("#endif")
        lines.append("#endif")
    return "\n".join(lines) + "\n"


def pass_terms(terms: Sequence[Term], backend: str, caller: str, grid: NodeGrid | None, *,
               implicit: bool = False, prepass: bool = False) -> PassTerms:
    """The GLSL forms on ``grid`` of the ``terms`` that act, for a pass of ``backend``
    ("fragment" or "implicit"), after :func:`refuse_terms`; a one-line ValueError for a term
    without the implicit product in an implicit pass, a term with a pre-pass where the caller
    does not run one (``prepass`` False), two terms with node bits or one prefix."""
    refuse_terms(terms, backend, caller)
    forms = []
    for term in terms:
        if not term.acts():
            continue
        form = term.glsl(grid)
        if form is not None:
            check_inline(form.include, form.source, caller)
        if form is None:
            raise ValueError(f"{caller}: {term.name} have no GLSL form")
        if implicit and not form.implicit:
            raise ValueError(f"{caller}: {term.name} have no implicit product in GLSL")
        if form.passes and form.prepass is None:
            raise ValueError(f"{caller}: {term.name}'s GLSL form names passes of its own but has no pre-pass to run them")
        if form.prepass is not None and not prepass:
            raise ValueError(f"{caller}: {term.name} need a pass of their own before each force evaluation, "
                             f"which this pass does not run")
        forms.append(form)
    prefixes = [f.prefix for f in forms]
    if len(set(prefixes)) != len(prefixes):
        raise ValueError(f"{caller}: two terms share a GLSL prefix ({', '.join(prefixes)})")
    if sum(f.node_bits is not None for f in forms) > 1:
        raise ValueError(f"{caller}: two terms keep node bits; the node data has room for one term's")
    return PassTerms(tuple(forms), implicit)


def _compose_hook(parts: Sequence[tuple[str, str]], header: str, signature: str, call: str, guarded: bool) -> str:
    """A composed hook file: ``header`` (comment lines), each part's include, then ``signature``
    calling ``call`` (with PREFIX replaced) for each part in turn; ``parts`` are (prefix, include)
    pairs; ``guarded``: each under ``#ifdef TERM_<PREFIX>`` (the shipped file)."""
    lines = header.splitlines()

    def each(prefix: str, text: str) -> None:
        lines.extend([f"#ifdef TERM_{prefix.upper()}", text, "#endif"] if guarded else [text])

    for prefix, include in parts:
        each(prefix, f'#include "{include}"')
    lines.append(signature + " {")
    for prefix, _ in parts:
        each(prefix, "    " + call.replace("PREFIX", prefix))
    lines.append("}")
    return "\n".join(lines) + "\n"


def compose_feedback(forms: Sequence[FeedbackTerm], *, guarded: bool = False) -> str:
    """``terms/feedback.glsl`` of ``forms``: each chunk's include, then ``feedback_terms`` calling
    each term's ``PREFIX_feedback`` in turn (``guarded``: each under ``#ifdef TERM_<PREFIX>``, the
    shipped file)."""
    header = ("// The physics terms of the transform-feedback stages (deformgl/sim/terms). Composed by\n"
              "// deformgl/sim/terms/glsl.py compose_feedback(); do not edit: `python -m deformgl.sim.terms.registry`\n"
              "// writes the shipped one. Included by feedback/forces.glsl under FEEDBACK_TERMS.")
    return _compose_hook([(f.prefix, f.file) for f in forms], header, "void feedback_terms(inout vec3 f, int i, vec3 xi)",
                         "PREFIX_feedback(f, i, xi);", guarded)


def compose_xpbd(chunks: Sequence[XpbdChunk], *, guarded: bool = False) -> str:
    """``terms/xpbd.glsl`` of ``chunks``: each chunk's include, then ``xpbd_terms`` calling each
    term's ``PREFIX_xpbd`` in turn (``guarded``: each under ``#ifdef TERM_<PREFIX>``, the shipped file)."""
    header = ("// The physics terms of the XPBD node sweep (deformgl/sim/terms). Composed by\n"
              "// deformgl/sim/terms/glsl.py compose_xpbd(); do not edit: `python -m deformgl.sim.terms.registry`\n"
              "// writes the shipped one. Included by sim/xpbd/iterate.frag under XPBD_TERMS.")
    return _compose_hook([(c.prefix, c.file) for c in chunks], header,
                         "void xpbd_terms(inout vec3 dx, inout float counts, ivec2 texel, int flags, float wi)",
                         "PREFIX_xpbd(dx, counts, texel, flags, wi);", guarded)


def feedback_terms(terms: Sequence[Term], grid: NodeGrid | None, caller: str) -> tuple[FeedbackTerm, ...]:
    """The transform-feedback chunks on ``grid`` of the ``terms`` that act, after
    :func:`refuse_terms`; a one-line ValueError (starting with ``caller``) for a term with neither a
    chunk nor :meth:`~deformgl.sim.terms.base.Term.feedback_pairs`, or for data that does not fit."""
    refuse_terms(terms, "feedback", caller)
    forms = []
    for term in terms:
        if not term.acts() or term.feedback_pairs() is not None:
            continue
        try:
            form = term.feedback(grid)
        except ValueError as err:
            raise ValueError(f"{caller}: {err}") from None
        if form is None:
            raise ValueError(f"{caller}: {term.name} have no transform-feedback form")
        check_inline(form.file, form.source, caller)
        forms.append(form)
    prefixes = [f.prefix for f in forms]
    if len(set(prefixes)) != len(prefixes):
        raise ValueError(f"{caller}: two terms share a feedback prefix ({', '.join(prefixes)})")
    return tuple(forms)


def blocked_table(table: NodeTable, scatter: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """A node table in a blocked layout: (members * layers, bh, bw, 4), layer ``m * layers + l``
    holding layer l of member m (``scatter`` places (N, 4) values into (members, bh, bw, 4))."""
    per_layer = np.stack([scatter(table.layer(l)) for l in range(table.layers)], axis=1)
    return np.ascontiguousarray(per_layer.reshape(-1, *per_layer.shape[2:]), np.float32)
