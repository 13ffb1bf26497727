"""XPBD on the fragment backend (Macklin, Müller & Chentanez 2016): the float32 GPU form of
:mod:`deformgl.sim.xpbd`, on the node grid of the fragment integrators (one texel per node,
Mosegaard & Sørensen 2005, section 3.1; ``grid.CompactLayout``).

Per substep three kinds of fragment pass (shaders/sim/xpbd/):

* ``predict.frag``: x~ from (x, v), into the iterate texture;
* ``iterate.frag`` x ``iterations``: one Jacobi sweep; each node gathers the corrections of its
  18 (+6 flexion) neighbour constraints and writes the new iterate and its spring multipliers
  (multiple render targets: the iterate, then ``NB_LAYERS`` lambda textures, then the drag
  lambda); iterate and multipliers are ping-ponged;
* ``finish.frag``: v = (x - x^n)/h and x into the state textures (ping-pong pair).

Each physics term of the system brings its XPBD passes (``Term.xpbd`` then
:meth:`~deformgl.sim.terms.constraints.TermConstraints.gpu`: :class:`~deformgl.sim.terms.constraints.XpbdPasses`,
e.g. the cells' per-cell pass, :class:`deformgl.sim.terms.volume.cell_xpbd.XpbdCells`), drawn before each sweep, and
its chunk in ``iterate.frag`` (``XPBD_TERMS``: ``terms/xpbd.glsl`` composed of the terms' chunks),
whose nodes gather the terms' corrections and write their active constraint count into the w of
the iterate.

Textures (``width x rows`` of the compact layout, NEAREST, ``texelFetch``; docs/ARCHITECTURE.md):
node RGBA32F (R inverse mass, 0 fixed; G flags 1 exists, 2 fixed, bits 6-13 a term's node bits
(the cells': ``64 << q`` full incident cell q); B load-group bits; A the node's constraint count
n_i: springs, drags, the terms' static counts), neighbours RGBA32I array of ``NB_LAYERS`` layers (absent: the node
itself), stiffness RGBA32F array (k_s of the spring to neighbour 4l + c in channel c of layer l,
0 where there is none: the per-spring weights of the calibrated lattice times the class's k),
state x, v, x', v' RGBA32F, two iterates (w: the terms' active constraints at the node), 2 x
``NB_LAYERS`` lambda RGBA32F (channel c of lambda texture l: the multiplier of neighbour 4l + c),
2 drag-lambda RGBA32F (xyz) with drags.
"""

from __future__ import annotations

import moderngl
import numpy as np

from deformgl.errors import GLError
from deformgl.gl.es_context import read_texture
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner, restore_framebuffer
from deformgl.grid.nodes import NodeGrid, layout_uniforms
from deformgl.sim.backends.grid_springs import compact_layout, grid_springs, spring_weights
from deformgl.sim.backends.uniforms import uniform_array
from deformgl.sim.clock import SimulationBase
from deformgl.sim.backends.compact_textures import compact_image, float_texture, layer_texture
from deformgl.sim.integrators import Constraints, Drag, Load, State
from deformgl.sim.springs import FLEXION, SHEAR, STRUCTURAL, SpringSystem
from deformgl.sim.scripted import load_groups
from deformgl.sim.terms.glsl import TERM_SHIFT, XPBD, check_inline, compose_xpbd
from deformgl.sim.terms.constraints import TermConstraints, XpbdPasses
from deformgl.sim.xpbd import (
    DEFAULT_ITERATIONS,
    DEFAULT_SUBSTEPS,
    NAME,
    OMEGA,
    XpbdSettings,
    _check_drags,
    constraint_counts,
    node_terms,
    relative_residual,
    term_constraints,
)

__all__ = ["XpbdFragment", "column_stiffness"]

_VEC4 = 16
_SAMPLERS = {"u_node": 0, "u_neighbours": 1, "u_stiffness": 2, "u_x": 3, "u_v": 4, "u_p": 5,
             "u_lambda_drag": 6, **{f"u_lambda{layer}": 7 + layer for layer in range(6)}}
#: The texture unit of the terms' first sampler (after the node sweep's own).
_TERM_UNIT = 13


def column_stiffness(system: SpringSystem, nb: np.ndarray, classes: list[tuple[float, float, float]]) -> np.ndarray:
    """(N, columns) float64 k_s of the spring to each neighbour column (0 where none)."""
    class_k = [c[0] for c in classes]
    col_class = np.array([STRUCTURAL] * 6 + [SHEAR] * 12 + [FLEXION] * (nb.shape[1] - 18))
    weights = spring_weights(system, nb, class_k)
    if weights is None:
        weights = (nb >= 0).astype(np.float64)
    return weights * np.asarray(class_k, np.float64)[col_class][None, :]


class XpbdFragment(SimulationBase, GLOwner):
    """A grid :class:`SpringSystem` stepped by XPBD in fragment passes.

    Args:
        ctx: the GL context.
        system: a grid system (:func:`springs.from_grid`, :func:`springs.cloth`,
            :func:`materials.lattice_system`).
        grid: its node grid (default ``system.grid``).
        dt: step in s, > 0.
        constraints, drags, loads, state, t0: as :class:`~deformgl.sim.backends.explicit_gpu.FragmentIntegrator`.
        iterations, substeps, omega: :class:`~deformgl.sim.xpbd.XpbdSettings`.

    Raises:
        ValueError: bad settings, dt <= 0, a system that is not the grid's, two drags on a node.
        GLError: the grid does not fit in a texture, or more render targets than the context has.
    """

    backend = "fragment"
    integrator = NAME

    def __init__(self, ctx: moderngl.Context, system: SpringSystem, grid: NodeGrid | None, dt: float, *,
                 constraints: Constraints | None = None, drags: tuple[Drag, ...] = (),
                 loads: tuple[Load, ...] = (), state: State | None = None, t0: float = 0.0,
                 iterations: int = DEFAULT_ITERATIONS, substeps: int = DEFAULT_SUBSTEPS,
                 omega: float = OMEGA) -> None:
        grid = system.grid if grid is None else grid
        if grid is None:
            raise ValueError("xpbd: the fragment backend needs a system on a node grid")
        if not dt > 0:
            raise ValueError(f"xpbd: dt must be > 0, got {dt}")
        self.settings = XpbdSettings(iterations, substeps, omega)
        #: the terms' float64 XPBD forms (their GPU passes: :attr:`term_passes`; the residual)
        self._term_forms = term_constraints(system, node_terms(system)[0])
        for form in self._term_forms:
            if type(form).gpu is TermConstraints.gpu:
                raise ValueError(f"xpbd: {form.name}: no XPBD form on the GPU")
        _check_drags(tuple(drags), system.count)
        self.ctx, self.system, self.grid = ctx, system, grid
        self._start_clock(dt, t0)
        self.constraints, self.drags, self.loads = constraints, tuple(drags), tuple(loads)
        self.count = grid.count
        self.load_bits = load_groups(self.loads, self.count)
        flexion, self.nb, self.classes = grid_springs(system, grid)
        self.layout = compact_layout(grid, int(ctx.info["GL_MAX_TEXTURE_SIZE"]))
        self.layers = -(-self.nb.shape[1] // 4)
        targets = 1 + self.layers + (1 if self.drags else 0)
        if targets > int(ctx.info.get("GL_MAX_DRAW_BUFFERS", 8)):
            raise GLError(f"xpbd: {targets} render targets needed, the context has "
                          f"{ctx.info.get('GL_MAX_DRAW_BUFFERS')}")
        GLOwner.__init__(self, ctx)
        self._fbos: dict[tuple[int, ...], moderngl.Framebuffer] = {}
        with self.building():
            self._build(state)

    # -- construction ------------------------------------------------------------------------

    def _texture(self, image: np.ndarray | None) -> moderngl.Texture:
        return float_texture(self, self.ctx, self.layout.size, image)

    def _image(self, values: np.ndarray) -> np.ndarray:
        return compact_image(self.layout.size, values)

    def _array_texture(self, table: np.ndarray, dtype: str) -> moderngl.TextureArray:
        return layer_texture(self, self.ctx, self.layout.size, table, dtype, self.layers)

    def _build(self, state: State | None) -> None:
        system, n, nb = self.system, self.count, self.nb
        w, h = self.layout.size
        own = np.arange(n)[:, None]
        self.tex_neighbours = self._array_texture(np.where(nb >= 0, nb, own).astype(np.int32), "i4")
        self.k_columns = column_stiffness(system, nb, self.classes)
        self.tex_stiffness = self._array_texture(self.k_columns.astype(np.float32), "f4")
        inv_mass, _ = node_terms(system)
        counts = constraint_counts(system, self.drags)
        #: each term's XPBD passes and multipliers (:class:`~deformgl.sim.terms.constraints.XpbdPasses`)
        self.term_passes: list[XpbdPasses] = []
        unit = _TERM_UNIT
        for form in self._term_forms:
            gpu = self.own(form.gpu(self.ctx, self.grid, self.layout, float(self.settings.omega), unit))
            check_inline(gpu.chunk.file, gpu.chunk.source, "xpbd")
            self.term_passes.append(gpu)
            unit += len(gpu.samplers)
        keep = [(f.name, b) for f, b in zip(self._term_forms, (t.node_bits() for t in self.term_passes)) if b is not None]
        if len(keep) > 1:
            raise ValueError(f"xpbd: {keep[0][0]} and {keep[1][0]} both keep node bits; the node data has room for "
                             f"one term's")
        bits = [b for _, b in keep]
        flags = 1.0 + 2.0 * system.fixed + (np.asarray(bits[0], np.float64) * float(1 << TERM_SHIFT) if bits else 0.0)
        node = np.stack([inv_mass, flags, self.load_bits, counts], axis=1)
        self.tex_node = self._texture(self._image(node))
        x = np.array(system.rest_positions if state is None else state.x, np.float64)
        v = np.zeros_like(x) if state is None else np.asarray(state.v, np.float64)
        if x.shape != (n, 3) or v.shape != (n, 3):
            raise ValueError(f"xpbd: state of shape {x.shape}, expected ({n}, 3)")
        v = np.where(system.fixed[:, None], 0.0, v)
        # state ping-pong: [x, v] and [x', v']
        self.state_pairs = [(self._texture(self._image(x)), self._texture(self._image(v))),
                            (self._texture(None), self._texture(None))]
        self.current = 0
        self.iterates = [self._texture(None), self._texture(None)]
        self.lambdas = [[self._texture(None) for _ in range(self.layers)] for _ in range(2)]
        self.drag_lambdas = [self._texture(None), self._texture(None)] if self.drags else []

        sp = bool(np.any(system.damping > 0))
        common: dict[str, object] = {"LOADS": len(self.loads)}
        if system.wind_drag > 0:
            common["WIND"] = True
        c = self.constraints
        iterate: dict[str, object] = {"NB_LAYERS": self.layers, "NB_COUNT": nb.shape[1],
                                      "SPRING_DAMPING": sp, "DRAGS": len(self.drags), "SPHERES": 0}
        if c is not None and (c.ground is not None or c.spheres):
            iterate.update(CONSTRAINTS=True, GROUND=c.ground is not None, SPHERES=len(c.spheres))
        chunks = [t.chunk for t in self.term_passes]
        for chunk in chunks:
            iterate.update(chunk.sweep_defines())
        self.p_predict = self._program("sim/xpbd/predict.frag", common)
        sources = {XPBD: compose_xpbd(chunks), **{c.file: c.source for c in chunks if c.source is not None}}
        self.p_iterate = self._program("sim/xpbd/iterate.frag", iterate, sources if chunks else None)
        self.p_finish = self._program("sim/xpbd/finish.frag", {})
        h_sub = self.dt / self.settings.substeps
        passes = [self.p_predict, self.p_iterate, self.p_finish]
        for term in self.term_passes:
            passes += term.programs()
            self.p_iterate.set(**term.sweep_uniforms(self.p_iterate))
        for p in passes:
            shared = {**_SAMPLERS, "u_h": h_sub}  # (a term's pass sets only those it uses)
            p.set(**{k: v for k, v in shared.items() if k in p.members})
            if "u_width_log2" in p.members:
                p.set(**layout_uniforms(self.layout.width))
        self.p_predict.set(u_gravity=tuple(float(g) for g in system.gravity),
                           u_mass_damping=system.mass_damping, u_velocity_damping=system.velocity_damping)
        if system.wind_drag > 0:
            self.p_predict.set(u_wind=tuple(float(g) for g in system.wind), u_wind_drag=system.wind_drag)
        ratios = tuple(cl[2] / cl[0] if cl[0] > 0 else 0.0 for cl in self.classes)
        self.p_iterate.set(u_rest=tuple(cl[1] for cl in self.classes), u_omega=float(self.settings.omega))
        if sp:
            self.p_iterate.set(u_ratio=ratios)
        if self.drags:
            self.p_iterate.set(u_drag_node=uniform_array([d.node for d in self.drags]),
                               u_drag_k=uniform_array([float(d.stiffness) for d in self.drags]))
        if c is not None and c.ground is not None:
            self.p_iterate.set(u_ground=float(c.ground))
        self._vaos = {id(p): self.own(self.ctx.vertex_array(p.gl, []))
                      for p in (self.p_predict, self.p_iterate, self.p_finish)}
        tex_count = 4 + 2 + 2 * self.layers + len(self.drag_lambdas)
        self.bytes_allocated = (tex_count + 1 + 2 * self.layers) * w * h * _VEC4
        self.bytes_allocated += sum(t.bytes_allocated for t in self.term_passes)

    def _program(self, fragment: str, defines: dict[str, object], chunks: dict[str, str] | None = None) -> Program:
        return self.own(Program(self.ctx, "sim/fullscreen.vert", fragment, defines=defines, chunks=chunks))

    # -- stepping ----------------------------------------------------------------------------

    def _fbo(self, textures: list[moderngl.Texture]) -> moderngl.Framebuffer:
        key = tuple(id(t) for t in textures)
        fbo = self._fbos.get(key)
        if fbo is None:
            fbo = self.own(self.ctx.framebuffer(color_attachments=textures))
            self._fbos[key] = fbo
        return fbo

    def _draw(self, program: Program, targets: list[moderngl.Texture]) -> None:
        self._fbo(targets).use()
        self._vaos[id(program)].render(moderngl.TRIANGLES, vertices=3)

    def _substep(self, t: float, h: float) -> int:
        """One substep from the current state at time t; returns the iterate index holding the
        last iterate."""
        x, v = self.state_pairs[self.current]
        if self.loads:
            self.p_predict.set(u_load=uniform_array([tuple(float(c) for c in np.asarray(load.force(t), float))
                                              for load in self.loads]))
        x.use(_SAMPLERS["u_x"])
        v.use(_SAMPLERS["u_v"])
        self._draw(self.p_predict, [self.iterates[0]])
        clear = self.lambdas[0] + self.drag_lambdas[:1]
        self._fbo(clear).clear(0.0, 0.0, 0.0, 0.0)
        for term in self.term_passes:
            term.clear()
        if self.drags:
            self.p_iterate.set(u_drag_target=uniform_array([tuple(float(c) for c in np.asarray(d.target(t + h), float))
                                                     for d in self.drags]))
        c = self.constraints
        if c is not None and c.spheres:
            self.p_iterate.set(u_spheres=uniform_array([(*map(float, s.centre_at(t + h)), float(s.radius))
                                                 for s in c.spheres]))
        a = 0
        for _ in range(self.settings.iterations):
            b = 1 - a
            self.iterates[a].use(_SAMPLERS["u_p"])
            for term in self.term_passes:
                term.sweep(a, b)
            for layer, tex in enumerate(self.lambdas[a]):
                tex.use(_SAMPLERS[f"u_lambda{layer}"])
            if self.drags:
                self.drag_lambdas[a].use(_SAMPLERS["u_lambda_drag"])
            self._draw(self.p_iterate, [self.iterates[b]] + self.lambdas[b] + self.drag_lambdas[b:b + 1])
            a = b
        self.iterates[a].use(_SAMPLERS["u_p"])
        out = self.state_pairs[1 - self.current]
        self._draw(self.p_finish, [out[0], out[1]])
        self.current = 1 - self.current
        return a

    def step(self, n: int = 1) -> None:
        """``n`` steps of dt (``substeps`` substeps each) on the GPU; nothing is read back."""
        if self._released:
            raise RuntimeError("xpbd: released")
        previous = self.ctx.fbo
        self.tex_node.use(_SAMPLERS["u_node"])
        self.tex_neighbours.use(_SAMPLERS["u_neighbours"])
        self.tex_stiffness.use(_SAMPLERS["u_stiffness"])
        subs = self.settings.substeps
        h = self.dt / subs
        try:
            for _ in range(n):
                for q in range(subs):
                    self._last = self._substep(self.t + q * h, h)
                self._tick()
        finally:
            restore_framebuffer(self.ctx, previous)

    # -- read-back (explicit) ----------------------------------------------------------------

    def _read(self, tex: moderngl.Texture, channels: int = 3) -> np.ndarray:
        data = np.frombuffer(read_texture(tex), dtype=np.float32)
        return data.reshape(-1, 4)[: self.count, :channels].copy()

    def positions(self) -> np.ndarray:
        """(N, 3) float32 positions (one read-back)."""
        if self._released:
            raise RuntimeError("xpbd: released")
        return self._read(self.state_pairs[self.current][0])

    def velocities(self) -> np.ndarray:
        """(N, 3) float32 velocities (one read-back)."""
        if self._released:
            raise RuntimeError("xpbd: released")
        return self._read(self.state_pairs[self.current][1])

    def position_slot(self) -> tuple[moderngl.Texture, int, int, int]:
        """(texture, nodes per row, slots per node, slot) of the current positions."""
        return self.state_pairs[self.current][0], self.layout.width, 1, 0

    @property
    def position_texture(self) -> moderngl.Texture:
        """The texture holding the latest positions (xyz)."""
        return self.state_pairs[self.current][0]

    @property
    def packed_normals(self) -> bool:
        """No packed node normal in the position texture's w."""
        return False

    @property
    def residual(self) -> float:
        """Relative residual |C + at lambda| / |C| of Macklin, Müller & Chentanez 2016, eq. 7 at the last iterate of the last
        substep (read back: the iterate and the multipliers; nan before a step)."""
        if self.steps_done == 0 or self._released:
            return float("nan")
        p = self._read(self.iterates[self._last]).astype(np.float64)
        lam = np.concatenate([self._read(t, 4) for t in self.lambdas[self._last]], axis=1)
        lam = lam[:, : self.nb.shape[1]].astype(np.float64)
        rows, cols = np.nonzero(self.k_columns > 0)
        once = rows < self.nb[rows, cols]  # each spring once (both ends hold a copy), as the float64 solver counts it
        rows, cols = rows[once], cols[once]
        rest = np.array([cl[1] for cl in self.classes])[np.where(cols < 6, 0, np.where(cols < 18, 1, 2))]
        c = np.linalg.norm(p[rows] - p[self.nb[rows, cols]], axis=1) - rest
        h = self.dt / self.settings.substeps
        at_lam = 1.0 / (self.k_columns[rows, cols] * h * h) * lam[rows, cols]
        for form, term in zip(self._term_forms, self.term_passes):
            c_term, at_lam_term = form.residual_terms(p, term.read(self._last), h)
            c, at_lam = np.concatenate([c, c_term]), np.concatenate([at_lam, at_lam_term])
        return relative_residual(c, at_lam)

    @property
    def bytes_per_node(self) -> float:
        """GPU bytes of all textures per node."""
        return self.bytes_allocated / self.count

    def release(self) -> None:
        """Release every GL object (idempotent)."""
        self._fbos.clear()
        GLOwner.release(self)
