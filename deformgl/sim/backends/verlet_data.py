"""The fragment backend's position-Verlet fast path (Mosegaard & Sørensen 2005, section 3.1): what
the pass models of a system (:func:`verlet_terms`) and its node textures (:class:`NodeTextures`);
the pass and the simulation are :mod:`deformgl.sim.backends.verlet_pass`.

One fragment pass per step over RGBA32F textures, the spring force of Mosegaard & Sørensen 2005,
eq. 1 (eq. 2 where the classes share one stiffness) and the packed eq. 3 node normal written
with the new position, so a mapped mesh draws straight from the state texture.
:class:`~deformgl.sim.backends.explicit_gpu.FragmentIntegrator` picks it by itself for Verlet when
the system uses nothing the pass does not model (:func:`verlet_terms`); nothing else builds a
:class:`~deformgl.sim.backends.verlet_pass.FoundationVerlet`. It computes the same function as the general Verlet stage
(Movania & Feng 2012, section 3; :func:`deformgl.sim.integrators.step`) from the same state.

Textures (channel layouts are also listed in docs/ARCHITECTURE.md):

* node data, static, RGBA32F (H, W, 4): R mass kg, G flag bits (exists 1, fixed 2, load g 4<<g,
  the terms' node bits 64<<b), B neighbour mask (18 bits), A the spring-weight levels code
  (:func:`~deformgl.sim.backends.grid_springs.weight_levels`) or 0.
* state, three rotating RGBA32F (H, W, 4): xyz position, w packed Mosegaard & Sørensen 2005, eq. 3 normal. Position Verlet
  needs the current and previous positions; the pass writes the third, then the roles rotate.
* with a physics term that reads the body diagonals of the node's neighbourhood on a grid that
  is not dense: the hood diagonals,
  static, RGBA32I array of 2 layers: the node numbers of the 8 body diagonals (±1, ±1, ±1)
  (:func:`~deformgl.grid.neighbours.diagonal_table`), the node itself where absent. The
  pass computes the terms with the springs (define ``TERMS``, ``TERMS_HOOD``:
  ``shaders/lib/node_hood.glsl``, the 18 neighbours the springs fetched and the 8 diagonals).

Texels past the last node hold position 0 and are never changed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import moderngl
import numpy as np

from deformgl.gl.es_context import read_texture
from deformgl.errors import GLError
from deformgl.gl.resources import GLOwner
from deformgl.grid.nodes import NEIGHBOUR_UNIT, REST_LENGTH_UNITS, CompactLayout, NodeGrid
from deformgl.grid.neighbours import diagonal_table
from deformgl.sim.backends.compact_textures import layer_texture
from deformgl.sim.backends.grid_springs import spring_weights, weight_layers, weight_levels
from deformgl.sim.integrators import Constraints, State
from deformgl.sim.normals import pack_normals, unit_sums
from deformgl.sim.springs import FLEXION, SHEAR, STRUCTURAL, SpringSystem
from deformgl.sim.scripted import LOAD_PER_KG_BIT, MAX_LOADS, Drag, Load, load_groups

from deformgl.sim.terms.glsl import PassTerms, pass_terms

__all__ = ["LAYOUTS", "FLAG_EXISTS", "FLAG_FIXED", "PULL_SHIFT", "MAX_PULLS",
           "VerletTerms", "verlet_terms", "node_data", "node_flags", "NodeTextures"]

#: The one-node layouts of :class:`NodeTextures`: "compact", and "indexed" (the compact layout
#: with its neighbour-index texture even on a dense grid: the tests that check both lookups agree
#: and the study that times them; the product picks by :attr:`CompactLayout.dense`).
LAYOUTS = ("compact", "indexed")
#: Node flag bits, stored in the G channel of the static node texture.
FLAG_EXISTS = 1
FLAG_FIXED = 2
#: Bit of load (pull) group g is ``1 << (PULL_SHIFT + g)``.
PULL_SHIFT = 2
#: The node's pulls are per kilogram (after the terms' node bits, lib/node_flags.glsl).
FLAG_PULLS_PER_KG = 1 << 14
MAX_PULLS = MAX_LOADS
#: Texture unit of the spring-weight texture array (SPRING_WEIGHTS).
WEIGHT_UNIT = 4
#: Texture unit of the hood-diagonal table (HOOD_DIAGONALS on compact layouts that are not dense).
HOOD_DIAGONAL_UNIT = 5
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
    """

    k_structural: float
    k_shear: float
    damping: float
    gravity: tuple[float, float, float]
    spacing: float
    n_pulls: int
    mass_damping: float = 0.0
    weights: np.ndarray | None = field(default=None, compare=False, repr=False)
    #: the system's further physics terms as the pass compiles them (deformgl.sim.terms)
    extra: PassTerms = field(default=PassTerms(()), compare=False, repr=False)


def verlet_terms(system: SpringSystem, grid: NodeGrid, *, loads: tuple[Load, ...] = (),
                 drags: tuple[Drag, ...] = (), constraints: Constraints | None = None) -> VerletTerms | str:
    """The pass's terms when it models everything ``system`` and the options use, else the
    reason it does not (one phrase). The springs must be the grid's (``FragmentIntegrator``
    checks that before it asks).

    The pass models: structural and shear springs at the grid's rest lengths (one stiffness per
    class, or per spring as weights of the class's largest), per-node mass, fixed nodes, global
    velocity damping and Rayleigh mass damping, gravity, up to :data:`MAX_PULLS` loads, the physics
    terms that act on the node or read its 3x3x3 neighbourhood (``system.terms``). It does not
    model flexion springs, terms called per grid
    neighbour, spring damping, wind, drags or obstacles.
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
    extra = pass_terms(system.terms, "fragment", "FragmentIntegrator", grid, prepass=True)
    if extra.prepasses:  # (the pass evaluates its forces once per step, in one draw)
        return f"a term with a pass of its own ({extra.prepasses[0].prefix})"
    weights = spring_weights(system, grid.neighbours, [k[0] or 0.0, k[1] or 0.0, 0.0])
    return VerletTerms(k_structural=k[0] or 0.0, k_shear=k[1] or 0.0, damping=float(system.velocity_damping),
                       gravity=(float(system.gravity[0]), float(system.gravity[1]), float(system.gravity[2])),
                       spacing=float(grid.spacing), n_pulls=len(loads), mass_damping=float(system.mass_damping),
                       weights=weights, extra=extra)


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
    :data:`FLAG_PULLS_PER_KG` (``load_bits``: :func:`~deformgl.sim.scripted.load_groups`)."""
    bits = FLAG_EXISTS + FLAG_FIXED * np.asarray(fixed, np.int64)
    if load_bits is not None:
        groups = np.asarray(load_bits, np.int64)
        bits = bits + ((groups & ((1 << MAX_LOADS) - 1)) << PULL_SHIFT)
        bits = bits + FLAG_PULLS_PER_KG * ((groups >> LOAD_PER_KG_BIT) & 1)
    return bits


class NodeTextures(GLOwner):
    """The GL textures of a node grid: one static node-data texture and the rotating state.

    Args:
        ctx: GL context.
        grid: the node grid.
        mass: (N,) kg per node (default 1: drawing only).
        flags: (N,) flag bits (:func:`node_flags`; default: every node exists, none fixed).
        n_state: number of state textures (3 for position Verlet).
        layout: "compact" (existing nodes packed densely, neighbours from an index texture, or
            by node-number offsets on dense grids) or "indexed" (:data:`LAYOUTS`); see
            docs/ARCHITECTURE.md.
        positions: (n_state, N, 3) start positions of each state texture (default: the rest
            positions in all); the w channel gets the packed Mosegaard & Sørensen 2005, eq. 3 normal of those positions.
        weights: (N, 18) spring weights (:class:`VerletTerms`), or None. Cell shares of the
            calibrated lattice go into the node texture's alpha as a levels code
            (:func:`weight_levels`; ``weight_levels`` is then True); other weights are stored as a
            5-layer RGBA32F texture array in the layout (bound to :data:`WEIGHT_UNIT`).
        weight_texture: store the weights in the texture array even where levels could hold
            them (the tests that check both give the same step, and the study that times them).
        hood: how much of the node's 3x3x3 neighbourhood the pass keeps for its terms
            (:attr:`~deformgl.sim.terms.glsl.PassTerms.hood`): 0, 1 (the 18 neighbours) or 2 (and
            the body diagonals, which on a compact layout that is not dense need their node numbers
            in :attr:`hood_diagonals`, bound to :data:`HOOD_DIAGONAL_UNIT`).
    """

    def __init__(self, ctx: moderngl.Context, grid: NodeGrid, *, mass: np.ndarray | None = None,
                 flags: np.ndarray | None = None, n_state: int = 3, layout: str = "compact",
                 positions: np.ndarray | None = None, weights: np.ndarray | None = None,
                 weight_texture: bool = False, hood: int = 0) -> None:
        if layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
        super().__init__(ctx)
        max_size = int(ctx.info["GL_MAX_TEXTURE_SIZE"])
        try:
            self.layout = CompactLayout.for_grid(grid, max_size, arithmetic=layout == "compact")
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
        self.hood_diagonals: moderngl.TextureArray | None = None
        if hood not in (0, 1, 2):
            raise ValueError(f"hood must be 0, 1 or 2, got {hood!r}")
        node, levels = node_data(grid, mass, flags, weights, weight_texture)
        #: the spring weights are the levels code in the node texture's alpha (SPRING_WEIGHT_LEVELS)
        self.weight_levels = levels
        self.state: list[moderngl.Texture] = []
        self.framebuffers: list[moderngl.Framebuffer] = []
        with self.building():
            if not self.layout.dense:
                layers = self.layout.neighbour_layers(grid.neighbours)
                w, h = self.layout.size
                self.neighbours = self.own(ctx.texture_array((w, h, 5), 4, layers.tobytes(), dtype="i4"))
                self.neighbours.filter = (moderngl.NEAREST, moderngl.NEAREST)
                if hood > 1:
                    self.hood_diagonals = layer_texture(self, ctx, self.layout.size, diagonal_table(grid), "i4", 2)
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
        """GPU bytes of every texture (the texels past the last node included)."""
        w, h = self.size
        static = w * h * 16 + (0 if self.neighbours is None else w * h * 5 * 16) + \
            (0 if self.weights is None else w * h * 5 * 16) + (0 if self.hood_diagonals is None else w * h * 2 * 16)
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
        if self.hood_diagonals is not None:
            self.hood_diagonals.use(HOOD_DIAGONAL_UNIT)

    def release(self) -> None:
        """Release every texture and framebuffer (idempotent)."""
        super().release()
        self.framebuffers, self.state = [], []
