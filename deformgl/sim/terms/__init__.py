"""Physics terms as objects (:class:`Term`): each declares what every backend needs of it
(:mod:`deformgl.sim.terms.base`); :mod:`deformgl.sim.terms.glsl` composes a pass's chunks."""

from deformgl.sim.terms.base import GlslTerm, NodeTable, Term, TermNeeds, block_diagonal

__all__ = ["GlslTerm", "NodeTable", "Term", "TermNeeds", "block_diagonal"]
