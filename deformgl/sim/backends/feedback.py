"""The transform-feedback backend of the five integrators (Movania & Feng 2012).

Every step stage is a vertex shader in ``shaders/feedback/`` drawn over ``POINTS``, one vertex per
node, its outputs captured with transform feedback into a buffer (the paper's section 4
pipeline; nothing is rasterised: the 1x1 framebuffer is only bound because Mesa skips every
draw, transform feedback included, without a complete one). It computes the same function as
the float64 reference :func:`deformgl.sim.integrators.step`, in float32.

GPU data (all 2D textures are read with ``texelFetch``, filter NEAREST):

* Static: ``nodes`` RGBA32I (NODE_ROW x rows): first entry and count of the node's neighbour
  list, fixed flag, load-group bits; the neighbour list (CSR, each spring once per end) in
  ``other`` R32I (the other node) and ``springs`` RGBA32F (rest length, stiffness, spring damping, 0), SPRING_ROW
  entries per row. A physics term's feedback form (``Term.feedback_pairs``) joins the lists as
  entries of rest length 0 and signed stiffness c_ij: the same shader, no define.
* Physics terms with a transform-feedback chunk (``Term.feedback``,
  :class:`~deformgl.sim.terms.base.FeedbackTerm`; define ``FEEDBACK_TERMS``): each term's integer
  table, its slots per node at ``node_slot_texel`` (units 5, 6, ...), and its chunk, composed into
  ``terms/feedback.glsl`` (:func:`~deformgl.sim.terms.glsl.compose_feedback`), which every stage
  calls after the springs.
* State: a pass writes K vec4 per node, interleaved in varying order (``Program`` captures
  interleaved). The buffer is then copied GPU to GPU into an RGBA32F texture of K * NODE_ROW x
  rows texels (``Texture.write(buffer)``: a pixel-unpack-buffer upload, no CPU round trip), in
  which slot s of node n is texel ``(K * (n % NODE_ROW) + s, n / NODE_ROW)``, so the next pass
  can fetch any neighbour's state.

Why 2D textures and not ``samplerBuffer``: moderngl 5.13 has no buffer textures (no
``GL_TEXTURE_BUFFER`` target), so after each pass the output buffer is copied into a 2D texture
with ``Texture.write(buffer)`` (the buffer bound as ``GL_PIXEL_UNPACK_BUFFER``: the copy stays in
the GL, nothing crosses to Python). This works on Mesa llvmpipe; it costs one copy of the pass's
output per pass.

State per integrator (``bytes_per_node`` counts what is allocated, static data included):

* euler, semi-implicit: state texture (x, v) + output buffer (x', v').
* midpoint: state (x, v), stage texture (x_m, v_m), output buffer (2 vec4).
* rk4: state (x, v), stage texture (x_s, v_s, sum_x, sum_v), output buffer (4 vec4).
* verlet: two position textures (x, x_prev, roles swapped each step) + output buffer (x').

The passes (one per stage of :func:`deformgl.sim.stages.spec`: its vertex shader, defines and
stage time) and the layout come from the stage table; the layout is checked to implement the
spec's buffer rotation.

Positions carry the node mass in w. The loop never reads anything back to the CPU; only
:meth:`FeedbackSimulation.positions` and :meth:`FeedbackSimulation.velocities` do.
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

from deformgl.gl.es_context import read_texture
from deformgl.sim.terms.glsl import FEEDBACK, compose_feedback, feedback_terms
from deformgl.sim.backends.uniforms import sphere_uniforms, uniform_array
from deformgl.sim.clock import SimulationBase

from deformgl.errors import GLError
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS, Constraints, State, initial_state
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner, restore_framebuffer
from deformgl.sim.springs import SpringSystem
from deformgl.sim.scripted import Drag, Load, load_groups
from deformgl.sim.stages import BUFFERS, IntegratorSpec, Stage, spec

__all__ = ["FeedbackSimulation", "NODE_ROW_MAX", "SPRING_ROW_MAX"]

#: Nodes per texture row at most (a 4-slot state texture is then 4096 texels wide).
NODE_ROW_MAX = 1024
#: Neighbour-list entries per texture row at most.
SPRING_ROW_MAX = 4096
_VEC4 = 16
#: The texture unit of the first term table (0-2 the lists, 3-4 the state).
_TERM_UNIT = 5


def _row(count: int, limit: int) -> int:
    """Texels per row: the smallest power of two >= count, at most ``limit``."""
    width = 1
    while width < count and width < limit:
        width *= 2
    return width


def _bytes(obj: moderngl.Buffer | moderngl.Texture) -> int:
    """Bytes of GPU memory a buffer or a (32-bit per channel) texture holds."""
    if isinstance(obj, moderngl.Buffer):
        return int(obj.size)
    return int(obj.width * obj.height * obj.components * 4)


def _varying(buffer: str) -> str:
    """The captured output a buffer is written to (``stages.BUFFERS``: kind, quantity)."""
    kind, quantity = BUFFERS[buffer]
    return f"out_sum_{quantity}" if kind == "sum" else f"out_{quantity}"


def _check_layout(sp: IntegratorSpec) -> None:
    """The buffer rotation this backend implements, checked against the spec's.

    With velocity as state, the final stage writes the next (x, v) and the step copies it over
    the state texture; the other stages write the stage texture. Without (Verlet), x' overwrites
    x_prev's texture and the two position textures swap roles: x <- x', x_prev <- x.
    """
    out = sp.final.writes
    if not sp.velocity and len(sp.stages) != 1:
        raise ValueError(f"FeedbackSimulation: {sp.name}: without velocity one stage only")
    if sp.velocity:
        expected = {"x": out[0], "v": out[1]}
    else:
        expected = {"x": out[0], "x_prev": "x"}
    if any(sp.before(role) != old for role, old in expected.items()):
        raise ValueError(f"FeedbackSimulation: {sp.name}'s buffer rotation {sp.rotation} is not "
                         f"one this backend implements")


def _reads_stage(stage: Stage) -> bool:
    """Whether a stage samples the stage texture (stage states or RK4's running sums)."""
    return stage.eval_stage or stage.read_sums


@dataclass
class _Pass:
    """One stage: its program and attribute-less vertex array (one vertex per node)."""

    program: Program
    vao: moderngl.VertexArray
    slots: int  # vec4 outputs per node


class FeedbackSimulation(SimulationBase, GLOwner):
    """A :class:`SpringSystem` stepped on the GPU by vertex shaders and transform feedback.

    Args:
        ctx: the GL context.
        system: the spring system (a term without a transform-feedback form: ValueError).
        integrator: one of :data:`deformgl.sim.integrators.EXPLICIT_INTEGRATORS`.
        dt: step in s, > 0.
        constraints: ground plane and (static or moving) spheres, or None.
        drags: scripted drags (targets evaluated on the CPU at each stage's time, as uniforms).
        loads: scripted per-node forces (at most ``scripted.MAX_LOADS``; forces evaluated on the
            CPU at each stage's time, as uniforms; group bits per node in ``nodes.w``).
        state: start state (default :func:`deformgl.sim.integrators.initial_state` at rest); Verlet
            uses its ``x_prev``.
        t0: time of the start state.
    """

    backend = "feedback"

    def __init__(self, ctx: moderngl.Context, system: SpringSystem, integrator: str, dt: float,
                 *, constraints: Constraints | None = None, drags: tuple[Drag, ...] = (),
                 loads: tuple[Load, ...] = (), state: State | None = None,
                 t0: float = 0.0) -> None:
        if integrator not in EXPLICIT_INTEGRATORS:
            raise ValueError(f"unknown integrator {integrator!r}; expected one of "
                             f"{', '.join(EXPLICIT_INTEGRATORS)}")
        #: the integrator's stages, buffers and role rotation (``deformgl.sim.stages``)
        self.spec = spec(integrator)
        _check_layout(self.spec)
        if not dt > 0:
            raise ValueError(f"FeedbackSimulation: dt must be > 0, got {dt}")
        #: the chunks of the terms that have one (``Term.feedback``), compiled into every stage
        self.feedback_terms = feedback_terms(system.terms, system.grid, "FeedbackSimulation")
        self.ctx = ctx
        self.system = system
        self.integrator = integrator
        self._start_clock(dt, t0)
        self.constraints = constraints
        self.drags = tuple(drags)
        self.loads = tuple(loads)
        self.count = system.count
        if self.count == 0:
            raise ValueError("FeedbackSimulation: the system has no nodes")
        self.load_bits = load_groups(self.loads, self.count)
        for drag in self.drags:
            if not 0 <= drag.node < self.count:
                raise ValueError(f"FeedbackSimulation: drag node {drag.node} outside the system")
        GLOwner.__init__(self, ctx)
        self._passes: dict[str, _Pass] = {}
        with self.building():
            self._build(state)

    # -- construction ------------------------------------------------------------------------


    def _texture(self, width: int, height: int, dtype: str, data: bytes | None = None,
                 components: int = 4) -> moderngl.Texture:
        tex = self.own(self.ctx.texture((width, height), components, data, dtype=dtype))
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        tex.repeat_x = tex.repeat_y = False
        return tex

    def _build(self, state: State | None) -> None:
        system, n = self.system, self.count
        limit = int(self.ctx.info["GL_MAX_TEXTURE_SIZE"])
        self.node_row = _row(n, min(NODE_ROW_MAX, *(f.row_limit(limit) for f in self.feedback_terms), limit))
        self.rows = -(-n // self.node_row)
        texels = self.node_row * self.rows

        # CSR neighbour lists: every spring once in the list of each of its ends; a physics term's
        # feedback form f_i = -sum_j c_ij (x_i - x_j) (Term.feedback_pairs) as
        # entries of rest length 0 and stiffness c_ij (signed), whose spring force k (0 - |d|) d / |d|
        # is exactly -c_ij d.
        ends = np.concatenate([system.i, system.j])
        other = np.concatenate([system.j, system.i])
        rest = np.tile(system.rest_length, 2)
        stiffness = np.tile(system.stiffness, 2)
        damping = np.tile(system.damping, 2)
        for term in system.terms:
            pairs = term.feedback_pairs()
            if pairs is None:
                continue  # (a chunk of its own: self.feedback_terms)
            rows, cols, coefficients = pairs
            ends = np.concatenate([ends, rows])
            other = np.concatenate([other, cols])
            rest = np.concatenate([rest, np.zeros(len(rows))])
            stiffness = np.concatenate([stiffness, coefficients])
            damping = np.concatenate([damping, np.zeros(len(rows))])
        order = np.argsort(ends, kind="stable")
        counts = np.bincount(ends, minlength=n)
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        params = np.zeros((len(ends), 4), np.float32)
        params[:, 0] = rest[order]
        params[:, 1] = stiffness[order]
        params[:, 2] = damping[order]
        entries = max(len(ends), 1)
        self.spring_row = _row(entries, min(SPRING_ROW_MAX, limit))
        spring_rows = -(-entries // self.spring_row)
        if self.rows > limit or spring_rows > limit:
            raise GLError(f"FeedbackSimulation: {n} nodes and {entries} spring-list entries need {self.rows} "
                          f"rows of {self.node_row} and {spring_rows} rows of {self.spring_row} texels, more than "
                          f"the GL texture limit {limit}; use a coarser grid")
        spring_texels = self.spring_row * spring_rows
        nodes = np.zeros((texels, 4), np.int32)
        nodes[:n, 0] = first
        nodes[:n, 1] = counts
        nodes[:n, 2] = system.fixed
        nodes[:n, 3] = self.load_bits
        other_img = np.zeros(spring_texels, np.int32)
        other_img[:len(ends)] = other[order]
        param_img = np.zeros((spring_texels, 4), np.float32)
        param_img[:len(ends)] = params
        self.tex_nodes = self._texture(self.node_row, self.rows, "i4", nodes.tobytes())
        self.tex_other = self._texture(self.spring_row, spring_rows, "i4", other_img.tobytes(),
                                       components=1)
        self.tex_springs = self._texture(self.spring_row, spring_rows, "f4", param_img.tobytes())
        #: the terms' tables, bound on units 5, 6, ... in the order of ``feedback_terms``
        self.term_textures = [self._texture(f.slots * self.node_row, self.rows, "i4",
                                            f.image(self.node_row, self.rows).tobytes())
                              for f in self.feedback_terms]

        # Start state (float64 on the CPU, uploaded once as float32).
        s = (initial_state(system, self.dt, t=self.t, drags=self.drags, loads=self.loads)
             if state is None else state)
        x = np.asarray(s.x, np.float64)
        v = np.where(system.fixed[:, None], 0.0, np.asarray(s.v, np.float64))
        if x.shape != (n, 3) or v.shape != (n, 3):
            raise ValueError(f"FeedbackSimulation: state of shape {x.shape}, expected ({n}, 3)")

        def positions_image(p: np.ndarray) -> np.ndarray:
            img = np.zeros((texels, 4), np.float32)
            img[:n, :3] = p
            img[:n, 3] = system.mass
            return img

        def velocity_image(w: np.ndarray) -> np.ndarray:
            img = np.zeros((texels, 4), np.float32)
            img[:n, :3] = w
            return img

        def interleave(*images: np.ndarray) -> bytes:
            # slot s of node m at texel K * (m % NODE_ROW) + s of row m // NODE_ROW
            return np.stack(images, axis=1).tobytes()

        sp = self.spec
        # vec4 slots per node of the stage texture: what the non-final stages write
        stage_slots = max((len(st.writes) for st in sp.stages if not st.final), default=0)
        if not sp.velocity:
            self.tex_x = [self._texture(self.node_row, self.rows, "f4",
                                        positions_image(x).tobytes()),
                          self._texture(self.node_row, self.rows, "f4",
                                        positions_image(np.asarray(s.x_prev)).tobytes())]
            self._current = 0
        else:
            self.tex_state = self._texture(2 * self.node_row, self.rows, "f4",
                                           interleave(positions_image(x), velocity_image(v)))
            self.tex_stage = (self._texture(stage_slots * self.node_row, self.rows, "f4")
                              if stage_slots else None)
        out_slots = max(len(st.writes) for st in sp.stages)
        self.buffer = self.own(self.ctx.buffer(reserve=out_slots * texels * _VEC4))
        # Mesa skips draws without a complete framebuffer; a renderbuffer of our own, since
        # releasing a simple_framebuffer would leave its renderbuffers behind
        self.colour = self.own(self.ctx.renderbuffer((1, 1)))
        self.fbo = self.own(self.ctx.framebuffer(color_attachments=[self.colour]))

        # Programs: compile only what the system uses.
        common: dict[str, object] = {"NODE_ROW": self.node_row, "SPRING_ROW": self.spring_row,
                                     "DRAGS": len(self.drags), "LOADS": len(self.loads)}
        if system.wind_drag > 0:
            common["WIND"] = True
        if np.any(system.damping > 0):
            common["SPRING_DAMPING"] = True
        c = self.constraints
        if c is not None and (c.ground is not None or c.spheres):
            common["CONSTRAINTS"] = True
            common["GROUND"] = c.ground is not None
            common["SPHERES"] = len(c.spheres)
        else:
            common["SPHERES"] = 0
        if sp.velocity:
            common["VELOCITY"] = True
        if self.feedback_terms:
            common["FEEDBACK_TERMS"] = True
            for f in self.feedback_terms:
                common[f"TERM_{f.prefix.upper()}"] = True
                common.update(f.defines)
        for stage in sp.stages:
            self._add_pass(stage, {**common, **stage.feedback_defines()})

        state_objects: list[moderngl.Buffer | moderngl.Texture] = [self.buffer]
        if not sp.velocity:  # (tex_stage is set only with velocity as state)
            state_objects += self.tex_x
        else:
            state_objects += [self.tex_state, *([self.tex_stage] if self.tex_stage else [])]
        self.state_bytes = int(sum(_bytes(o) for o in state_objects))
        self.bytes_allocated = int(sum(_bytes(o) for o in self._owned
                                       if isinstance(o, (moderngl.Buffer, moderngl.Texture))))

    def _add_pass(self, stage: Stage, defines: dict[str, object]) -> None:
        varyings = tuple(_varying(b) for b in stage.writes)
        chunks = ({FEEDBACK: compose_feedback(self.feedback_terms),
                   **{f.file: f.source for f in self.feedback_terms if f.source is not None}}
                  if self.feedback_terms else None)
        program = Program(self.ctx, stage.vertex, defines=defines, varyings=varyings, chunks=chunks)
        self.own(program)
        vao = self.own(self.ctx.vertex_array(program.gl, []))
        self._passes[stage.name] = _Pass(program, vao, len(varyings))
        system = self.system
        uniforms: dict[str, object] = {
            "u_nodes": 0, "u_other": 1, "u_springs": 2, "u_dt": self.dt,
            "u_gravity": tuple(float(g) for g in system.gravity),
            "u_velocity_damping": system.velocity_damping,
            "u_mass_damping": system.mass_damping}
        if "WIND" in defines:
            uniforms.update(u_wind=tuple(float(w) for w in system.wind),
                            u_wind_drag=system.wind_drag)
        for unit, f in enumerate(self.feedback_terms, start=_TERM_UNIT):
            uniforms.update(f.uniforms)
            uniforms[f.sampler] = unit
        if not self.spec.velocity:
            uniforms.update(u_x=3, u_x_prev=4)
        else:
            uniforms["u_state"] = 3
            if _reads_stage(stage):
                uniforms["u_stage"] = 4
        if self.drags:
            uniforms["u_drag_node"] = uniform_array([d.node for d in self.drags])
            uniforms["u_drag_k"] = uniform_array([float(d.stiffness) for d in self.drags])
        c = self.constraints
        if "CONSTRAINTS" in defines and stage.final and c is not None:
            if c.ground is not None:
                uniforms["u_ground"] = float(c.ground)
        program.set(**uniforms)

    # -- stepping ----------------------------------------------------------------------------

    def _set_time(self, p: _Pass, t: float, *, constrain: bool = False) -> None:
        """Uniforms that depend on time: loads and drag targets at the stage time t, sphere
        centres."""
        if self.loads:
            forces = [tuple(float(c) for c in np.asarray(load.force(t), float))
                      for load in self.loads]
            p.program.set(u_load=uniform_array(forces))
        if self.drags:
            targets = [tuple(float(c) for c in np.asarray(d.target(t), float)) for d in self.drags]
            p.program.set(u_drag_target=uniform_array(targets))
        values = sphere_uniforms(self.constraints, self.t, self.dt) if constrain else {}
        if values and not self.spec.velocity:
            del values["u_sphere_velocity"]
        if values:
            p.program.set(**values)

    def _run(self, stage: Stage, t: float, into: moderngl.Texture) -> None:
        p = self._passes[stage.name]
        self._set_time(p, t, constrain=stage.final)
        p.vao.transform(self.buffer, moderngl.POINTS, vertices=self.count)
        into.write(self.buffer)  # GPU to GPU (pixel-unpack buffer), no read-back

    def _stage_texture(self) -> moderngl.Texture:
        """The stage texture (midpoint and RK4 have one)."""
        if self.tex_stage is None:
            raise RuntimeError(f"FeedbackSimulation: {self.integrator} has no stage texture")
        return self.tex_stage

    def step(self, n: int = 1) -> None:
        """``n`` steps of dt; nothing is read back."""
        if self._released:
            raise RuntimeError("FeedbackSimulation: released")
        previous = self.ctx.fbo
        self.fbo.use()  # Mesa skips draws, transform feedback included, without a framebuffer
        self.tex_nodes.use(0)
        self.tex_other.use(1)
        self.tex_springs.use(2)
        for unit, tex in enumerate(self.term_textures, start=_TERM_UNIT):
            tex.use(unit)
        dt, sp = self.dt, self.spec
        try:
            for _ in range(n):
                t = self.t
                if not sp.velocity:
                    cur, prev = self.tex_x[self._current], self.tex_x[1 - self._current]
                    cur.use(3)
                    prev.use(4)
                    for stage in sp.stages:  # (one: x' overwrites x_prev; roles swap)
                        self._run(stage, stage.at(t, dt), prev)
                    self._current = 1 - self._current
                else:
                    self.tex_state.use(3)
                    bound = False  # the stage texture on unit 4 once a stage reads it
                    for stage in sp.stages:
                        if _reads_stage(stage) and not bound:
                            self._stage_texture().use(4)
                            bound = True
                        into = self.tex_state if stage.final else self._stage_texture()
                        self._run(stage, stage.at(t, dt), into)
                self._tick()
        finally:
            # give the caller its framebuffer back; code elsewhere may have left the context
            # pointing at a framebuffer it has since released: then bind framebuffer 0
            restore_framebuffer(self.ctx, previous)

    # -- read-back (explicit) ----------------------------------------------------------------

    def _read(self, tex: moderngl.Texture, slots: int) -> np.ndarray:
        data = np.frombuffer(read_texture(tex), dtype=np.float32)
        return data.reshape(self.rows * self.node_row, slots, 4)[:self.count]

    def positions(self) -> np.ndarray:
        """(N, 3) float32 positions (one read-back)."""
        if not self.spec.velocity:
            return self._read(self.tex_x[self._current], 1)[:, 0, :3].copy()
        return self._read(self.tex_state, 2)[:, 0, :3].copy()

    def position_slot(self) -> tuple[moderngl.Texture, int, int, int]:
        """Where the current positions are on the GPU: (texture, nodes per row, slots per node,
        slot); node n's position is texel ``(slots * (n % row) + slot, n / row)``."""
        if not self.spec.velocity:
            return self.tex_x[self._current], self.node_row, 1, 0
        return self.tex_state, self.node_row, 2, 0

    def velocities(self) -> np.ndarray:
        """(N, 3) velocities (one read-back). Verlet: the backward difference (x - x_prev)/dt in
        float64 of the float32 positions, 0 at fixed nodes (as the reference)."""
        if not self.spec.velocity:
            x = self._read(self.tex_x[self._current], 1)[:, 0, :3].astype(np.float64)
            xp = self._read(self.tex_x[1 - self._current], 1)[:, 0, :3].astype(np.float64)
            return np.where(self.system.fixed[:, None], 0.0, (x - xp) / self.dt)
        return self._read(self.tex_state, 2)[:, 1, :3].copy()

    @property
    def bytes_per_node(self) -> float:
        """GPU bytes allocated by this simulation per node (state, buffers, static data; the
        texture padding of the last row included)."""
        return self.bytes_allocated / self.count

    @property
    def state_bytes_per_node(self) -> float:
        """Bytes of the state textures and the output buffer per node slot (texel of a row),
        static neighbour data excluded: 16 x the vec4s of integrators.GPU_BUFFERS."""
        return self.state_bytes / (self.rows * self.node_row)

    def release(self) -> None:
        """Release every GL object (idempotent)."""
        fbo = getattr(self, "fbo", None)
        if fbo is not None and self.ctx.fbo is fbo:
            # do not leave the context pointing at a released framebuffer: bind framebuffer 0,
            # the state of a fresh context
            self.ctx.detect_framebuffer(0).use()
        GLOwner.release(self)
        self._passes.clear()
