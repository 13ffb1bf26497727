"""The five integrators of Movania & Feng 2012 on the fragment backend (grid topology).

Each stage of a step is a fragment pass over the compact node texture (one texel per node,
Mosegaard & Sørensen 2005, section 3.1; ``grid.CompactLayout``): positions and velocities live in
RGBA32F textures, a pass that produces both writes them together with multiple render targets,
and midpoint / RK4 stages go into stage textures. It computes the same function as the float64
reference :func:`deformgl.sim.integrators.step`, in float32, for systems built by
:func:`deformgl.sim.springs.from_grid` or :func:`deformgl.sim.springs.cloth` on the given grid.

Topology is implicit: the neighbours come from a neighbour-index texture array (the 18
``NEIGHBOUR_OFFSETS`` of the compact layout, plus the 6 flexion neighbours at distance 2 along
an axis when the system has flexion springs; an absent one points at the node itself). Per-class
stiffness, rest length and spring damping are uniforms (``from_grid`` gives one value per class);
a system whose springs of a class differ in stiffness (the calibrated lattice of
:mod:`deformgl.sim.materials`) adds a weight texture: each spring's stiffness and damping are
the class's times its weight;
per-node mass and the fixed flag are a static RGBA32F texture. The constructor checks that the
system's springs are exactly the grid's.

The system's physics terms (``system.terms``, :mod:`deformgl.sim.terms`) are compiled into the
same passes (define ``TERMS``, their chunks composed by
:mod:`deformgl.sim.terms.glsl`), their node tables and pre-pass outputs bound from :data:`_TERM_UNIT`; a term that reads
the grid neighbours is gathered in the same loop as the springs, and one that reads the node's
3x3x3 neighbourhood from the 18 neighbour positions the springs fetched and, where it needs them,
the 8 body diagonals (``shaders/lib/node_hood.glsl``).

GPU textures (all ``width x rows`` texels of the compact layout, NEAREST, ``texelFetch``):

* static: node data RGBA32F (R mass, G flags: 1 exists, 2 fixed, 64 << b the terms' node bits,
  B load-group bits, A the neighbour mask on dense grids), neighbours RGBA32I array of 5 layers
  (6 with flexion; not on dense grids); with a term that reads the body diagonals on grids that
  are not dense, their table, RGBA32I array of 2 layers (the nodes at (±1, ±1, ±1),
  :func:`~deformgl.grid.neighbours.diagonal_table`); the terms' node tables;
* state (``state_bytes_per_node`` = 16 x the vec4s of :data:`integrators.GPU_BUFFERS`):
  euler / semi-implicit x, v, x', v'; midpoint x, v, x_m, v_m, x', v'; rk4 x, v and two stage
  sets (x_s, v_s, sum_x, sum_v) used ping-pong; verlet three rotating positions (no velocity).

The passes, the buffers and their rotation after a step come from the integrator's
:func:`deformgl.sim.stages.spec` (one pass per stage, the pool in ``spec.buffers`` order,
``roles[i]`` the pool index playing ``spec.buffers[i]``).

Loads (per-node scripted forces) and drags (a stiff spring from one node to a moving target)
are uniforms set before each pass at the pass's stage time, as on the feedback backend.

Nothing is read back while stepping; only :meth:`FragmentIntegrator.positions` and
:meth:`FragmentIntegrator.velocities` read.
"""

from __future__ import annotations

import moderngl
import numpy as np

from deformgl.gl.es_context import read_texture
from deformgl.sim.backends.uniforms import sphere_uniforms, uniform_array
from deformgl.sim.clock import SimulationBase

from deformgl.grid.nodes import NEIGHBOUR_OFFSETS, NodeGrid, layout_uniforms
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS, Constraints, State, initial_state
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner, restore_framebuffer
from deformgl.sim.springs import SpringSystem
from deformgl.sim.scripted import Drag, Load, load_groups
from deformgl.sim.backends.blocked import BlockedTextures
from deformgl.sim.backends.verlet_data import NodeTextures, VerletTerms, node_flags, verlet_terms
from deformgl.sim.backends.verlet_pass import FoundationVerlet
from deformgl.grid.neighbours import FLEXION_OFFSETS
from deformgl.sim.backends.grid_springs import compact_layout, grid_springs, spring_weights
from deformgl.sim.stages import BUFFERS, Stage, spec
from deformgl.sim.terms.glsl import pass_terms
from deformgl.sim.backends.compact_textures import compact_image, float_texture, layer_texture
from deformgl.grid.neighbours import diagonal_table

__all__ = ["FOUNDATION_LAYOUTS", "FragmentIntegrator", "PATHS"]

#: How the fragment backend runs Verlet (see :class:`FragmentIntegrator`).
PATHS = ("auto", "general", "foundation")
#: The foundation pass's node layouts (``layout=``, see :class:`FragmentIntegrator`).
FOUNDATION_LAYOUTS = ("auto", "compact", "blocked")

_VEC4 = 16
_SAMPLERS = {"u_node": 0, "u_neighbours": 1, "u_x": 2, "u_v": 3, "u_x_prev": 3, "u_xs": 4,
             "u_vs": 5, "u_sum_x": 6, "u_sum_v": 7, "u_weights": 8}
#: texture unit of the neighbourhood's body-diagonal table (HOOD_DIAGONALS on grids that are not dense)
_HOOD_DIAGONAL_UNIT = 9
#: the first texture unit of the physics terms' tables and pre-pass outputs (deformgl.sim.terms):
#: they take the units from it to the context's GL_MAX_TEXTURE_IMAGE_UNITS (16 at least)
_TERM_UNIT = 10


def _sampler(buffer: str) -> str:
    """The ``step.frag`` sampler a buffer is read with (``stages.BUFFERS``: kind, quantity)."""
    kind, quantity = BUFFERS[buffer]
    return {"state": f"u_{quantity}", "stage": f"u_{quantity}s", "sum": f"u_sum_{quantity}"}[kind]


class FragmentIntegrator(SimulationBase, GLOwner):
    """A grid :class:`SpringSystem` stepped by fragment passes with one of the five integrators.

    Args:
        ctx: the GL context.
        system: spring system from :func:`springs.from_grid` / :func:`springs.cloth` on ``grid``.
        grid: the node grid (node order of the system).
        integrator: one of :data:`deformgl.sim.integrators.EXPLICIT_INTEGRATORS`.
        dt: step in s, > 0.
        constraints: ground plane and (static or moving) spheres, or None.
        drags: scripted drags (targets evaluated at each pass's stage time, as uniforms).
        loads: scripted per-node forces (at most ``scripted.MAX_LOADS``).
        state: start state (default :func:`integrators.initial_state` at rest); Verlet uses its
            ``x_prev``.
        t0: time of the start state.
        path: "auto" (default): Verlet runs on the foundation pass of Mosegaard & Sørensen 2005,
            section 3.1 (:mod:`~deformgl.sim.backends.verlet_data`: one pass per step, the packed
            node normal written with each position, :attr:`packed_normals`) whenever that pass
            models the system and options (:func:`~deformgl.sim.backends.verlet_data.verlet_terms`),
            every other case on the stages of :data:`deformgl.sim.stages.SPECS`; "general": the
            stages always; "foundation": the foundation pass or a ValueError saying why not.
        layout: the foundation pass's node layout: "auto" (default): several nodes per fragment
            (the blocked layout, :mod:`~deformgl.sim.backends.blocked`) where
            :func:`~deformgl.sim.backends.blocked.default_block` measured it faster and the pass
            models the system in blocks, else "compact"; "compact" (one node per fragment), or
            "blocked" with ``block`` (which needs ``path="foundation"`` or a system the pass
            models). The general stages always use the compact layout.
        block: (x, y, z) nodes per fragment (:data:`~deformgl.grid.blocks.BLOCK_SHAPES`): the
            blocked layout in that shape (node positions bit for bit those of "compact").

    Raises:
        ValueError: unknown integrator or path, dt <= 0, a drag on a node that does not exist,
            too many loads, a system that is not the grid's, ``path="foundation"`` on a system
            or integrator the foundation pass does not model.
        GLError: the grid does not fit in a texture.
    """

    backend = "fragment"

    def __init__(self, ctx: moderngl.Context, system: SpringSystem, grid: NodeGrid | None,
                 integrator: str, dt: float, *, constraints: Constraints | None = None,
                 drags: tuple[Drag, ...] = (), loads: tuple[Load, ...] = (),
                 state: State | None = None, t0: float = 0.0, path: str = "auto", layout: str = "auto",
                 block: tuple[int, int, int] | None = None) -> None:
        grid = system.grid if grid is None else grid
        if grid is None:
            raise ValueError("FragmentIntegrator: the system has no node grid (build it with "
                             "springs.from_grid or springs.cloth, or pass grid=)")
        if path not in PATHS:
            raise ValueError(f"FragmentIntegrator: path must be one of {', '.join(PATHS)}, got {path!r}")
        if integrator not in EXPLICIT_INTEGRATORS:
            raise ValueError(f"unknown integrator {integrator!r}; expected one of "
                             f"{', '.join(EXPLICIT_INTEGRATORS)}")
        #: the integrator's stages, buffers and role rotation (``deformgl.sim.stages``)
        self.spec = spec(integrator)
        if not dt > 0:
            raise ValueError(f"FragmentIntegrator: dt must be > 0, got {dt}")
        if grid.count == 0:
            raise ValueError("FragmentIntegrator: the grid has no nodes")
        self.ctx = ctx
        self.system = system
        self.grid = grid
        self.integrator = integrator
        self._start_clock(dt, t0)
        self.constraints = constraints
        self.count = grid.count
        self.drags = tuple(drags)
        self.loads = tuple(loads)
        self.load_bits = load_groups(self.loads, self.count)
        for drag in self.drags:
            if not 0 <= drag.node < self.count:
                raise ValueError(f"FragmentIntegrator: drag node {drag.node} outside the system")
        self.flexion, self.neighbour_table, self.classes = grid_springs(system, grid)
        #: the foundation pass when it runs this simulation (see ``path``), else None
        self.fast: FoundationVerlet | None = None
        self._fbos: dict[tuple[int, ...], moderngl.Framebuffer] = {}
        self.passes: dict[str, Program] = {}
        if layout not in FOUNDATION_LAYOUTS:
            raise ValueError(f"FragmentIntegrator: layout must be one of {', '.join(FOUNDATION_LAYOUTS)}, got {layout!r}")
        if block is not None and layout == "auto":
            layout = "blocked"
        terms = self._fast_path(path, layout)
        if terms is not None:
            GLOwner.__init__(self, ctx)
            start = (initial_state(system, self.dt, t=self.t, drags=self.drags, loads=self.loads)
                     if state is None else state)
            with self.building():
                self.fast = self.own(FoundationVerlet(ctx, system, grid, terms, self.dt, start, loads=self.loads,
                                                      t0=self.t, layout=layout, block=block))
            return
        self.layout = compact_layout(grid, int(ctx.info["GL_MAX_TEXTURE_SIZE"]))
        #: every node of the box exists: neighbours by node-number offsets, no index texture
        self.dense = self.layout.dense
        offsets = np.concatenate([NEIGHBOUR_OFFSETS, FLEXION_OFFSETS])[: self.neighbour_table.shape[1]]
        self.neighbour_offsets = [int(v) for v in offsets @ np.array(self.layout.strides)]
        GLOwner.__init__(self, ctx)
        with self.building():
            self._build(state)

    # -- construction ------------------------------------------------------------------------

    def _fast_path(self, path: str, layout: str) -> VerletTerms | None:
        """The foundation pass's terms when it runs this simulation, None for the stages."""
        variant = layout == "blocked"  # (the general stages run the compact layout only)
        verlet = self.spec is FoundationVerlet.spec  # the one integrator the pass implements
        if path == "general" or (path == "auto" and not verlet):
            if variant:
                raise ValueError("FragmentIntegrator: the blocked layout is the foundation pass's (path='foundation')")
            return None
        if not verlet:
            raise ValueError(f"FragmentIntegrator: the foundation pass is {FoundationVerlet.integrator}, "
                             f"not {self.integrator}")
        terms = verlet_terms(self.system, self.grid, loads=self.loads, drags=self.drags,
                             constraints=self.constraints)
        if isinstance(terms, VerletTerms):
            return terms
        if path == "foundation" or variant:
            raise ValueError(f"FragmentIntegrator: the foundation pass does not model {terms}")
        return None

    @property
    def foundation(self) -> FoundationVerlet:
        """The foundation pass running this simulation (``path="foundation"`` guarantees one)."""
        if self.fast is None:
            raise RuntimeError("FragmentIntegrator: this simulation runs the general stages, not the foundation pass")
        return self.fast

    @property
    def block(self) -> tuple[int, int, int] | None:
        """The nodes per fragment (x, y, z) of the foundation pass's blocked layout, None on a
        one-node layout or the general stages."""
        return None if self.fast is None else self.fast.block

    @property
    def packed_normals(self) -> bool:
        """The position texture's w holds the packed node normal of Mosegaard & Sørensen
        2005, eq. 3 (the foundation pass): the mappings can draw from it directly."""
        return self.fast is not None

    @property
    def position_texture(self) -> moderngl.Texture:
        """The texture holding the latest positions (xyz; w: packed normal on the foundation pass)."""
        return self.position_slot()[0]

    @property
    def textures(self) -> NodeTextures | BlockedTextures:
        """The foundation pass's node textures (its layout, static data and state)."""
        if self.fast is None:
            raise AttributeError("FragmentIntegrator.textures: only the foundation pass has node textures")
        return self.fast.textures


    def _texture(self, image: np.ndarray | None) -> moderngl.Texture:
        return float_texture(self, self.ctx, self.layout.size, image)

    def _image(self, values: np.ndarray) -> np.ndarray:
        return compact_image(self.layout.size, values)

    def _build(self, state: State | None) -> None:
        system, n = self.system, self.count
        w, h = self.layout.size
        nb = self.neighbour_table
        layers = -(-nb.shape[1] // 4)
        self.tex_neighbours = None
        mask = np.zeros(n)
        if self.dense:
            # neighbours by arithmetic: bit j of the mask (exact in float32: at most 24 bits)
            bits = (nb >= 0).astype(np.int64) << np.arange(nb.shape[1])
            mask = np.bitwise_or.reduce(bits, axis=1).astype(np.float64)
        else:
            # (columns past the table, never read: the loops stop at NB_COUNT)
            self.tex_neighbours = layer_texture(self, self.ctx, (w, h), np.where(nb >= 0, nb, np.arange(n)[:, None]),
                                                "i4", layers)
        #: per-spring stiffness as weights of the class's k (the calibrated lattice), or None
        self.tex_weights: moderngl.TextureArray | None = None
        weights = spring_weights(system, nb, [c[0] for c in self.classes])
        if weights is not None:
            self.tex_weights = layer_texture(self, self.ctx, (w, h), weights, "f4", layers)
        #: the texture units of the terms' tables and pre-pass outputs
        self._term_units = tuple(range(_TERM_UNIT, int(self.ctx.info["GL_MAX_TEXTURE_IMAGE_UNITS"])))
        #: the system's physics terms as this backend's passes compile them (deformgl.sim.terms)
        self.terms = pass_terms(system.terms, "fragment", "FragmentIntegrator", self.grid, prepass=True)
        self.term_textures: list[moderngl.Texture | moderngl.TextureArray] = list(self.terms.textures(
            lambda t: layer_texture(self, self.ctx, (w, h), t.values, "f4", t.layers)))
        #: the terms' own passes, run before each stage on its evaluation positions (GlslTerm.prepass)
        self.term_passes = [self.own(form.prepass(self.ctx, layout_uniforms(self.layout.width)))
                            for form in self.terms.prepasses if form.prepass is not None]
        self.term_textures += [tex for p in self.term_passes for tex in p.textures()]
        #: the body diagonals of the node's neighbourhood, for a term that reads them on a grid
        #: that is not dense (HOOD_DIAGONALS, lib/node_hood.glsl), or None
        self.tex_hood_diagonals: moderngl.TextureArray | None = None
        if self.terms.hood > 1 and not self.dense:
            self.tex_hood_diagonals = layer_texture(self, self.ctx, (w, h), diagonal_table(self.grid), "i4", 2)
        flags = node_flags(system.fixed) | self.terms.node_bits(n)
        node = np.stack([system.mass, flags, self.load_bits, mask], axis=1)
        self.tex_node = self._texture(self._image(node))

        s = (initial_state(system, self.dt, t=self.t, drags=self.drags, loads=self.loads)
             if state is None else state)
        x = np.asarray(s.x, np.float64)
        v = np.where(system.fixed[:, None], 0.0, np.asarray(s.v, np.float64))
        if x.shape != (n, 3) or v.shape != (n, 3):
            raise ValueError(f"FragmentIntegrator: state of shape {x.shape}, expected ({n}, 3)")
        sp = self.spec
        start = {"x": x, "v": v, "x_prev": s.x_prev}
        # one texture per buffer of the spec; roles[i]: the pool index playing sp.buffers[i]
        self.pool = [self._texture(self._image(start[b]) if b in sp.state else None)
                     for b in sp.buffers]
        self.roles = list(range(len(self.pool)))
        self._index = {b: i for i, b in enumerate(sp.buffers)}

        common: dict[str, object] = {"NB_LAYERS": layers, "NB_COUNT": nb.shape[1], "DENSE": self.dense,
                                     "SPRING_DAMPING": bool(np.any(system.damping > 0)),
                                     "SPRING_WEIGHTS": self.tex_weights is not None,
                                     "SPHERES": 0, "DRAGS": len(self.drags),
                                     "LOADS": len(self.loads)}
        if system.wind_drag > 0:
            common["WIND"] = True
        common.update(self.terms.defines())
        if sp.velocity:
            common["VELOCITY"] = True
        c = self.constraints
        final: dict[str, object] = dict(common)
        if c is not None and (c.ground is not None or c.spheres):
            final.update(CONSTRAINTS=True, GROUND=c.ground is not None, SPHERES=len(c.spheres))
        for stage in sp.stages:
            self._add(stage.name, {**(final if stage.final else common), **stage.fragment_defines()})
        self._vaos = {key: self.own(self.ctx.vertex_array(p.gl, []))
                      for key, p in self.passes.items()}
        self.state_bytes = len(self.pool) * w * h * _VEC4
        static = w * h * _VEC4 + (0 if self.dense else w * h * layers * _VEC4) + \
            (0 if self.tex_weights is None else w * h * layers * _VEC4) + \
            (0 if self.tex_hood_diagonals is None else w * h * 2 * _VEC4)
        static += sum(w * h * t.layers * _VEC4 for t in self.terms.tables)
        static += sum(p.bytes_allocated for p in self.term_passes)
        self.bytes_allocated = self.state_bytes + static

    def _add(self, key: str, defines: dict[str, object]) -> None:
        program = self.own(Program(self.ctx, "sim/fullscreen.vert",
                                    "sim/integrators/step.frag", defines=defines, chunks=self.terms.chunks()))
        self.passes[key] = program
        system = self.system
        (k1, l1, c1), (k2, l2, c2), (k3, l3, c3) = self.classes
        members = program.members
        uniforms: dict[str, object] = {
            **{s: u for s, u in _SAMPLERS.items() if s in members},
            **layout_uniforms(self.layout.width), "u_dt": self.dt,
            "u_k": (k1, k2, k3), "u_rest": (l1, l2, l3),
            "u_gravity": tuple(float(g) for g in system.gravity),
            "u_velocity_damping": system.velocity_damping,
            "u_mass_damping": system.mass_damping}
        if defines.get("WIND"):
            uniforms.update(u_wind=tuple(float(g) for g in system.wind),
                            u_wind_drag=system.wind_drag)
        if self.drags:
            uniforms["u_drag_node"] = uniform_array([d.node for d in self.drags])
            uniforms["u_drag_k"] = uniform_array([float(d.stiffness) for d in self.drags])
        if defines.get("SPRING_DAMPING"):
            uniforms["u_c"] = (c1, c2, c3)
        if defines.get("DENSE"):
            uniforms["u_offsets"] = self.neighbour_offsets
        if self.tex_hood_diagonals is not None:
            uniforms["u_hood_diagonals"] = _HOOD_DIAGONAL_UNIT
        if self.terms:
            # (a term's uniform may be used in its implicit functions only: set where active)
            uniforms.update({k: v for k, v in self.terms.uniforms(self._term_units).items() if k in members})
        if defines.get("GROUND"):  # (set only with a ground plane)
            c = self.constraints
            if c is None or c.ground is None:
                raise RuntimeError("FragmentIntegrator: GROUND defined without a ground plane")
            uniforms["u_ground"] = float(c.ground)
        program.set(**uniforms)

    # -- stepping ----------------------------------------------------------------------------

    def _fbo(self, targets: tuple[int, ...]) -> moderngl.Framebuffer:
        fbo = self._fbos.get(targets)
        if fbo is None:
            fbo = self.own(self.ctx.framebuffer(color_attachments=[self.pool[i]
                                                                    for i in targets]))
            self._fbos[targets] = fbo
        return fbo

    def _set_spheres(self, program: Program) -> None:
        values = sphere_uniforms(self.constraints, self.t, self.dt)
        if values and not self.spec.velocity:
            del values["u_sphere_velocity"]
        if values:
            program.set(**values)

    def _set_time(self, program: Program, t: float) -> None:
        """Loads and drag targets at the stage time t."""
        if self.loads:
            program.set(u_load=uniform_array([tuple(float(c) for c in np.asarray(load.force(t), float))
                                       for load in self.loads]))
        if self.drags:
            program.set(u_drag_target=uniform_array([tuple(float(c) for c in
                                                    np.asarray(d.target(t), float))
                                              for d in self.drags]))

    def _bind_static(self) -> None:
        """The static textures on their units (the stages' own state is bound per pass)."""
        self.tex_node.use(_SAMPLERS["u_node"])
        if self.tex_neighbours is not None:
            self.tex_neighbours.use(_SAMPLERS["u_neighbours"])
        if self.tex_weights is not None:
            self.tex_weights.use(_SAMPLERS["u_weights"])
        if self.tex_hood_diagonals is not None:
            self.tex_hood_diagonals.use(_HOOD_DIAGONAL_UNIT)
        for tex, unit in zip(self.term_textures, self._term_units):
            tex.use(unit)

    def _run(self, stage: Stage, t: float) -> None:
        """One pass: ``stage.reads`` sampled, ``stage.writes`` rendered (current roles); the
        terms' own passes first, on the stage's evaluation positions."""
        program = self.passes[stage.name]
        r, index = self.roles, self._index
        if self.term_passes:
            where = next((b for b in stage.reads if BUFFERS[b] == ("stage", "x")), "x")
            for term_pass in self.term_passes:
                term_pass.run(self.pool[r[index[where]]])
            self._bind_static()
        self._set_time(program, t)
        if stage.final:
            self._set_spheres(program)
        for buffer in stage.reads:
            self.pool[r[index[buffer]]].use(_SAMPLERS[_sampler(buffer)])
        self._fbo(tuple(r[index[b]] for b in stage.writes)).use()
        self._vaos[stage.name].render(moderngl.TRIANGLES, vertices=3)

    def step(self, n: int = 1) -> None:
        """``n`` steps of dt on the GPU; nothing is read back."""
        if self._released:
            raise RuntimeError("FragmentIntegrator: released")
        if self.fast is not None:
            self.fast.step(n)
            self.steps_done, self.t = self.fast.steps_done, self.fast.t
            return
        previous = self.ctx.fbo
        self._bind_static()
        try:
            for _ in range(n):
                for stage in self.spec.stages:
                    self._run(stage, stage.at(self.t, self.dt))
                self.roles = self.spec.rotate(self.roles)
                self._tick()
        finally:
            restore_framebuffer(self.ctx, previous)

    # -- read-back (explicit) ----------------------------------------------------------------

    def _read(self, index: int) -> np.ndarray:
        data = np.frombuffer(read_texture(self.pool[self.roles[index]]), dtype=np.float32)
        return data.reshape(-1, 4)[: self.count, :3].copy()

    def positions(self) -> np.ndarray:
        """(N, 3) float32 positions (one read-back)."""
        if self._released:
            raise RuntimeError("FragmentIntegrator: released")
        if self.fast is not None:
            return self.fast.positions()
        return self._read(self._index["x"])

    def position_slot(self) -> tuple[moderngl.Texture, int, int, int]:
        """Where the current positions are on the GPU: (texture, nodes per row, slots per node,
        slot); node n's position is texel ``(slots * (n % row) + slot, n / row)``."""
        if self.fast is not None:
            return self.fast.position_slot()
        return self.pool[self.roles[self._index["x"]]], self.layout.width, 1, 0

    def velocities(self) -> np.ndarray:
        """(N, 3) velocities (one read-back). Verlet: the backward difference (x - x_prev)/dt in
        float64 of the float32 positions, 0 at fixed nodes (as the reference)."""
        if self._released:
            raise RuntimeError("FragmentIntegrator: released")
        if self.fast is not None:
            return self.fast.velocities()
        if not self.spec.velocity:
            x = self._read(self._index["x"]).astype(np.float64)
            xp = self._read(self._index["x_prev"]).astype(np.float64)
            return np.where(self.system.fixed[:, None], 0.0, (x - xp) / self.dt)
        return self._read(self._index["v"])

    @property
    def bytes_per_node(self) -> float:
        """GPU bytes of all textures (state and static, padding texels included) per node."""
        if self.fast is not None:
            return self.fast.bytes_per_node
        return self.bytes_allocated / self.count

    @property
    def state_bytes_per_node(self) -> float:
        """Bytes of the state textures per texel: 16 x the vec4s of integrators.GPU_BUFFERS."""
        if self.fast is not None:
            return 16.0 * len(self.fast.textures.state)
        w, h = self.layout.size
        return self.state_bytes / (w * h)

    def release(self) -> None:
        """Release every GL object (idempotent)."""
        for fbo in self._fbos.values():
            if self.ctx.fbo is fbo:
                self.ctx.detect_framebuffer(0).use()
        GLOwner.release(self)
        self._fbos.clear()
        self.passes.clear()
