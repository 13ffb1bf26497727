"""The fragment backend's position-Verlet fast path as passes and a simulation: Mosegaard &
Sørensen 2005, section 3.1 — one fragment pass per step (:class:`VerletPass` on a one-node layout,
:class:`~deformgl.sim.backends.blocked.BlockedVerletPass` on the blocked layout), the spring force
of Mosegaard & Sørensen 2005, eq. 1 (Mosegaard & Sørensen 2005, eq. 2 where the classes share one
stiffness) and the packed node normal (Mosegaard & Sørensen 2005, eq. 3) written with the new position, so a mapped mesh draws straight from the state texture.
:class:`~deformgl.sim.backends.explicit_gpu.FragmentIntegrator` builds a :class:`FoundationVerlet` by
itself for Verlet when the pass models the system (:func:`~deformgl.sim.backends.verlet_data.verlet_terms`;
the textures and their channels: :mod:`deformgl.sim.backends.verlet_data`)."""

from __future__ import annotations

from functools import partial

import moderngl
import numpy as np

from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner, restore_framebuffer
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.backends.blocked import BlockedTextures, BlockedVerletPass, blocked_refusal, default_block
from deformgl.sim.backends.verlet_data import (HOOD_DIAGONAL_UNIT, MAX_PULLS, TERM_UNITS, WEIGHT_UNIT,
                                               NodeTextures, VerletTerms, node_data, node_flags, verlet_terms)
from deformgl.sim.backends.term_tables import TermTables
from deformgl.sim.backends.uniforms import pull_uniforms
from deformgl.sim.clock import SimulationBase
from deformgl.sim.integrators import State, initial_state
from deformgl.sim.stages import spec
from deformgl.sim.springs import SpringSystem
from deformgl.sim.scripted import Load, load_groups

__all__ = ["FoundationVerlet", "VerletPass"]


class VerletPass(GLOwner):
    """The position-Verlet fragment pass: one program, one draw per step, one triangle over the
    compact layout's texture (existing nodes packed in node order: one rectangle of texels).

    Args:
        ctx: GL context.
        terms: the pass's uniforms (decide the compiled variant: pulls).
        grid: the node grid.
        textures: the textures it reads and writes.
    """

    def __init__(self, ctx: moderngl.Context, terms: VerletTerms, grid: NodeGrid, textures: NodeTextures) -> None:
        super().__init__(ctx)
        layout = textures.layout
        self.n_pulls = terms.n_pulls
        with self.building():
            self.program = self.own(Program(ctx, "sim/fullscreen.vert", "sim/verlet.frag", defines={
                "PULLS": terms.n_pulls,
                "SPRING_WEIGHTS": textures.weights is not None or textures.weight_levels,
                "SPRING_WEIGHT_LEVELS": textures.weight_levels, **layout.shader_defines(),
                **terms.extra.defines()}, chunks=terms.extra.chunks()))
            if textures.hood_diagonals is not None:
                self.program.set(u_hood_diagonals=HOOD_DIAGONAL_UNIT)
            self.program.set(**layout.shader_uniforms(),
                             u_spacing=terms.spacing, u_k_structural=terms.k_structural,
                             u_k_shear=terms.k_shear, u_damping=terms.damping, u_mass_damping=terms.mass_damping,
                             u_gravity=terms.gravity, u_position=0, u_previous=1, u_node=2)
            if textures.weights is not None:
                self.program.set(u_weights=WEIGHT_UNIT)
            self.vao = self.own(ctx.vertex_array(self.program.gl, []))
        self._dt: float | None = None

    def run(self, textures: NodeTextures, current: int, previous: int, target: int, dt: float,
            pull: np.ndarray | None) -> None:
        """Draw one step: read state[current], state[previous], write state[target]."""
        if dt != self._dt:
            self.program.set(u_dt=dt)
            self._dt = dt
        self.program.set(**pull_uniforms(pull, self.n_pulls, "VerletPass.run"))
        textures.state[current].use(0)
        textures.state[previous].use(1)
        textures.bind_static(2)
        textures.framebuffers[target].use()
        self.vao.render(moderngl.TRIANGLES, vertices=3)


class FoundationVerlet(SimulationBase, GLOwner):
    """Position Verlet of a grid :class:`SpringSystem` in one fragment pass per step, the packed
    Mosegaard & Sørensen 2005, eq. 3 normal written with each position. Built by ``FragmentIntegrator`` (its Verlet fast
    path), which checks the system first (:func:`verlet_terms`).

    Args:
        ctx: GL context.
        system: the spring system; grid: its node grid; terms: :func:`verlet_terms` of both.
        dt: time step (s).
        state: the start state (x and x_prev are uploaded; fixed nodes get x_prev = x).
        loads: the scripted loads (pull groups), evaluated at ``t0 + steps * dt`` before each step.
        t0: time of the start state.
        weight_texture: see :class:`NodeTextures` (the tests and the study that compare the two).
        layout: "compact", "indexed" (:class:`NodeTextures`), "blocked" (``block`` nodes per
            fragment, :mod:`~deformgl.sim.backends.blocked`) or "auto" (``block`` if given, else
            :func:`~deformgl.sim.backends.blocked.default_block`, where the renderer can run it;
            else "compact").
        block: (x, y, z) nodes per fragment (:data:`~deformgl.grid.blocks.BLOCK_SHAPES`).

    Raises:
        ValueError: dt <= 0; "blocked" without a block, a block with another layout, a block the
            renderer cannot run
            (:func:`~deformgl.sim.backends.blocked.blocked_refusal`).
    """

    backend = "fragment"
    integrator = "verlet"
    #: the integrator it implements, as the stage table describes it (one stage, x_prev state)
    spec = spec("verlet")

    def __init__(self, ctx: moderngl.Context, system: SpringSystem, grid: NodeGrid, terms: VerletTerms,
                 dt: float, state: State, *, loads: tuple[Load, ...] = (), t0: float = 0.0,
                 layout: str = "compact", weight_texture: bool = False, block: tuple[int, int, int] | None = None) -> None:
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        if layout == "blocked" and block is None:
            raise ValueError("FoundationVerlet: the blocked layout takes a block shape")
        if layout not in ("auto", "blocked") and block is not None:
            raise ValueError(f"FoundationVerlet: layout {layout!r} takes no block shape")
        GLOwner.__init__(self, ctx)
        self.system, self.grid = system, grid
        self._start_clock(dt, t0)
        self.loads = tuple(loads)
        self.count = grid.count
        flags = node_flags(system.fixed, load_groups(self.loads, grid.count)) | terms.extra.node_bits(grid.count)
        x = np.asarray(state.x, np.float64)
        x_prev = np.where(system.fixed[:, None], x, np.asarray(state.x_prev, np.float64))
        if layout == "auto" and block is None:
            block = default_block(grid)
        why = None if block is None else blocked_refusal(ctx.info, block)
        if why is None and block is not None and terms.extra.others:
            why = f"the blocked layout cannot read other nodes' state by number, as {terms.extra.others[0].prefix} does"
        if why is not None and layout == "blocked":
            raise ValueError(f"FoundationVerlet: {why}")
        if why is not None:  # ("auto": the one-node layout where the renderer cannot run the block)
            block = None
        if layout == "auto":
            layout = "compact" if block is None else "blocked"
        #: the nodes per fragment (x, y, z) of the blocked layout, None on the one-node layouts
        self.block = block
        self.textures: NodeTextures | BlockedTextures
        self.verlet: VerletPass | BlockedVerletPass
        #: the physics terms' node tables in the layout (deformgl.sim.terms), or None
        self.term_tables: TermTables | None = None
        with self.building():
            if block is not None:
                node, levels = node_data(grid, system.mass, flags, terms.weights, weight_texture)
                blocked = self.own(BlockedTextures(ctx, grid, block, node, np.stack([x, x_prev, x]),
                                                   weights=None if levels else terms.weights))
                units = range(blocked.units["weights"] + 1, int(ctx.info.get("GL_MAX_TEXTURE_IMAGE_UNITS", 16)))
                self.term_tables = self.own(TermTables(ctx, terms.extra, grid, blocked.blocks, units))
                block_pass = self.own(BlockedVerletPass(ctx, terms, blocked, weight_levels=levels))
                block_pass.program.set(**self.term_tables.active_uniforms(block_pass.program))
                self.textures, self.verlet = blocked, block_pass
                #: one step: (current, previous, target, dt, pull forces)
                self._draw_step = partial(block_pass.run, blocked)
            else:
                textures = self.own(NodeTextures(ctx, grid, mass=system.mass, flags=flags, layout=layout,
                                                 positions=np.stack([x, x_prev, x]), weights=terms.weights,
                                                 weight_texture=weight_texture, hood=terms.extra.hood))
                one_pass = self.own(VerletPass(ctx, terms, grid, textures))
                if terms.extra:
                    self.term_tables = self.own(TermTables(ctx, terms.extra, grid, textures.layout, TERM_UNITS))
                    one_pass.program.set(**self.term_tables.active_uniforms(one_pass.program))
                self.textures, self.verlet = textures, one_pass
                self._draw_step = partial(one_pass.run, textures)
        self.current, self.previous, self.spare = 0, 1, 2
        self._pull = np.zeros((MAX_PULLS, 3))

    @classmethod
    def for_system(cls, ctx: moderngl.Context, system: SpringSystem, dt: float, *, loads: tuple[Load, ...] = (),
                   state: State | None = None, layout: str | None = None, weight_texture: bool = False,
                   block: tuple[int, int, int] | None = None) -> "FoundationVerlet":
        """The pass on ``system``'s own grid from rest (or ``state``), with the switches the user
        options leave out: ``layout="indexed"`` and ``weight_texture`` (the tests that check both
        lookups give the same step, and the studies that time them); ``block`` as
        :class:`~deformgl.sim.backends.explicit_gpu.FragmentIntegrator`'s. ``layout`` None:
        "compact", or "auto" with a ``block``.

        Raises:
            ValueError: the system has no grid, or the pass does not model it (naming what).
        """
        if system.grid is None:
            raise ValueError("FoundationVerlet.for_system: the system has no node grid")
        terms = verlet_terms(system, system.grid, loads=loads)
        if isinstance(terms, str):
            raise ValueError(f"FoundationVerlet.for_system: the pass does not model {terms}")
        start = initial_state(system, dt, loads=loads) if state is None else state
        layout = layout or ("compact" if block is None else "auto")
        return cls(ctx, system, system.grid, terms, dt, start, loads=loads, layout=layout,
                   weight_texture=weight_texture, block=block)

    @property
    def position_texture(self) -> moderngl.Texture:
        """The state texture holding the latest positions and packed normals (the blocked layout's
        compact view)."""
        return self.textures.view(self.current)

    def position_slot(self) -> tuple[moderngl.Texture, int, int, int]:
        """(texture, nodes per row, texels per node, slot) of the latest positions, for
        :class:`~deformgl.sim.census.NodeCensus` (node n is texel (n % width, n // width), the
        blocked layout's compact view included; w, the packed normal, is not looked at)."""
        return self.position_texture, self.textures.layout.width, 1, 0

    def step(self, n: int = 1) -> None:
        """Advance n steps on the GPU (no read-back)."""
        if self.released:
            raise RuntimeError("FoundationVerlet: released")
        previous = self.ctx.fbo
        try:
            for _ in range(n):
                if self.loads:
                    t = self.t
                    for g, load in enumerate(self.loads):
                        self._pull[g] = np.asarray(load.force(t), dtype=np.float64)
                if self.term_tables is not None:
                    self.term_tables.bind()
                self._draw_step(self.current, self.previous, self.spare, self.dt, self._pull)
                self.current, self.previous, self.spare = self.spare, self.current, self.previous
                self._tick()
        finally:
            restore_framebuffer(self.ctx, previous)  # the caller's framebuffer, as every backend

    def read_state(self, which: int | None = None) -> np.ndarray:
        """(N, 4) float32 texel of every node from a state texture (default: current)."""
        if self.released:
            raise RuntimeError("FoundationVerlet: released")
        return self.textures.read(self.current if which is None else which)

    def positions(self) -> np.ndarray:
        """(N, 3) float32 current node positions (one read-back)."""
        return self.read_state()[:, :3].copy()

    def velocities(self) -> np.ndarray:
        """(N, 3) backward difference (x - x_prev)/dt in float64 of the float32 positions, 0 at
        fixed nodes (as the general Verlet stage and the reference)."""
        x = self.read_state()[:, :3].astype(np.float64)
        xp = self.read_state(self.previous)[:, :3].astype(np.float64)
        return np.where(self.system.fixed[:, None], 0.0, (x - xp) / self.dt)

    def normals(self) -> np.ndarray:
        """(N,) float32 packed Mosegaard & Sørensen 2005, eq. 3 normals stored with the current positions (one read-back)."""
        return self.read_state()[:, 3].copy()

    @property
    def bytes_per_node(self) -> float:
        """GPU bytes of all textures per node."""
        return self.textures.bytes_allocated / self.count

    def release(self) -> None:
        """Release every GL object (idempotent); the context's default framebuffer is bound if
        one of the state framebuffers was."""
        textures = getattr(self, "textures", None)  # (None when the constructor failed before it)
        if not self.released and textures is not None and any(self.ctx.fbo is f for f in textures.framebuffers):
            self.ctx.detect_framebuffer(0).use()
        GLOwner.release(self)
