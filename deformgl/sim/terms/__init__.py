"""Physics terms as objects (:class:`Term`): each declares what every backend needs of it
(:mod:`deformgl.sim.terms.base`; its XPBD form :mod:`deformgl.sim.terms.constraints`);
:mod:`deformgl.sim.terms.glsl` composes a pass's chunks."""

from deformgl.sim.terms.base import FeedbackTerm, GlslTerm, NodeTable, Term, TermNeeds, block_diagonal
from deformgl.sim.terms.constraints import TermConstraints, XpbdChunk, XpbdPasses

__all__ = ["FeedbackTerm", "GlslTerm", "NodeTable", "Term", "TermConstraints", "TermNeeds", "XpbdChunk", "XpbdPasses",
           "block_diagonal"]
