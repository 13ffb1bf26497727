"""Count the nodes of a GPU state texture that satisfy a predicate, without reading the state back.

A census is one fragment pass over ``row x rows`` fragments, fragment ``(i, j)`` being the node at
texel ``(i, j)`` of the node layout (``shaders/lib/node_texel.glsl``, node ``j * row + i``), into a small framebuffer of its own (an R8 renderbuffer). Fragments whose
predicate is false are discarded, those past the last node too, and an occlusion query counts
the survivors: the only thing that crosses to the CPU is that one integer per query. OpenGL ES
counts no samples (``GL_SAMPLES_PASSED`` is desktop only): there the query is
``GL_ANY_SAMPLES_PASSED`` (:class:`~deformgl.gl.es_context.AnySamplesQuery`) and a count is 0
or 1 ("at least one"), which is all the convergence stop and the blow-up guard ask (``== 0``).

State textures are RGBA32F, read with ``texelFetch``; slot ``s`` of node ``n`` is texel
``(slots * (n % row) + s, n / row)`` (``node_slot_texel``; ``row`` a power of two): ``slots = 1, row = layout.width`` for
:class:`~deformgl.sim.backends.explicit_gpu.FragmentIntegrator`, ``slots = 2, row = node_row`` for
the ``tex_state`` of :class:`~deformgl.sim.backends.feedback.FeedbackSimulation` (``slots = 1`` for its
Verlet ``tex_x``). Only xyz is looked at; w (mass, a packed normal) is ignored.

Each pass runs with every enable flag off (no depth test, blending or culling, through a
``ctx.scope``) and gives the caller its framebuffer and enable flags back afterwards.
"""

from __future__ import annotations

import moderngl

from deformgl.gl.es_context import AnySamplesQuery
from deformgl.gl.programs import Program, profile_of
from deformgl.gl.resources import GLOwner, is_released
from deformgl.grid.nodes import layout_uniforms

__all__ = ["NodeCensus"]


class NodeCensus(GLOwner):
    """Counts of nodes moved or gone bad, and GPU snapshots of one slot, for one node layout.

    Args:
        ctx: the GL context.
        count: nodes (>= 1); texels of node number ``count`` and beyond are never counted.
        row: nodes per texture row (a power of two, the layout's width).
        slots: texels per node in the textures passed as ``now`` / ``state`` (>= 1).
    """

    def __init__(self, ctx: moderngl.Context, *, count: int, row: int, slots: int = 1) -> None:
        if count < 1 or row < 1 or slots < 1:
            raise ValueError(f"NodeCensus: count {count}, row {row}, slots {slots}: need >= 1")
        if row & (row - 1):
            raise ValueError(f"NodeCensus: row {row}: the node layout's width is a power of two")
        self.ctx = ctx
        self.count, self.row, self.slots = int(count), int(row), int(slots)
        self.rows = -(-self.count // self.row)
        GLOwner.__init__(self, ctx)
        self._passes: dict[str, tuple[Program, moderngl.VertexArray]] = {}
        self._snapshot: moderngl.Texture | None = None
        self._snapshot_fbo: moderngl.Framebuffer | None = None
        with self.building():
            marks = self.own(ctx.renderbuffer((self.row, self.rows), 1, dtype="f1"))
            self._fbo = self.own(ctx.framebuffer(color_attachments=[marks]))
            # moderngl 5.13 queries have no release(); one per census, freed with the context
            self._query: moderngl.Query | AnySamplesQuery = (
                self.own(AnySamplesQuery()) if profile_of(ctx) == "es" else ctx.query(samples=True))

    def _check(self, tex: moderngl.Texture, slots: int, slot: int, name: str) -> None:
        if not 0 <= slot < slots:
            raise ValueError(f"NodeCensus: {name} slot {slot} outside 0..{slots - 1}")
        if tex.components != 4 or tex.dtype != "f4":
            raise ValueError(f"NodeCensus: {name} must be an RGBA32F texture")
        if tex.width < slots * self.row or tex.height < self.rows:
            raise ValueError(f"NodeCensus: {name} is {tex.width}x{tex.height} texels, "
                             f"{slots * self.row}x{self.rows} needed")

    def _run(self, mode: str, fbo: moderngl.Framebuffer, textures: dict[str, moderngl.Texture],
             uniforms: dict[str, object], *, counted: bool) -> int:
        """One pass of variant ``mode`` into ``fbo``; the surviving fragments if ``counted``."""
        if self._released:
            raise RuntimeError("NodeCensus: released")
        if mode not in self._passes:
            program = self.own(Program(self.ctx, "sim/fullscreen.vert", "census/census.frag",
                                       defines={mode: True}))
            self._passes[mode] = (program, self.own(self.ctx.vertex_array(program.gl, [])))
        program, vao = self._passes[mode]
        for unit, (sampler, tex) in enumerate(textures.items()):
            tex.use(unit)
            uniforms[sampler] = unit
        program.set(**layout_uniforms(self.row), u_count=self.count, **uniforms)
        previous = self.ctx.fbo
        if previous is None or is_released(previous):
            # the caller's framebuffer was released: leave framebuffer 0 bound afterwards
            self.ctx.detect_framebuffer(0).use()
        scope = self.ctx.scope(fbo, enable_only=moderngl.NOTHING)
        try:
            with scope:
                if not counted:
                    vao.render(moderngl.TRIANGLES, vertices=3)
                    return 0
                with self._query:
                    vao.render(moderngl.TRIANGLES, vertices=3)
            return int(self._query.samples)
        finally:
            scope.release()

    def moved(self, now: moderngl.Texture, before: moderngl.Texture, threshold: float, *,
              slot: int = 0, before_slots: int | None = None,
              before_slot: int | None = None) -> int:
        """Number of nodes with ``length(now.xyz - before.xyz) > threshold`` (float32, strict).

        A node whose xyz is NaN or +-Inf in ``now`` or ``before`` counts as moved. ``now`` has
        ``slots`` texels per node and is read at ``slot``; ``before`` has ``before_slots``
        (default: 1 for this census's :meth:`snapshot`, else ``slots``) and is read at
        ``before_slot`` (default: 0 for a 1-slot texture, else ``slot``). One integer crosses
        to the CPU.
        """
        if before_slots is None:
            before_slots = 1 if before is self._snapshot else self.slots
        bslots = int(before_slots)
        bslot = (0 if bslots == 1 else slot) if before_slot is None else int(before_slot)
        self._check(now, self.slots, slot, "now")
        self._check(before, bslots, bslot, "before")
        return self._run("MOVED", self._fbo, {"u_state": now, "u_before": before}, {
            "u_slots": self.slots, "u_slot": slot, "u_before_slots": bslots,
            "u_before_slot": bslot, "u_threshold": float(threshold)}, counted=True)

    def bad(self, state: moderngl.Texture, limit: float, *, slot: int = 0) -> int:
        """Number of nodes whose xyz at ``slot`` has a NaN or +-Inf component or one with
        ``|component| > limit``. One integer crosses to the CPU."""
        self._check(state, self.slots, slot, "state")
        return self._run("BAD", self._fbo, {"u_state": state}, {
            "u_slots": self.slots, "u_slot": slot, "u_limit": float(limit)}, counted=True)

    def snapshot(self, state: moderngl.Texture, *, slot: int = 0) -> moderngl.Texture:
        """Copy slot ``slot`` of every node of ``state`` into this census's 1-slot RGBA32F
        texture (``row x rows``, all four channels, bit-exact) by a pass on the GPU; nothing is
        read back. The same texture is returned, overwritten, on every call."""
        self._check(state, self.slots, slot, "state")
        if self._snapshot is None:
            tex = self.own(self.ctx.texture((self.row, self.rows), 4, dtype="f4"))
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
            tex.repeat_x = tex.repeat_y = False
            self._snapshot_fbo = self.own(self.ctx.framebuffer(color_attachments=[tex]))
            self._snapshot = tex
        assert self._snapshot_fbo is not None
        self._run("COPY", self._snapshot_fbo, {"u_state": state},
                  {"u_slots": self.slots, "u_slot": slot}, counted=False)
        return self._snapshot

    def release(self) -> None:
        """Release every GL object this census owns (idempotent)."""
        GLOwner.release(self)
        self._passes.clear()
        self._snapshot = self._snapshot_fbo = None
