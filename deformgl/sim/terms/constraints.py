"""A term's XPBD form (``Term.xpbd``): its constraints in float64 (:class:`TermConstraints`, solved
in the springs' Jacobi sweep by :class:`deformgl.sim.xpbd.XpbdSolver`), and on the GPU what
:class:`deformgl.sim.backends.xpbd_gpu.XpbdFragment` asks of the passes a term adds to its sweep
(:class:`XpbdPasses`, built by :meth:`TermConstraints.gpu`; the backend owns and releases them,
names none) and of its chunk in the node sweep (:class:`XpbdChunk`).

Per sweep from iterate set a to set b the backend calls :meth:`XpbdPasses.sweep` (the term's own
passes, e.g. a per-cell pass writing its multipliers' changes) before the node sweep, which then
gathers the term's corrections in its chunk (:class:`XpbdChunk`) from
what ``sweep`` left bound. The node data's flag word carries the term's node bits (bits 6-13,
``lib/node_flags.glsl`` ``term_bits``; one term per system may have them); the iterate's w holds
the sum of the terms' active constraints at the node after the sweep (the next sweep's n_i adds it).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from deformgl.grid.nodes import NodeGrid

if TYPE_CHECKING:  # (the float64 form needs no GL: the GPU side is typed only)
    import moderngl

    from deformgl.gl.programs import Program
    from deformgl.grid.nodes import CompactLayout

__all__ = ["TermConstraints", "XpbdChunk", "XpbdPasses"]


@dataclass(frozen=True)
class XpbdChunk:
    """A term's XPBD form on the GPU as the shader pack and the node sweep know it
    (:mod:`deformgl.sim.backends.xpbd_gpu`): the chunk ``file`` (under ``shaders/``) that the node
    sweep ``sim/xpbd/iterate.frag`` includes, through ``terms/xpbd.glsl``
    (:func:`deformgl.sim.terms.glsl.compose_xpbd`) under ``XPBD_TERMS``, defining::

        void PREFIX_xpbd(inout vec3 dx, inout float counts, ivec2 texel, int flags, float wi);
            // adds the node's corrections from the term's constraints (wi its inverse mass), and to
            // counts its constraints active after this sweep (the next sweep's n_i adds them)

    and the fragment shaders of the term's own passes (``passes``, drawn with
    ``sim/fullscreen.vert``), compiled with ``defines`` (one of ``variants`` where the pack
    enumerates them). ``source``: the chunk's text, given inline under the include name ``file``
    (a term outside the package), else the file is read.

    The chunk is included after the node sweep's own declarations and may read them:
    ``u_node`` (R inverse mass, G flags, A static constraint count) and ``u_p`` (the iterate, w the
    terms' active constraints after the last sweep), ``node_texel`` / ``texel_node``
    (``lib/node_texel.glsl``), ``term_bits(flags)`` (``lib/node_flags.glsl``: the node bits of
    :meth:`XpbdPasses.node_bits`); its own uniforms and samplers start with ``u_`` + prefix."""

    prefix: str
    file: str
    passes: tuple[str, ...] = ()
    defines: dict[str, object] = field(default_factory=dict)
    variants: tuple[dict[str, object], ...] = ()
    source: str | None = None

    def sweep_defines(self) -> dict[str, object]:
        """The defines the node sweep adds for this chunk."""
        return {"XPBD_TERMS": True, f"TERM_{self.prefix.upper()}": True, **self.defines}


class TermConstraints(ABC):
    """A term's XPBD form (Macklin, Müller & Chentanez 2016): its constraints, solved in the same
    Jacobi sweep as the springs' (:class:`deformgl.sim.xpbd.XpbdSolver`, float64), and their GPU
    passes (:meth:`gpu`). ``multipliers`` is whatever the form keeps per substep (its lambdas)."""

    @abstractmethod
    def static_counts(self) -> np.ndarray:
        """(N,) float64 its constraints at each node, always counted in n_i."""

    @abstractmethod
    def start(self) -> object:
        """The multipliers at a substep's start."""

    def dynamic_counts(self, multipliers: object) -> np.ndarray | None:
        """(N,) its constraints counted at each node this sweep on top of :meth:`static_counts`
        (e.g. the active ones of an inequality), from the last sweep's multipliers; None: none."""
        return None

    @abstractmethod
    def sweep(self, p: np.ndarray, multipliers: object, counts: np.ndarray, h: float, omega: float) -> np.ndarray:
        """One Jacobi sweep at the iterate p (N, 3), m, with n_i ``counts``, substep h (s) and
        relaxation omega: updates ``multipliers`` in place, returns the (N, 3) corrections, m."""

    @abstractmethod
    def residual_terms(self, p: np.ndarray, multipliers: object, h: float) -> tuple[np.ndarray, np.ndarray]:
        """(C, alpha~ lambda) of its constraints at p, in metres (they join the springs' relative
        residual |C + alpha~ lambda| / |C|)."""

    #: the term as messages name it (:func:`deformgl.sim.xpbd.term_constraints` sets the term's
    #: ``Term.name`` where a form leaves it empty)
    name: str = ""

    def gpu(self, ctx: "moderngl.Context", grid: NodeGrid, layout: "CompactLayout", omega: float,
            first_unit: int) -> XpbdPasses:
        """Its GPU form on the compact ``layout`` of ``grid``, its samplers on units from
        ``first_unit`` (the backend owns and releases it). A form without one does not override
        this: the GPU backend refuses it in one line naming the term before it builds anything."""
        raise NotImplementedError(f"{self.name or type(self).__name__}: no XPBD form on the GPU")


class XpbdPasses(Protocol):
    """A term's XPBD passes on the GPU (see the module docstring): a
    :class:`~deformgl.gl.resources.GLOwner` (the backend owns it and releases it) with these;
    subclass it after GLOwner (``class P(GLOwner, XpbdPasses)``: GLOwner's ``release``), and a
    method left out is an error when it is built.

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
        ...

    @abstractmethod
    def sweep_uniforms(self, program: Program) -> dict[str, object]:
        """The uniforms its chunk needs in the node sweep ``program`` (its samplers included)."""
        ...

    def node_bits(self) -> np.ndarray | None:
        """(N,) integers 0..255: its bits in the node flags, or None (the default)."""
        return None

    @abstractmethod
    def clear(self) -> None:
        """Zero its multipliers of set 0 (a substep's start)."""
        ...

    @abstractmethod
    def sweep(self, a: int, b: int) -> None:
        """Its passes from multiplier set ``a`` to ``b`` at the iterate bound to ``u_p``; leaves
        bound what the node sweep's chunk reads."""
        ...

    @abstractmethod
    def read(self, b: int) -> object:
        """Its multipliers of set ``b`` in float64, as :class:`TermConstraints`
        keeps them (the residual's read-back)."""
        ...

    @abstractmethod
    def release(self) -> None:
        """Release its GL objects (idempotent)."""
        ...
