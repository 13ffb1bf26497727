"""Implicit (backward) Euler on the fragment backend: matrix-free preconditioned (Jacobi,
block-Jacobi or multigrid) conjugate gradients in fragment passes over the compact node texture,
the dot products summed on the GPU.

The same method as the float64 reference :mod:`deformgl.sim.implicit` (same iteration, same warm
start, same stopping test), in float32. A step is (``shaders/sim/implicit/implicit.frag``):

1. SETUP: ``b = dt (f - dt H v)`` and the preconditioner P^-1 at the step's start state (forces
   at ``t + dt``), and ``b . P^-1 b`` per texel: Jacobi ``1 / diag(A)``, or block-Jacobi (define
   PRECOND_BLOCK) the inverse of the node's 3x3 diagonal block of A, computed per node in the
   pass (GLSL ``inverse``);
2. the warm start (:data:`~deformgl.sim.implicit.WARM_STARTS`): "scaled" (default) WARM
   ``q = A dv_prev`` and the sums of ``dv_prev . q`` (R) and ``b . dv_prev`` (G), then INIT with
   WARM_SCALED: ``dv = s dv_prev``, ``s = (b . dv_prev) / (dv_prev . A dv_prev)``, ``r = b - s q``;
   "previous": INIT ``r = b - A dv_prev``; "zero": dv cleared, then INIT; and in each
   ``p = P^-1 r``, ``r . P^-1 r``;
3. per iteration: MATVEC ``q = A p`` (and ``p . q``), the sum of ``p . q``, UPDATE (dv, r and
   ``r . P^-1 r``), its sum, DIRECTION (``p = P^-1 r + beta p``);
4. FINAL: ``v' = v + dv``, ``x' = x + dt v'``, the constraints, fixed nodes.

The matrix-vector product of a node is computed from its 18 (+6 flexion) grid neighbours
(Mosegaard & Sørensen 2005, section 3.1: the neighbour-index texture of
:class:`~deformgl.sim.backends.explicit_gpu.FragmentIntegrator`, with the per-spring weight texture of
the calibrated lattice). The system's further physics terms (``system.terms``,
:mod:`deformgl.sim.terms`) add their K y and diagonal blocks in
:data:`~deformgl.sim.backends.implicit_passes.TERM_PASSES` (define TERMS; those that read the grid
neighbours in the same loop as the springs), their forces in SETUP; a term that reads the node's
3x3x3 neighbourhood gathers it through the 27-node table, and the flag the terms set in SETUP
travels in b's w. Every sum is a chain of 4x4 reduction passes down to a 1x1 texture
(``shaders/sim/implicit/reduce.frag``) that the next pass samples: with a fixed iteration count
(``cg_tolerance`` 0) nothing is read back while stepping; with a tolerance the CPU reads one
scalar (``r . r``) every ``cg_check_every`` iterations, and ``b . b`` once per step, and stops at
``|r| <= max(tol |b|, floor)`` (:func:`~deformgl.sim.implicit.residual_floor`), the NumPy
reference's test; after the iterations TRUE_RESIDUAL sums the true ``|b - A dv|^2`` (one more
product, one more read), which the step's report gives and judges; without one
:meth:`ImplicitFragment.residual` reads the last step's two scalars on request.

GPU textures (all ``width x rows`` texels of the compact layout, RGBA32F unless said, NEAREST):

* static: node data (R mass, G flags: 1 exists, 2 fixed, the terms' node bits 6-13, B load-group
  bits, A 0), neighbours RGBA32I array (5 or 6 layers), spring weights array (with
  SPRING_WEIGHTS), as the fragment backend's; with a term that reads the node's neighbourhood its
  27-node table, RGBA32I array of 7 layers (slot 4 l + c of
  :func:`~deformgl.grid.neighbours.neighbourhood`'s 27, the node itself where absent);
  the terms' node tables;
* state: x, v and x', v' (xyz; the pairs swap after a step);
* solver: b (xyz; w the terms' flag of SETUP, read by the products), P^-1 (xyz: Jacobi 1 / diag(A); block-Jacobi the diagonal of the block's
  inverse, and a second texture ``inv_off`` with its off-diagonal xy, xz, yz), dv (two,
  ping-pong; the latest is the next step's warm start), r (two), p (two), q (xyz), a per-texel
  product (after SETUP, INIT and UPDATE R the preconditioned, G the plain dot product; after
  MATVEC R; after WARM R and G), the reduction levels (RGBA, each channel
  summed; each ``ceil(w/4) x ceil(h/4)`` of the last, down to 1x1) and five 1x1 scalars (R:
  ``b.P^-1 b`` (G ``b.b``), ``p.q`` (after a step with a tolerance, G the true
  ``|b - A dv|^2``), ``r.P^-1 r`` twice (G ``r.r``): before and after an update;
  the warm start's R ``dv_prev . A dv_prev`` and G ``b . dv_prev``).
"""

from __future__ import annotations

import moderngl
import numpy as np

from deformgl.gl.es_context import read_texture
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner, restore_framebuffer
from deformgl.grid.nodes import NodeGrid, layout_uniforms
from deformgl.grid.neighbours import neighbourhood
from deformgl.sim.backends.grid_springs import compact_layout, grid_springs, spring_weights
from deformgl.sim.backends.uniforms import sphere_uniforms, uniform_array
from deformgl.sim.clock import SimulationBase
from deformgl.sim.backends.implicit_passes import (REDUCE_UNIT, TERM_PASSES, TERM_UNITS,
                                                   UNITS, pass_defines)
from deformgl.sim.backends.term_tables import TermTables
from deformgl.sim.terms.glsl import pass_terms
from deformgl.sim.backends.multigrid_gpu import GpuMultigrid
from deformgl.sim.implicit import (DEFAULT_PRECONDITIONER, DEFAULT_WARM_START, SolveReport, SolverStats, assemble,
                                   check_cg, check_preconditioner, check_warm_start, multigrid_levels, residual_floor,
                                   solver_note)
from deformgl.sim.multigrid import Hierarchy
from deformgl.sim.integrators import Constraints, State, initial_state
from deformgl.sim.springs import SpringSystem
from deformgl.sim.scripted import Drag, Load, load_groups
from deformgl.sim.backends.compact_textures import compact_image, float_texture, layer_texture

__all__ = ["ImplicitFragment"]

_UNITS, _REDUCE_UNIT = UNITS, REDUCE_UNIT


class ImplicitFragment(SimulationBase, GLOwner):
    """A grid :class:`SpringSystem` stepped by backward Euler on the GPU.

    Args:
        ctx, system, grid, dt, constraints, drags, loads, state, t0: as
            :class:`~deformgl.sim.backends.explicit_gpu.FragmentIntegrator`.
        cg_iterations: CG iterations per step (the most, with a tolerance).
        cg_tolerance: relative residual ``|r| / |b|`` to stop at, or ``|r|`` at most the absolute
            floor (:func:`~deformgl.sim.implicit.residual_floor`) (0: always ``cg_iterations``,
            no read-back).
        cg_check_every: iterations between residual read-backs (with a tolerance).
        cg_preconditioner: "jacobi" or "block-jacobi"
            (:data:`~deformgl.sim.implicit.PRECONDITIONERS`).
        cg_warm_start: "scaled", "previous" or "zero" (:data:`~deformgl.sim.implicit.WARM_STARTS`).

    Attributes:
        last_report: the last step's :class:`~deformgl.sim.implicit.SolveReport` (with a
            tolerance; without one the residual is read only by :meth:`residual`).
        unconverged, worst_residual: steps that missed the tolerance, and their worst residual.
    """

    backend = "fragment"
    integrator = "implicit-euler"
    packed_normals = False

    def __init__(self, ctx: moderngl.Context, system: SpringSystem, grid: NodeGrid | None, dt: float, *,
                 constraints: Constraints | None = None, drags: tuple[Drag, ...] = (),
                 loads: tuple[Load, ...] = (), state: State | None = None, t0: float = 0.0,
                 cg_iterations: int = 20, cg_tolerance: float = 0.0, cg_check_every: int = 4,
                 cg_preconditioner: str = DEFAULT_PRECONDITIONER, cg_warm_start: str = DEFAULT_WARM_START) -> None:
        grid = system.grid if grid is None else grid
        if grid is None:
            raise ValueError("ImplicitFragment: the system has no node grid (build it with springs.from_grid, "
                             "springs.cloth or materials.lattice_system)")
        if not dt > 0:
            raise ValueError(f"ImplicitFragment: dt must be > 0, got {dt}")
        check_cg(cg_iterations, cg_tolerance, cg_check_every)
        self.preconditioner = check_preconditioner(cg_preconditioner)
        self.multigrid = self.preconditioner == "multigrid"
        self.block = self.preconditioner in ("block-jacobi", "multigrid")  # (multigrid: the smoother's blocks)
        self.mg: GpuMultigrid | None = None
        self._z: moderngl.Texture | None = None  # (multigrid: the texture the last cycle left z in)
        self.warm_start = check_warm_start(cg_warm_start)
        self.ctx, self.system, self.grid = ctx, system, grid
        self._start_clock(dt, t0)
        self.constraints, self.drags, self.loads = constraints, tuple(drags), tuple(loads)
        self.count = grid.count
        for drag in self.drags:
            if not 0 <= drag.node < self.count:
                raise ValueError(f"ImplicitFragment: drag node {drag.node} outside the system")
        self.iterations, self.tolerance, self.check_every = int(cg_iterations), float(cg_tolerance), int(cg_check_every)
        self.flexion, self.neighbour_table, self.classes = grid_springs(system, grid)
        #: the system's physics terms as the passes compile them (deformgl.sim.terms)
        self.terms = pass_terms(system.terms, "implicit", "ImplicitFragment", grid, implicit=True)
        #: the product passes read b's w, the flag the terms set in SETUP (TERMS_HELD)
        self.held_flag = bool(self.terms.defines().get("TERMS_HELD"))
        self.term_tables: TermTables | None = None
        self.layout = compact_layout(grid, int(ctx.info["GL_MAX_TEXTURE_SIZE"]))
        self.last_report = SolveReport(0, 0.0, True)
        self.unconverged, self.worst_residual = 0, 0.0
        self.floor = 0.0  # (set in _build, from the start state)
        self.stats = SolverStats(self.preconditioner, self.tolerance)
        self.last_moved = float("inf")
        self._fbos: dict[tuple[int, ...], moderngl.Framebuffer] = {}
        GLOwner.__init__(self, ctx)
        with self.building():
            self._build(state)

    # -- construction ------------------------------------------------------------------------

    def _texture(self, size: tuple[int, int], image: np.ndarray | None = None) -> moderngl.Texture:
        return float_texture(self, self.ctx, size, image)

    def _image(self, values: np.ndarray) -> np.ndarray:
        return compact_image(self.layout.size, values)

    def _array_texture(self, values: np.ndarray, dtype: str) -> moderngl.TextureArray:
        return layer_texture(self, self.ctx, self.layout.size, values, dtype)

    def _build(self, state: State | None) -> None:
        system, n, size = self.system, self.count, self.layout.size
        nb = self.neighbour_table
        own = np.arange(n)[:, None]
        table = np.where(nb >= 0, nb, own).astype(np.int32)
        layers = -(-nb.shape[1] // 4)
        table = np.concatenate([table, np.repeat(own, 4 * layers - nb.shape[1], axis=1).astype(np.int32)], axis=1)
        self.tex_neighbours = self._array_texture(table, "i4")
        weights = spring_weights(system, nb, [c[0] for c in self.classes])
        self.tex_weights = None if weights is None else self._array_texture(weights.astype(np.float32), "f4")
        flags = (1 + 2 * system.fixed.astype(np.int64)) | self.terms.node_bits(n)
        node = np.stack([system.mass, flags, load_groups(self.loads, n), np.zeros(n)], axis=1)
        self.tex_node = self._texture(size, self._image(node))
        if self.terms:
            self.term_tables = self.own(TermTables(self.ctx, self.terms, self.grid, self.layout, TERM_UNITS))
        #: the 27-node neighbourhood table of the terms that read it (HOOD_NODES), or None
        self.tex_hood = self._array_texture(neighbourhood(self.grid), "i4") if self.terms.hood else None
        s = initial_state(system, self.dt, t=self.t, drags=self.drags, loads=self.loads) if state is None else state
        x = np.asarray(s.x, np.float64)
        v = np.where(system.fixed[:, None], 0.0, np.asarray(s.v, np.float64))
        if x.shape != (n, 3) or v.shape != (n, 3):
            raise ValueError(f"ImplicitFragment: state of shape {x.shape}, expected ({n}, 3)")
        self.floor = residual_floor(system, x, self.dt, drags=self.drags)
        self.stats.floor = self.floor
        zero = np.zeros((n, 3))
        names: tuple[str, ...] = ("x", "v", "x_out", "v_out", "b", "inv", "dv", "dv_out", "r", "r_out", "p",
                                  "p_out", "q", "prod") + (("inv_off",) if self.block else ()) + (
                                  ("mg_x", "mg_x_out", "mg_res") if self.multigrid else ())
        start = {"x": x, "v": v, "x_out": x, "v_out": v}
        self.tex = {name: self._texture(size, self._image(start.get(name, zero))) for name in names}
        # reduction levels: 4x4 blocks down to 1x1, then the scalars
        self.levels: list[tuple[moderngl.Texture, tuple[int, int]]] = []
        w, h = size
        while (w, h) != (1, 1):
            w, h = -(-w // 4), -(-h // 4)
            if (w, h) != (1, 1):
                self.levels.append((self._texture((w, h)), (w, h)))
        self.scalars = {name: self._texture((1, 1)) for name in ("bpb", "pq", "rz", "rz_new", "warm")}
        defines = pass_defines(system, flexion=self.flexion, weights=self.tex_weights is not None,
                               drags=len(self.drags), loads=len(self.loads), constraints=self.constraints,
                               block=self.block, scaled=self.warm_start == "scaled",
                               multigrid=self.multigrid,
                               term_defines=self.terms.defines())
        self.passes = {name: self._program(d) for name, d in defines.items()}
        self.reduce = self.own(Program(self.ctx, "sim/fullscreen.vert", "sim/implicit/reduce.frag"))
        self._vaos = {name: self.own(self.ctx.vertex_array(p.gl, [])) for name, p in self.passes.items()}
        self._reduce_vao = self.own(self.ctx.vertex_array(self.reduce.gl, []))
        self.reduce.set(u_src=_REDUCE_UNIT)
        texels = size[0] * size[1]
        self.bytes_allocated = 16 * (len(names) * texels + texels * layers * (1 + (weights is not None))
                                     + sum(a * b for _, (a, b) in self.levels) + len(self.scalars)
                                     + (0 if self.tex_hood is None else 7 * texels))
        if self.term_tables is not None:
            self.bytes_allocated += self.term_tables.bytes_allocated
        if self.multigrid:
            self.mg = self._build_multigrid(s)

    def _build_multigrid(self, start: State) -> GpuMultigrid:
        """The V-cycle's coarse levels from the start state's step matrix (float64, on the CPU)."""
        system = self.system
        lin = assemble(system, np.asarray(start.x, np.float64), np.where(system.fixed[:, None], 0.0, start.v),
                       self.t, self.dt, drags=self.drags, loads=self.loads)
        hierarchy = Hierarchy(lin.matrix, multigrid_levels(system).prolongations)
        mg = GpuMultigrid(self, self.ctx, hierarchy, ~system.fixed, self.layout.width,
                          int(self.ctx.info["GL_MAX_TEXTURE_SIZE"]), self._fbo)
        for name in ("MG_SMOOTH_ZERO", "MG_SMOOTH"):
            self.passes[name].set(u_omega=mg.omega)
        self.bytes_allocated += mg.bytes_allocated
        return mg

    def _program(self, defines: dict[str, object]) -> Program:
        program = self.own(Program(self.ctx, "sim/fullscreen.vert", "sim/implicit/implicit.frag", defines=defines,
                                   chunks=self.terms.chunks()))
        (k1, l1, c1), (k2, l2, c2), (k3, l3, c3) = self.classes
        system = self.system
        values: dict[str, object] = {
            **_UNITS, **layout_uniforms(self.layout.width), "u_dt": self.dt,
            "u_k": (k1, k2, k3), "u_rest": (l1, l2, l3), "u_c": (c1, c2, c3),
            "u_gravity": tuple(float(g) for g in system.gravity), "u_velocity_damping": system.velocity_damping,
            "u_mass_damping": system.mass_damping, "u_wind": tuple(float(g) for g in system.wind),
            "u_wind_drag": system.wind_drag}
        if self.term_tables is not None:
            values.update(self.term_tables.uniforms)
        if self.drags:
            values["u_drag_node"] = uniform_array([d.node for d in self.drags])
            values["u_drag_k"] = uniform_array([float(d.stiffness) for d in self.drags])
        c = self.constraints
        if c is not None and c.ground is not None:
            values["u_ground"] = float(c.ground)
        members = program.members
        program.set(**{k: v for k, v in values.items() if k in members})
        return program

    # -- stepping ----------------------------------------------------------------------------

    def _fbo(self, *targets: moderngl.Texture) -> moderngl.Framebuffer:
        key = tuple(t.glo for t in targets)
        fbo = self._fbos.get(key)
        if fbo is None:
            fbo = self.own(self.ctx.framebuffer(color_attachments=list(targets)))
            self._fbos[key] = fbo
        return fbo

    def _draw(self, name: str, reads: dict[str, str | moderngl.Texture], writes: tuple[str | moderngl.Texture, ...]) -> None:
        """Pass ``name`` reading ``reads`` (sampler: a texture, the name of one of ``self.tex``,
        or "$" and a scalar's name) into ``writes``."""
        if self.block and "u_inv" in reads:
            reads = {**reads, "u_inv_off": "inv_off"}
        if self.block and name == "SETUP":
            writes = (*writes, "inv_off")
        for sampler, tex in reads.items():
            if isinstance(tex, str):
                tex = self.scalars[tex[1:]] if tex.startswith("$") else self.tex[tex]
            tex.use(_UNITS[sampler])
        if self.tex_hood is not None and name in TERM_PASSES:
            self.tex_hood.use(_UNITS["u_hood_nodes"])
        if self.term_tables is not None and name in TERM_PASSES:
            self.term_tables.bind()
        self._fbo(*(self.tex[w] if isinstance(w, str) else w for w in writes)).use()
        self._vaos[name].render(moderngl.TRIANGLES, vertices=3)

    def _bind_static(self) -> None:
        """The textures every pass reads on fixed units (node data, neighbours, weights, x)."""
        self.tex_node.use(_UNITS["u_node"])
        self.tex_neighbours.use(_UNITS["u_neighbours"])
        if self.tex_weights is not None:
            self.tex_weights.use(_UNITS["u_weights"])
        self.tex["x"].use(_UNITS["u_x"])

    def _fine_pass(self, name: str, rhs: moderngl.Texture, x: moderngl.Texture | None,
                   out: moderngl.Texture) -> None:
        """A multigrid pass on the finest level (:data:`MG_PASSES`; the coarse levels' passes
        rebind the units in between)."""
        self._bind_static()
        reads: dict[str, str | moderngl.Texture] = {"u_mg_rhs": rhs}
        if x is not None:
            reads["u_vec"] = x
        if name != "MG_RESIDUAL":
            reads["u_inv"] = "inv"
        if self.held_flag:
            reads["u_b"] = "b"
        self._draw(name, reads, (out,))

    def _precondition(self, p: str | None) -> None:
        """z = M^-1 r by the V-cycle, and per texel r . z and r . r into ``prod`` (with ``p``:
        p = z too)."""
        assert self.mg is not None
        z = self.mg.cycle(self.tex["r"], self.tex["mg_x"], self.tex["mg_x_out"], self.tex["mg_res"],
                          self._fine_pass)
        self.mg.rz(self.tex["r"], z, self.tex["prod"], None if p is None else self.tex[p])
        self._z = z
        self._bind_static()

    def _sum(self, target: str) -> None:
        """Sum the product texture's R into the 1x1 scalar ``target``."""
        src, size = self.tex["prod"], self.layout.size
        for tex, level_size in self.levels + [(self.scalars[target], (1, 1))]:
            src.use(_REDUCE_UNIT)
            self.reduce.set(u_size=size)
            self._fbo(tex).use()
            self._reduce_vao.render(moderngl.TRIANGLES, vertices=3)
            src, size = tex, level_size

    def _swap(self, a: str, b: str) -> None:
        self.tex[a], self.tex[b] = self.tex[b], self.tex[a]

    def _scalar(self, name: str, channel: int = 0) -> float:
        """Channel ``channel`` of the 1x1 scalar ``name`` (R 0, G 1)."""
        return float(np.frombuffer(read_texture(self.scalars[name]), dtype=np.float32)[channel])

    def _set_time(self, program: Program, t: float) -> None:
        if self.loads:
            program.set(u_load=uniform_array([tuple(float(c) for c in np.asarray(load.force(t), float))
                                       for load in self.loads]))
        if self.drags:
            program.set(u_drag_target=uniform_array([tuple(float(c) for c in np.asarray(d.target(t), float))
                                              for d in self.drags]))

    def _set_spheres(self) -> None:
        values = sphere_uniforms(self.constraints, self.t, self.dt)
        if values:
            self.passes["FINAL"].set(**values)

    def _one_step(self) -> None:
        self._bind_static()
        self._set_time(self.passes["SETUP"], self.t + self.dt)
        self._draw("SETUP", {"u_v": "v", "u_vec": "v"}, ("b", "inv", "prod"))
        tol = self.tolerance > 0
        self._sum("bpb")  # (also without a tolerance: residual() reads it)
        if self.warm_start == "scaled":
            self._draw("WARM", {"u_vec": "dv", "u_b": "b"}, ("q", "prod"))
            self._sum("warm")
            self._draw("INIT", {"u_vec": "dv", "u_b": "b", "u_inv": "inv", "u_q": "q", "u_warm": "$warm"},
                       ("r", "p", "prod", "dv_out"))
            self._swap("dv", "dv_out")
        else:
            if self.warm_start == "zero":
                self._fbo(self.tex["dv"]).clear(0.0, 0.0, 0.0, 0.0)
            self._draw("INIT", {"u_vec": "dv", "u_b": "b", "u_inv": "inv"}, ("r", "p", "prod"))
        if self.multigrid:
            self._precondition("p")
        self._sum("rz")
        bb = self._scalar("bpb", 1) if tol else 0.0
        stop = max(self.tolerance * float(np.sqrt(max(bb, 0.0))), self.floor)
        done = 0
        for k in range(self.iterations):
            if tol and k % self.check_every == 0 and float(np.sqrt(max(self._scalar("rz", 1), 0.0))) <= stop:
                break
            self._draw("MATVEC", {"u_vec": "p", **({"u_b": "b"} if self.held_flag else {})}, ("q", "prod"))
            self._sum("pq")
            self._draw("UPDATE", {"u_dv": "dv", "u_r": "r", "u_p": "p", "u_q": "q", "u_inv": "inv", "u_rz": "$rz",
                                  "u_pq": "$pq"}, ("dv_out", "r_out", "prod"))
            self._swap("dv", "dv_out")
            self._swap("r", "r_out")
            if self.multigrid:
                self._precondition(None)
            self._sum("rz_new")
            z: dict[str, str | moderngl.Texture] = {"u_inv": "inv"}
            if self.multigrid:
                assert self._z is not None  # (_precondition just ran)
                z = {"u_z": self._z}
            self._draw("DIRECTION", {"u_r": "r", "u_p": "p", **z, "u_rz": "$rz", "u_rz_new": "$rz_new"},
                       ("p_out",))
            self._swap("p", "p_out")
            self.scalars["rz"], self.scalars["rz_new"] = self.scalars["rz_new"], self.scalars["rz"]
            done = k + 1
        if tol:  # the report's residual: the true |b - A dv|, not CG's updated r (at x, before FINAL)
            self._draw("TRUE_RESIDUAL", {"u_vec": "dv", "u_b": "b"}, ("prod",))
            self._sum("pq")
        self._set_spheres()
        self._draw("FINAL", {"u_v": "v", "u_dv": "dv"}, ("x_out", "v_out"))
        self._swap("x", "x_out")
        self._swap("v", "v_out")
        if tol:
            rr = self._scalar("pq", 1)
            res = self._residual(rr, bb)
            self.last_report = SolveReport(done, res, res <= self.tolerance or float(np.sqrt(max(rr, 0.0))) <= self.floor)
            if not self.last_report.within_tolerance:
                self.unconverged += 1
                self.worst_residual = max(self.worst_residual, res)
        else:
            self.last_report = SolveReport(done, float("nan"), True)
        self.stats.add(self.last_report)

    @staticmethod
    def _residual(rr: float, bb: float) -> float:
        return float(np.sqrt(max(rr, 0.0) / bb)) if bb > 0 else 0.0

    def step(self, n: int = 1) -> None:
        """``n`` steps on the GPU; with a tolerance, one scalar read every ``cg_check_every``
        iterations, none without."""
        if self._released:
            raise RuntimeError("ImplicitFragment: released")
        previous = self.ctx.fbo
        try:
            for _ in range(n):
                self._one_step()
                self._tick()
        finally:
            restore_framebuffer(self.ctx, previous)

    def residual(self) -> float:
        """The last step's relative residual ``|r| / |b|`` (with a tolerance the true residual; without
        one CG's updated r, two scalar reads)."""
        if self.tolerance > 0:
            return self.last_report.residual
        return self._residual(self._scalar("rz", 1), self._scalar("bpb", 1))

    def solver_stats(self) -> dict[str, object]:
        """The run's solves for the run record (:meth:`~deformgl.sim.implicit.SolverStats.summary`;
        without a tolerance nothing is read while stepping, so the last residual is read here)."""
        out = self.stats.summary()
        if self.tolerance <= 0 and self.steps_done:
            out["residual_last"] = self.residual()
        return out

    def solver_note(self) -> str | None:
        """What the run loop notes about the solves (CG missed its tolerance), or None."""
        return solver_note(self.unconverged, self.steps_done, self.worst_residual, self.tolerance)

    # -- read-back (explicit) ----------------------------------------------------------------

    def _read(self, name: str) -> np.ndarray:
        data = np.frombuffer(read_texture(self.tex[name]), dtype=np.float32)
        return data.reshape(-1, 4)[: self.count, :3].copy()

    def positions(self) -> np.ndarray:
        """(N, 3) float32 positions (one read-back)."""
        return self._read("x")

    def velocities(self) -> np.ndarray:
        """(N, 3) float32 velocities (one read-back)."""
        return self._read("v")

    def velocity_change(self) -> np.ndarray:
        """(N, 3) float32 dv of the last step (one read-back)."""
        return self._read("dv")

    def position_slot(self) -> tuple[moderngl.Texture, int, int, int]:
        """(texture, nodes per row, 1 slot per node, slot 0), as the fragment backend."""
        return self.tex["x"], self.layout.width, 1, 0

    @property
    def position_texture(self) -> moderngl.Texture:
        return self.tex["x"]

    @property
    def bytes_per_node(self) -> float:
        return self.bytes_allocated / self.count

    def release(self) -> None:
        """Release every GL object (idempotent)."""
        for fbo in self._fbos.values():
            if self.ctx.fbo is fbo:
                self.ctx.detect_framebuffer(0).use()
        GLOwner.release(self)
        self._fbos.clear()
