"""The GPU side of a term's XPBD form: what :class:`deformgl.sim.backends.xpbd_gpu.XpbdFragment`
asks of the passes a term adds to its Jacobi sweep (:meth:`deformgl.sim.terms.base.TermConstraints.gpu`
builds them; the backend owns and releases them, names none).

Per sweep from iterate set a to set b the backend calls :meth:`XpbdPasses.sweep` (the term's own
passes, e.g. a per-cell pass writing its multipliers' changes) before the node sweep, which then
gathers the term's corrections in its chunk (:class:`~deformgl.sim.terms.base.XpbdChunk`) from
what ``sweep`` left bound. The node data's flag word carries the term's node bits (bits 6-13,
``lib/node_flags.glsl`` ``term_bits``; one term per system may have them); the iterate's w holds
the sum of the terms' active constraints at the node after the sweep (the next sweep's n_i adds it).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner
from deformgl.sim.terms.base import XpbdChunk

__all__ = ["XpbdPasses"]


class XpbdPasses(GLOwner, ABC):
    """A term's XPBD passes on the GPU (see the module docstring).

    Attributes:
        chunk: its node-sweep chunk and pass shaders (with this instance's defines).
        samplers: its samplers in the node sweep and its passes, name -> texture unit.
        bytes_allocated: GPU bytes of its textures.
    """

    chunk: XpbdChunk
    samplers: dict[str, int]
    bytes_allocated: int

    @abstractmethod
    def programs(self) -> list[Program]:
        """Its own passes' programs: the backend sets on each the node sweep's shared samplers
        (``u_node``, ``u_p``), ``u_h`` and the layout's uniforms where they use them."""

    @abstractmethod
    def sweep_uniforms(self, program: Program) -> dict[str, object]:
        """The uniforms its chunk needs in the node sweep ``program`` (its samplers included)."""

    def node_bits(self) -> np.ndarray | None:
        """(N,) integers 0..255: its bits in the node flags, or None."""
        return None

    @abstractmethod
    def clear(self) -> None:
        """Zero its multipliers of set 0 (a substep's start)."""

    @abstractmethod
    def sweep(self, a: int, b: int) -> None:
        """Its passes from multiplier set ``a`` to ``b`` at the iterate bound to ``u_p``; leaves
        bound what the node sweep's chunk reads."""

    @abstractmethod
    def read(self, b: int) -> object:
        """Its multipliers of set ``b`` in float64, as :class:`~deformgl.sim.terms.base.TermConstraints`
        keeps them (the residual's read-back)."""
