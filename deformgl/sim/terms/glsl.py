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

import moderngl
import numpy as np

from deformgl.sim.terms.base import GlslTerm, NodeTable, Term

__all__ = ["ACTIVE", "PassTerms", "pass_terms", "refuse_terms"]

#: The include name of the composed term list.
ACTIVE = "terms/active.glsl"
_NODE = "lib/term_node.glsl"


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
        """``TERMS`` (and ``TERMS_IMPLICIT``) where the pass has terms."""
        if not self.forms:
            return {}
        return {"TERMS": True, "TERMS_IMPLICIT": self.implicit}

    def chunks(self) -> dict[str, str]:
        """The include files given as text: each inline chunk, and ``terms/active.glsl``."""
        if not self.forms:
            return {}
        lines = ["// The physics terms of this pass (composed by deformgl/sim/terms/glsl.py)",
                 f'#include "{_NODE}"']
        lines += [f'#include "{form.include}"' for form in self.forms]
        lines.append("void terms_force(inout vec3 f, TermNode n) {")
        lines += [f"    {form.prefix}_force(f, n);" for form in self.forms]
        lines.append("}")
        if self.implicit:
            lines.append("void terms_product(inout vec3 q, TermNode n, vec3 y) {")
            lines += [f"    {form.prefix}_product(q, n, y);" for form in self.forms]
            lines.append("}")
            lines.append("void terms_diagonal(inout vec3 d, inout vec3 off, TermNode n) {")
            lines += [f"    {form.prefix}_diagonal(d, off, n);" for form in self.forms]
            lines.append("}")
        out = {ACTIVE: "\n".join(lines) + "\n"}
        for form in self.forms:
            if form.source is not None:
                out[form.include] = form.source
        return out

    @property
    def tables(self) -> tuple[NodeTable, ...]:
        """Every node table the pass samples, in order."""
        return tuple(t for form in self.forms for t in form.tables)

    def uniforms(self, units: Sequence[int]) -> dict[str, object]:
        """The terms' uniform values and their tables' samplers on ``units`` (one each, in the
        order of :attr:`tables`)."""
        tables = self.tables
        if len(tables) > len(units):
            raise ValueError(f"the terms sample {len(tables)} node tables; this pass has {len(units)} texture units "
                             f"left for them")
        out: dict[str, object] = {}
        for form in self.forms:
            out.update(form.uniforms)
        out.update({t.sampler: unit for t, unit in zip(tables, units)})
        return out

    def textures(self, make: Callable[[NodeTable], moderngl.TextureArray]) -> list[moderngl.TextureArray]:
        """One texture array per table, made by the backend in its node layout."""
        return [make(t) for t in self.tables]


def pass_terms(terms: Sequence[Term], backend: str, caller: str, *, implicit: bool = False) -> PassTerms:
    """The GLSL forms of ``terms`` for a pass of ``backend`` ("fragment" or "implicit"), after
    :func:`refuse_terms`."""
    refuse_terms(terms, backend, caller)
    forms = tuple(form for form in (t.glsl() for t in terms) if form is not None)
    prefixes = [f.prefix for f in forms]
    if len(set(prefixes)) != len(prefixes):
        raise ValueError(f"{caller}: two terms share a GLSL prefix ({', '.join(prefixes)})")
    return PassTerms(forms, implicit)


def blocked_table(table: NodeTable, scatter: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """A node table in a blocked layout: (members * layers, bh, bw, 4), layer ``m * layers + l``
    holding layer l of member m (``scatter`` places (N, 4) values into (members, bh, bw, 4))."""
    per_layer = np.stack([scatter(table.layer(l)) for l in range(table.layers)], axis=1)
    return np.ascontiguousarray(per_layer.reshape(-1, *per_layer.shape[2:]), np.float32)
