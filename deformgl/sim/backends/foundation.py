"""The fragment backend's position-Verlet fast path: Mosegaard & Sørensen 2005, section 3.1.

One fragment pass per step over RGBA32F textures, the spring force of Mosegaard & Sørensen 2005,
eq. 1 (eq. 2 where the classes share one stiffness) and the packed eq. 3 node normal written
with the new position, so a mapped mesh draws straight from the state texture.
:class:`~deformgl.sim.backends.fragment.FragmentIntegrator` picks it by itself for Verlet when
the system uses nothing the pass does not model (:func:`verlet_terms`); nothing else builds a
:class:`FoundationVerlet`. It computes the same function as the general Verlet stage
(Movania & Feng 2012, section 3; :func:`deformgl.sim.integrators.step`) from the same state.

Textures (channel layouts are also listed in docs/ARCHITECTURE.md):

* node data, static, RGBA32F (H, W, 4): R mass kg, G flag bits (exists 1, fixed 2, load g 4<<g,
  full incident cell q 64<<q), B neighbour mask (18 bits), A the spring-weight levels code
  (:func:`~deformgl.sim.backends.grid_springs.weight_levels`) or 0.
* state, three rotating RGBA32F (H, W, 4): xyz position, w packed Mosegaard & Sørensen 2005, eq. 3 normal. Position Verlet
  needs the current and previous positions; the pass writes the third, then the roles rotate.
* with the volumetric term (``system.cells``, :mod:`deformgl.sim.volume`) on a grid that is not
  dense: the cell diagonals, static, RGBA32I array of 2 layers: the node numbers of the 8 body
  diagonals (±1, ±1, ±1) (:func:`~deformgl.sim.backends.cell_pass.diagonal_table`), the node itself
  where absent. The pass computes the term with the springs (define ``CELLS``,
  ``shaders/sim/cells/node_hood.glsl``: the 18 neighbours the springs fetched and the 8
  diagonals). Compact layouts only: the z-slice atlas (a benchmark variant) refuses a system with
  cells.

Texels outside the grid (padding, empty nodes) hold position 0 and are never changed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

import moderngl
import numpy as np

from deformgl.gl.es_context import read_texture
from deformgl.errors import GLError
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner, restore_framebuffer
from deformgl.grid.nodes import NEIGHBOUR_UNIT, REST_LENGTH_UNITS, AtlasLayout, CompactLayout, NodeGrid
from deformgl.sim.backends.blocked import BlockedTextures, BlockedVerletPass, blocked_refusal, default_block
from deformgl.sim.backends.cell_pass import (active_cells, cell_flags, cell_kind, cell_terms, diagonal_table,
                                             term_uniforms)
from deformgl.sim.backends.compact_textures import layer_texture
from deformgl.sim.backends.term_tables import TermTables
from deformgl.sim.backends.uniforms import pull_uniforms
from deformgl.sim.backends.grid_springs import spring_weights, weight_layers, weight_levels
from deformgl.sim.base import SimulationBase
from deformgl.sim.integrators import Constraints, State
from deformgl.sim.normals import pack_normals, unit_sums
from deformgl.sim.stages import spec
from deformgl.sim.springs import (FLEXION, LOAD_PER_KG_BIT, MAX_LOADS, SHEAR, STRUCTURAL, Drag, Load, SpringSystem,
                                  load_groups)
from deformgl.sim.volume import CellVolumes
from deformgl.sim.terms.glsl import PassTerms, pass_terms

__all__ = ["DRAW_MODES", "LAYOUTS", "FLAG_EXISTS", "FLAG_FIXED", "PULL_SHIFT", "MAX_PULLS",
           "VerletTerms", "verlet_terms", "node_data", "node_flags", "NodeTextures", "VerletPass",
           "FoundationVerlet", "tile_rectangles"]

DRAW_MODES = ("rects", "points", "quad")
LAYOUTS = ("compact", "indexed", "atlas")
#: Node flag bits, stored in the G channel of the static node texture.
FLAG_EXISTS = 1
FLAG_FIXED = 2
#: Bit of load (pull) group g is ``1 << (PULL_SHIFT + g)``.
PULL_SHIFT = 2
#: The node's pulls are per kilogram (after the cells' bits, lib/node_flags.glsl).
FLAG_PULLS_PER_KG = 1 << 14
MAX_PULLS = MAX_LOADS
#: Texture unit of the spring-weight texture array (SPRING_WEIGHTS).
WEIGHT_UNIT = 4
#: Texture unit of the cell-diagonal table (CELLS on compact layouts that are not dense).
CELL_DIAGONAL_UNIT = 5
#: Texture units of the physics terms' node tables (deformgl.sim.terms) on the one-node pass.
TERM_UNITS = (6, 7, 8, 9, 10, 11, 12, 13, 14, 15)


@dataclass(frozen=True)
class VerletTerms:
    """The uniforms of the pass, read once from a :class:`SpringSystem` (a view of it, not a
    second model).

    Attributes:
        k_structural, k_shear: N/m of the 6 springs at distance h and the 12 at h*sqrt(2).
        damping: N*s/m global velocity damping.
        mass_damping: Rayleigh alpha in 1/s (force -alpha m v).
        weights: (N, 18) weight of each neighbour's spring (its stiffness over its class's k)
            where the springs of a class differ (the calibrated lattice), else None.
        gravity: (3,) m/s^2.
        spacing: grid spacing h (rest lengths are h and h*sqrt(2)).
        n_pulls: number of loads (pull groups).
        cells: the volumetric term's full cells (``system.cells`` when they exert a force:
            :func:`~deformgl.sim.backends.cell_pass.active_cells`), or None.
    """

    k_structural: float
    k_shear: float
    damping: float
    gravity: tuple[float, float, float]
    spacing: float
    n_pulls: int
    mass_damping: float = 0.0
    weights: np.ndarray | None = field(default=None, compare=False, repr=False)
    cells: CellVolumes | None = field(default=None, compare=False, repr=False)
    #: the system's further physics terms as the pass compiles them (deformgl.sim.terms)
    extra: PassTerms = field(default=PassTerms(()), compare=False, repr=False)


def _one_value(values: np.ndarray) -> float | None:
    return float(values[0]) if len(values) and bool(np.all(values == values[0])) else None


def verlet_terms(system: SpringSystem, grid: NodeGrid, *, loads: tuple[Load, ...] = (),
                 drags: tuple[Drag, ...] = (), constraints: Constraints | None = None) -> VerletTerms | str:
    """The pass's terms when it models everything ``system`` and the options use, else the
    reason it does not (one phrase). The springs must be the grid's (``FragmentIntegrator``
    checks that before it asks).

    The pass models: structural and shear springs at the grid's rest lengths (one stiffness per
    class, or per spring as weights of the class's largest), per-node mass, fixed nodes, global
    velocity damping and Rayleigh mass damping, gravity, up to :data:`MAX_PULLS` loads, the volumetric term of
    the full cells (``system.cells``), the physics terms that act on the node alone
(``system.terms``). It does not model flexion springs, terms that read the grid neighbours, spring
    damping, wind, drags or obstacles.
    """
    cls = system.spring_class
    if np.any(cls == FLEXION):
        return "flexion springs"
    for term in system.terms:
        if term.neighbours:  # (the pass sums the springs in Mosegaard & Sørensen's grouped form)
            return term.name
    if np.any(system.damping > 0):
        return "spring damping"
    if system.wind_drag > 0:
        return "wind"
    if drags:
        return "drags"
    if constraints is not None and (constraints.ground is not None or constraints.spheres):
        return "obstacles"
    if len(loads) > MAX_PULLS:
        return f"more than {MAX_PULLS} loads"
    k = [float(system.stiffness[cls == c].max()) if np.any(cls == c) else None for c in (STRUCTURAL, SHEAR)]
    for c, name in ((STRUCTURAL, "structural"), (SHEAR, "shear")):
        sel = cls == c
        rest = grid.spacing * np.where(c == STRUCTURAL, REST_LENGTH_UNITS[0], REST_LENGTH_UNITS[-1])
        if np.any(sel) and not np.allclose(system.rest_length[sel], rest, rtol=1e-9, atol=0.0):
            return f"{name} rest lengths other than the grid's"
    weights = spring_weights(system, grid.neighbours, [k[0] or 0.0, k[1] or 0.0, 0.0])
    return VerletTerms(k_structural=k[0] or 0.0, k_shear=k[1] or 0.0, damping=float(system.velocity_damping),
                       gravity=(float(system.gravity[0]), float(system.gravity[1]), float(system.gravity[2])),
                       spacing=float(grid.spacing), n_pulls=len(loads), mass_damping=float(system.mass_damping),
                       weights=weights, cells=active_cells(system.cells),
                       extra=pass_terms(system.terms, "fragment", "FragmentIntegrator"))


def node_data(grid: NodeGrid, mass: np.ndarray, flags: np.ndarray, weights: np.ndarray | None,
              weight_texture: bool = False) -> tuple[np.ndarray, bool]:
    """(N, 4) float64 static node texel of every node (mass, flags, neighbour mask, the spring
    weights' levels code or 0) and whether the levels code holds the weights (else any weights
    need a weight texture; ``weight_texture``: always)."""
    levels = None if weights is None or weight_texture else weight_levels(weights, grid.neighbour_mask)
    node = np.stack([mass, flags, grid.neighbour_mask, np.zeros(grid.count) if levels is None else levels], axis=1)
    return node, levels is not None


def node_flags(fixed: np.ndarray, load_bits: np.ndarray | None = None) -> np.ndarray:
    """(N,) int64 flag bits of the static node texture: exists, fixed, load groups and
    :data:`FLAG_PULLS_PER_KG` (``load_bits``: :func:`~deformgl.sim.springs.load_groups`)."""
    bits = FLAG_EXISTS + FLAG_FIXED * np.asarray(fixed, np.int64)
    if load_bits is not None:
        groups = np.asarray(load_bits, np.int64)
        bits = bits + ((groups & ((1 << MAX_LOADS) - 1)) << PULL_SHIFT)
        bits = bits + FLAG_PULLS_PER_KG * ((groups >> LOAD_PER_KG_BIT) & 1)
    return bits


def tile_rectangles(layout: AtlasLayout, ijk: np.ndarray) -> np.ndarray:
    """(6 * tiles, 2) triangle corners, in texels, of the rectangle around each tile's nodes."""
    texels = layout.texel(ijk)
    corners = []
    for k in np.unique(ijk[:, 2]):
        t = texels[ijk[:, 2] == k]
        (x0, y0), (x1, y1) = t.min(axis=0), t.max(axis=0) + 1
        corners += [(x0, y0), (x1, y0), (x1, y1), (x0, y0), (x1, y1), (x0, y1)]
    return np.array(corners, dtype=np.float64)


class NodeTextures(GLOwner):
    """The GL textures of a node grid: one static node-data texture and the rotating state.

    Args:
        ctx: GL context.
        grid: the node grid.
        mass: (N,) kg per node (default 1: drawing only).
        flags: (N,) flag bits (:func:`node_flags`; default: every node exists, none fixed).
        n_state: number of state textures (3 for position Verlet).
        layout: "compact" (existing nodes packed densely, neighbours from an index texture, or
            by node-number offsets on dense grids), "indexed" (compact with the index texture
            always, to measure what the offsets save) or "atlas" (z-slices as tiles, neighbours
            by tile arithmetic); see docs/ARCHITECTURE.md.
        positions: (n_state, N, 3) start positions of each state texture (default: the rest
            positions in all); the w channel gets the packed Mosegaard & Sørensen 2005, eq. 3 normal of those positions.
        weights: (N, 18) spring weights (:class:`VerletTerms`), or None. Cell shares of the
            calibrated lattice go into the node texture's alpha as a levels code
            (:func:`weight_levels`; ``weight_levels`` is then True); other weights are stored as a
            5-layer RGBA32F texture array in the layout (bound to :data:`WEIGHT_UNIT`).
        weight_texture: store the weights in the texture array even where levels could hold
            them (to measure what the levels save, and test they match).
        cells: "none", or the terms of the volumetric term the pass computes: "barrier" (the
            barrier alone) or "centre" (the centre term, with or without the barrier), which on a
            compact layout that is not dense needs the node numbers of the 8 body diagonals in
            :attr:`cell_diagonals` (bound to :data:`CELL_DIAGONAL_UNIT`); the atlas refuses both.
    """

    def __init__(self, ctx: moderngl.Context, grid: NodeGrid, *, mass: np.ndarray | None = None,
                 flags: np.ndarray | None = None, n_state: int = 3, layout: str = "compact",
                 positions: np.ndarray | None = None, weights: np.ndarray | None = None,
                 weight_texture: bool = False, cells: str = "none") -> None:
        if layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
        super().__init__(ctx)
        max_size = int(ctx.info["GL_MAX_TEXTURE_SIZE"])
        try:
            self.layout: AtlasLayout | CompactLayout = (
                CompactLayout.for_grid(grid, max_size, arithmetic=layout == "compact")
                if layout in ("compact", "indexed") else AtlasLayout.for_grid(grid.shape, max_size))
        except ValueError as exc:
            raise GLError(f"{exc}; use a coarser grid") from None
        n = grid.count
        self.grid = grid
        mass = np.ones(n) if mass is None else np.asarray(mass, np.float64)
        flags = node_flags(np.zeros(n, bool)) if flags is None else np.asarray(flags)
        starts = (np.broadcast_to(grid.rest_positions, (n_state, n, 3)) if positions is None
                  else np.asarray(positions, np.float64))
        self.size = self.layout.size
        self.neighbours: moderngl.TextureArray | None = None
        self.weights: moderngl.TextureArray | None = None
        #: RGBA32I array, 2 layers: the node at body diagonal q (channel q % 4 of layer q // 4), or None
        self.cell_diagonals: moderngl.TextureArray | None = None
        if cells not in ("none", "barrier", "centre"):
            raise ValueError(f"cells must be 'none', 'barrier' or 'centre', got {cells!r}")
        if cells != "none" and not isinstance(self.layout, CompactLayout):
            raise ValueError("NodeTextures: the atlas layout has no cell term (a system with cells runs on the compact "
                             "layout)")
        node, levels = node_data(grid, mass, flags, weights, weight_texture)
        #: the spring weights are the levels code in the node texture's alpha (SPRING_WEIGHT_LEVELS)
        self.weight_levels = levels
        self.state: list[moderngl.Texture] = []
        self.framebuffers: list[moderngl.Framebuffer] = []
        with self.building():
            if isinstance(self.layout, CompactLayout) and not self.layout.dense:
                layers = self.layout.neighbour_layers(grid.neighbours)
                w, h = self.layout.size
                self.neighbours = self.own(ctx.texture_array((w, h, 5), 4, layers.tobytes(), dtype="i4"))
                self.neighbours.filter = (moderngl.NEAREST, moderngl.NEAREST)
                if cells == "centre":
                    self.cell_diagonals = layer_texture(self, ctx, self.layout.size, diagonal_table(grid), "i4", 2)
            if weights is not None and not levels:
                w, h = self.layout.size
                images = np.stack([self.layout.scatter(grid.ijk, layer) for layer in weight_layers(weights)])
                self.weights = self.own(ctx.texture_array((w, h, 5), 4,
                                                          np.ascontiguousarray(images, dtype="f4").tobytes(),
                                                          dtype="f4"))
                self.weights.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self.node = self._texture(self.layout.scatter(grid.ijk, node))
            for x in starts:
                image = np.concatenate([x, pack_normals(unit_sums(grid, x))[:, None]], axis=1)
                tex = self._texture(self.layout.scatter(grid.ijk, image))
                self.state.append(tex)
                self.framebuffers.append(self.own(ctx.framebuffer(color_attachments=[tex])))

    def _texture(self, image: np.ndarray) -> moderngl.Texture:
        h, w, c = image.shape
        tex = self.own(self.ctx.texture((w, h), c, data=np.ascontiguousarray(image, dtype="f4").tobytes(),
                                        dtype="f4"))
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        tex.repeat_x = tex.repeat_y = False
        return tex

    @property
    def bytes_allocated(self) -> int:
        """GPU bytes of every texture (padding texels included)."""
        w, h = self.size
        static = w * h * 16 + (0 if self.neighbours is None else w * h * 5 * 16) + \
            (0 if self.weights is None else w * h * 5 * 16) + (0 if self.cell_diagonals is None else w * h * 2 * 16)
        return static + len(self.state) * w * h * 16

    def view(self, current: int) -> moderngl.Texture:
        """State texture ``current`` (what the draw passes read; as :meth:`BlockedTextures.view`)."""
        return self.state[current]

    def read(self, which: int) -> np.ndarray:
        """(N, 4) float32 state texel of every node of state texture ``which`` (one read-back)."""
        w, h = self.size
        image = np.frombuffer(read_texture(self.state[which]), dtype="f4").reshape(h, w, 4)
        return self.layout.gather(self.grid.ijk, image)

    def bind_static(self, node_unit: int) -> None:
        """Bind the node-data texture (and the neighbour-index texture of compact layouts)."""
        self.node.use(node_unit)
        if self.neighbours is not None:
            self.neighbours.use(NEIGHBOUR_UNIT)
        if self.weights is not None:
            self.weights.use(WEIGHT_UNIT)
        if self.cell_diagonals is not None:
            self.cell_diagonals.use(CELL_DIAGONAL_UNIT)

    def release(self) -> None:
        """Release every texture and framebuffer (idempotent)."""
        super().release()
        self.framebuffers, self.state = [], []


class VerletPass(GLOwner):
    """The position-Verlet fragment pass: one program, one draw per step.

    Args:
        ctx: GL context.
        terms: the pass's uniforms (decide the compiled variant: pulls).
        grid: the node grid.
        textures: the textures it reads and writes.
        draw: ``"rects"`` (default) draws, per z-slice tile, the rectangle around its existing
            nodes and skips empty texels inside it with a test; ``"points"`` draws one point per
            existing node (no test, but llvmpipe pays per primitive); ``"quad"`` covers the
            whole atlas, padding included. ``python -m studies.pass_variants`` measures all three.
        branch: test each neighbour's mask bit with a branch instead of weighting by it.
    """

    def __init__(self, ctx: moderngl.Context, terms: VerletTerms, grid: NodeGrid, textures: NodeTextures, *,
                 draw: str = "rects", branch: bool = False) -> None:
        if draw not in DRAW_MODES:
            raise ValueError(f"draw must be one of {DRAW_MODES}, got {draw!r}")
        super().__init__(ctx)
        layout = textures.layout
        cells = terms.cells
        if cells is not None and not isinstance(layout, CompactLayout):
            raise ValueError("VerletPass: the cell term needs a compact layout")
        if terms.extra and not isinstance(layout, CompactLayout):
            raise ValueError("VerletPass: the physics terms' tables need a compact layout, not the z-slice atlas")
        if isinstance(layout, CompactLayout) and draw == "rects":
            draw = "quad"  # a compact layout is one rectangle of existing nodes already
        self.draw = draw
        self.n_pulls = terms.n_pulls
        vert = {"points": "sim/node_points.vert", "rects": "sim/node_rects.vert",
                "quad": "sim/fullscreen.vert"}[draw]
        self.vbo: moderngl.Buffer | None = None
        with self.building():
            self.program = self.own(Program(ctx, vert, "sim/verlet.frag", defines={
                "NEIGHBOUR_BRANCH": branch, "DRAW_POINTS": draw == "points", "PULLS": terms.n_pulls,
                "SPRING_WEIGHTS": textures.weights is not None or textures.weight_levels,
                "SPRING_WEIGHT_LEVELS": textures.weight_levels, "CELLS": cells is not None,
                **(cell_terms(cells) if cells is not None else {}), **layout.shader_defines(),
                **terms.extra.defines()}, chunks=terms.extra.chunks()))
            if cells is not None:
                self.program.set(**term_uniforms(cells))
            if textures.cell_diagonals is not None:
                self.program.set(u_cell_diagonals=CELL_DIAGONAL_UNIT)
            self.program.set(**layout.shader_uniforms(),
                             u_spacing=terms.spacing, u_k_structural=terms.k_structural,
                             u_k_shear=terms.k_shear, u_damping=terms.damping, u_mass_damping=terms.mass_damping,
                             u_gravity=terms.gravity, u_position=0, u_previous=1, u_node=2)
            if textures.weights is not None:
                self.program.set(u_weights=WEIGHT_UNIT)
            if draw == "points":
                self.program.set(u_target_size=textures.size)
                texels = layout.texel(grid.ijk).astype("i4")
                self.vbo = self.own(ctx.buffer(texels.tobytes()))
                self.vao = self.own(ctx.vertex_array(self.program.gl, [(self.vbo, "2i", "in_texel")]))
                self.vertices = len(texels)
                self.mode = moderngl.POINTS
            elif draw == "rects" and isinstance(layout, AtlasLayout):  # (compact: "quad", above)
                self.program.set(u_target_size=textures.size)
                corners = tile_rectangles(layout, grid.ijk)
                self.vbo = self.own(ctx.buffer(corners.astype("f4").tobytes()))
                self.vao = self.own(ctx.vertex_array(self.program.gl, [(self.vbo, "2f", "in_texel_corner")]))
                self.vertices = len(corners)
                self.mode = moderngl.TRIANGLES
            else:
                self.vao = self.own(ctx.vertex_array(self.program.gl, []))
                self.vertices = 3
                self.mode = moderngl.TRIANGLES
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
        self.vao.render(self.mode, vertices=self.vertices)


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
        draw, branch: pass variants, see :class:`VerletPass`; weight_texture: see :class:`NodeTextures`.
        layout: "compact", "indexed", "atlas" (:class:`NodeTextures`), "blocked" (``block`` nodes per
            fragment, :mod:`~deformgl.sim.backends.blocked`) or "auto" (``block`` if given, else
            :func:`~deformgl.sim.backends.blocked.default_block`, where the renderer can run it;
            else "compact").
        block: (x, y, z) nodes per fragment (:data:`~deformgl.grid.blocks.BLOCK_SHAPES`).

    Raises:
        ValueError: dt <= 0; the atlas layout with cells; "blocked" without a block, a block with
            another layout or a draw other than "rects", a block the renderer cannot run
            (:func:`~deformgl.sim.backends.blocked.blocked_refusal`).
    """

    backend = "fragment"
    integrator = "verlet"
    #: the integrator it implements, as the stage table describes it (one stage, x_prev state)
    spec = spec("verlet")

    def __init__(self, ctx: moderngl.Context, system: SpringSystem, grid: NodeGrid, terms: VerletTerms,
                 dt: float, state: State, *, loads: tuple[Load, ...] = (), t0: float = 0.0,
                 draw: str = "rects", branch: bool = False, layout: str = "compact",
                 weight_texture: bool = False, block: tuple[int, int, int] | None = None) -> None:
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        if layout == "blocked" and block is None:
            raise ValueError("FoundationVerlet: the blocked layout takes a block shape")
        if layout not in ("auto", "blocked") and block is not None:
            raise ValueError(f"FoundationVerlet: layout {layout!r} takes no block shape")
        if block is not None and draw != "rects":
            raise ValueError(f"FoundationVerlet: draw {draw!r} is a variant of the one-node pass, not of a block")
        GLOwner.__init__(self, ctx)
        self.system, self.grid = system, grid
        self._start_clock(dt, t0)
        self.loads = tuple(loads)
        self.count = grid.count
        flags = node_flags(system.fixed, load_groups(self.loads, grid.count)) | cell_flags(grid, terms.cells)
        x = np.asarray(state.x, np.float64)
        x_prev = np.where(system.fixed[:, None], x, np.asarray(state.x_prev, np.float64))
        if layout == "auto" and block is None and draw == "rects":  # (points, quad: one-node variants)
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
                block_pass = self.own(BlockedVerletPass(ctx, terms, blocked, weight_levels=levels, branch=branch))
                block_pass.program.set(**self.term_tables.uniforms)
                self.textures, self.verlet = blocked, block_pass
                #: one step: (current, previous, target, dt, pull forces)
                self._draw_step = partial(block_pass.run, blocked)
            else:
                textures = self.own(NodeTextures(ctx, grid, mass=system.mass, flags=flags, layout=layout,
                                                 positions=np.stack([x, x_prev, x]), weights=terms.weights,
                                                 weight_texture=weight_texture, cells=cell_kind(terms.cells)))
                one_pass = self.own(VerletPass(ctx, terms, grid, textures, draw=draw, branch=branch))
                if terms.extra:
                    self.term_tables = self.own(TermTables(ctx, terms.extra, grid, textures.layout, TERM_UNITS))
                    one_pass.program.set(**self.term_tables.uniforms)
                self.textures, self.verlet = textures, one_pass
                self._draw_step = partial(one_pass.run, textures)
        self.current, self.previous, self.spare = 0, 1, 2
        self._pull = np.zeros((MAX_PULLS, 3))

    @property
    def position_texture(self) -> moderngl.Texture:
        """The state texture holding the latest positions and packed normals (the blocked layout's
        compact view)."""
        return self.textures.view(self.current)

    def position_slot(self) -> tuple[moderngl.Texture, int, int, int]:
        """(texture, nodes per row, texels per node, slot) of the latest positions, for
        :class:`~deformgl.sim.census.NodeCensus` (compact layouts only: node n is texel
        (n % width, n // width); w, the packed normal, is not looked at)."""
        if not isinstance(self.textures.layout, CompactLayout):
            raise ValueError("position_slot: the atlas layout does not store node n at (n % width, n // width)")
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
