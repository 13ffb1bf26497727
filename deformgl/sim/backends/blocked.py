"""The foundation's position-Verlet pass on the blocked node layout: several nodes per fragment
(issue 30; :class:`~deformgl.grid.blocks.BlockedLayout`).

One fragment owns a block of nodes: it fetches the block's union neighbourhood once and writes its
members' new states through one render target each. Every node's update is the one-node pass's
(``shaders/sim/verlet_node.glsl``), so the positions are bit for bit those of the compact layout.
The pass models what :class:`~deformgl.sim.backends.verlet_pass.VerletPass` models: springs with
per-spring weights (levels codes or a weight texture), fixed nodes, pulls, damping, and the
physics terms that act on the node or read its neighbourhood (the body diagonals from the block's). A block needs one render
target per member (:func:`blocked_refusal`).

Textures (channel layouts in docs/ARCHITECTURE.md, "Blocked layout"):

* state, three rotating sets of ``members`` RGBA32F textures (H, W, 4) in blocks: texel b of
  texture m holds member m of block b, xyz position, w packed Mosegaard & Sørensen 2005, eq. 3
  normal; one framebuffer per set with ``members`` colour attachments.
* node data, static, RGBA32F array of ``members`` layers: the one-node pass's node texel
  (``shaders/lib/node_flags.glsl``) of member m in layer m; a member without a node is all 0.
* where not every block exists: the block-neighbour table, RGBA32I array of 7 layers
  (:meth:`~deformgl.grid.blocks.BlockedLayout.neighbour_layers`).
* per-spring weights that are not levels codes: RGBA32F array of 5 layers per member, member m's
  (the one-node weight texture's 5 layers) at layers 5 m .. 5 m + 4.
* the compact view: one RGBA32F texture in the compact layout (what the draw passes, the census and
  the mappings read), filled from the current set by ``shaders/sim/unblock.frag`` when asked for,
  through a static RGBA32I place texture (the node's block texel x, y and member).
"""

from __future__ import annotations

import moderngl
import numpy as np

from deformgl.errors import GLError
from deformgl.gl.es_context import read_texture
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner, restore_framebuffer
from deformgl.grid.blocks import BlockedLayout
from deformgl.grid.nodes import CompactLayout, NodeGrid
from deformgl.sim.backends.compact_textures import compact_image, float_texture
from deformgl.sim.backends.grid_springs import weight_layers
from deformgl.sim.backends.uniforms import pull_uniforms
from deformgl.sim.normals import pack_normals, unit_sums

__all__ = ["BlockedTextures", "BlockedVerletPass", "blocked_refusal", "default_block", "texture_units", "BLOCK_TABLE",
           "SHEET_BLOCK"]

#: The block the foundation pass takes by itself (``layout="auto"``) on a volume, by grid size: the
#: first row whose node count the grid reaches; None: the compact layout. The block is turned so
#: that its side of one node lies along the grid's thinnest axis. A sheet (a grid one node thick
#: along an axis) takes :data:`SHEET_BLOCK` nodes along its first other axis instead. Measured with
#: ``deformgl bench sim --blocks`` on llvmpipe (docs/PERFORMANCE.md, "Several nodes per fragment:
#: the blocked layout").
BLOCK_TABLE: tuple[tuple[int, tuple[int, int, int] | None], ...] = ((2000, (1, 2, 2)), (0, None))
#: Nodes per block on a sheet: 2 (128 x 128 x 1: 1.9-2.0x the compact pass, blocks of 4 1.2-1.3x).
SHEET_BLOCK = 2


def default_block(grid: NodeGrid) -> tuple[int, int, int] | None:
    """The block :data:`BLOCK_TABLE` gives ``grid`` (None: the compact layout), its shortest side
    along the grid's thinnest axis (the first of equals: x); on a sheet :data:`SHEET_BLOCK` nodes
    along the sheet's first axis."""
    for count, block in BLOCK_TABLE:
        if grid.count >= count:
            if block is None:
                return None
            shape = [1, 1, 1]
            if 1 in grid.shape:
                shape[next(a for a in range(3) if grid.shape[a] > 1)] = SHEET_BLOCK
                return shape[0], shape[1], shape[2]
            thin = int(np.argmin(grid.shape))
            order = sorted(range(3), key=lambda a: (a != thin, a))  # the thinnest axis first
            for axis, side in zip(order, sorted(block)):
                shape[axis] = side
            return shape[0], shape[1], shape[2]
    return None


def texture_units(members: int) -> dict[str, int]:
    """The blocked pass's texture units: current members 0 .. m - 1, previous m .. 2m - 1, then the
    node data, the block-neighbour table and the spring weights (2m + 3 units: 19 for 8 members)."""
    return {"previous": members, "node": 2 * members, "neighbours": 2 * members + 1, "weights": 2 * members + 2}


def blocked_refusal(info, block: tuple[int, int, int]) -> str | None:
    """Why the blocked pass cannot run in ``block`` on the renderer of ``info`` (a context's
    ``ctx.info``: its render targets and fragment texture units), or None."""
    members = block[0] * block[1] * block[2]
    targets = min(int(info["GL_MAX_DRAW_BUFFERS"]), int(info.get("GL_MAX_COLOR_ATTACHMENTS", 8)))
    if members > targets:
        return f"a block of {members} nodes needs {members} render targets, the renderer has {targets}"
    units = int(info.get("GL_MAX_TEXTURE_IMAGE_UNITS", 16))
    if texture_units(members)["weights"] + 1 > units:
        return (f"a block of {members} nodes samples up to {texture_units(members)['weights'] + 1} textures, "
                f"the renderer has {units} units")
    return None


class BlockedTextures(GLOwner):
    """The GL textures of a node grid in blocks: static node data, three rotating state sets, and
    the compact view (:attr:`layout`, :attr:`size` and :meth:`view` are the compact view's, what
    the draw passes read).

    Args:
        ctx: GL context.
        grid: the node grid.
        block: (bx, by, bz) nodes per block (:data:`~deformgl.grid.blocks.BLOCK_SHAPES`).
        node: (N, 4) float64 static node texel of each node (mass, flags, mask, levels code).
        positions: (3, N, 3) start positions of each state set; w gets the packed normal.
        weights: (N, 18) per-spring weights to store as a texture (None: none, or levels codes in
            ``node``).
        arithmetic: False: the block-neighbour table even where every block exists.
    """

    def __init__(self, ctx: moderngl.Context, grid: NodeGrid, block: tuple[int, int, int], node: np.ndarray,
                 positions: np.ndarray, *, weights: np.ndarray | None = None, arithmetic: bool = True) -> None:
        super().__init__(ctx)
        max_size = int(ctx.info["GL_MAX_TEXTURE_SIZE"])
        try:
            self.blocks = BlockedLayout.for_grid(grid, block, max_size, arithmetic=arithmetic)
            #: the compact view's layout (what the draw passes and the census read)
            self.layout = CompactLayout.for_grid(grid, max_size)
        except ValueError as exc:
            raise GLError(f"{exc}; use a coarser grid") from None
        self.grid = grid
        self.size = self.layout.size
        self.members = self.blocks.members
        bw, bh = self.blocks.size
        self.neighbours: moderngl.TextureArray | None = None
        self.weights: moderngl.TextureArray | None = None
        self.state: list[list[moderngl.Texture]] = []
        self.framebuffers: list[moderngl.Framebuffer] = []
        self._viewed: int | None = None  # the state set the view holds
        with self.building():
            images = self.blocks.scatter(grid.ijk, np.asarray(node, np.float64))
            self.node = self.own(ctx.texture_array((bw, bh, self.members), 4,
                                                   np.ascontiguousarray(images, "f4").tobytes(), dtype="f4"))
            self.node.filter = (moderngl.NEAREST, moderngl.NEAREST)
            if not self.blocks.dense:
                layers = self.blocks.neighbour_layers()
                self.neighbours = self.own(ctx.texture_array((bw, bh, len(layers)), 4, layers.tobytes(), dtype="i4"))
                self.neighbours.filter = (moderngl.NEAREST, moderngl.NEAREST)
            if weights is not None:
                layers = np.stack([self.blocks.scatter(grid.ijk, layer) for layer in weight_layers(weights)], axis=1)
                self.weights = self.own(ctx.texture_array((bw, bh, 5 * self.members), 4,
                                                          np.ascontiguousarray(layers, "f4").tobytes(), dtype="f4"))
                self.weights.filter = (moderngl.NEAREST, moderngl.NEAREST)
            for x in positions:
                values = np.concatenate([x, pack_normals(unit_sums(grid, x))[:, None]], axis=1)
                textures = [float_texture(self, ctx, (bw, bh), image) for image in self.blocks.scatter(grid.ijk, values)]
                self.state.append(textures)
                self.framebuffers.append(self.own(ctx.framebuffer(color_attachments=textures)))
            member, texel = self.blocks.place(grid.ijk)
            place = np.full((self.layout.size[1] * self.layout.size[0], 4), -1, np.int32)  # padding: member -1, 0
            place[: grid.count] = np.stack([texel[:, 0], texel[:, 1], member, np.zeros_like(member)], axis=1)
            self.place = self.own(ctx.texture(self.size, 4, place.tobytes(), dtype="i4"))
            self.place.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self.view_texture = float_texture(self, ctx, self.size, compact_image(self.size, np.zeros((0, 4))))
            self.view_framebuffer = self.own(ctx.framebuffer(color_attachments=[self.view_texture]))
            bx, by, bz = block
            self.unblock = self.own(Program(ctx, "sim/fullscreen.vert", "sim/unblock.frag",
                                            defines={"BLOCK_X": bx, "BLOCK_Y": by, "BLOCK_Z": bz}))
            self.units = texture_units(self.members)
            self.unblock.set(u_place=self.units["previous"], **{f"u_position{m}": m for m in range(self.members)})
            self.unblock_vao = self.own(ctx.vertex_array(self.unblock.gl, []))

    def bind(self, current: int, previous: int | None = None) -> None:
        """Bind state set ``current`` to units 0.. (and ``previous`` to 8.., the static textures)."""
        for m, tex in enumerate(self.state[current]):
            tex.use(m)
        if previous is not None:
            for m, tex in enumerate(self.state[previous]):
                tex.use(self.units["previous"] + m)
            self.node.use(self.units["node"])
            if self.neighbours is not None:
                self.neighbours.use(self.units["neighbours"])
            if self.weights is not None:
                self.weights.use(self.units["weights"])

    def changed(self) -> None:
        """The state sets were written: the view is stale."""
        self._viewed = None

    def view(self, current: int) -> moderngl.Texture:
        """The compact view of state set ``current`` (one copy pass when it is stale)."""
        if self._viewed != current:
            previous = self.ctx.fbo
            try:
                self.bind(current)
                self.place.use(self.units["previous"])
                self.view_framebuffer.use()
                self.unblock_vao.render(moderngl.TRIANGLES, vertices=3)
            finally:
                restore_framebuffer(self.ctx, previous)
            self._viewed = current
        return self.view_texture

    def read(self, which: int) -> np.ndarray:
        """(N, 4) float32 state texel of every node of set ``which`` (read back member by member)."""
        bw, bh = self.blocks.size
        images = np.stack([np.frombuffer(read_texture(t), "f4").reshape(bh, bw, 4) for t in self.state[which]])
        return self.blocks.gather(self.grid.ijk, images)

    @property
    def bytes_allocated(self) -> int:
        """GPU bytes of every texture (padding texels and the view included)."""
        bw, bh = self.blocks.size
        w, h = self.size
        per_set = bw * bh * 16 * self.members
        tables = (0 if self.neighbours is None else bw * bh * 7 * 16) + \
            (0 if self.weights is None else bw * bh * 5 * 16 * self.members)
        return per_set * (1 + len(self.state)) + tables + w * h * 32

    def release(self) -> None:
        """Release every texture, framebuffer and the view's program (idempotent)."""
        super().release()
        self.framebuffers, self.state = [], []


class BlockedVerletPass(GLOwner):
    """The position-Verlet fragment pass of a block per fragment (``shaders/sim/verlet_block.frag``):
    one program, one draw over the block texture per step; the run signature of
    :class:`~deformgl.sim.backends.verlet_pass.VerletPass`.

    Args:
        ctx: GL context.
        terms: the pass's uniforms (:class:`~deformgl.sim.backends.verlet_data.VerletTerms`;
            :func:`blocked_refusal` None).
        textures: the blocked textures it reads and writes.
        weight_levels: the node data's alpha holds the lattice's levels code (else any weights are
            the textures' weight texture).
    """

    def __init__(self, ctx: moderngl.Context, terms, textures: BlockedTextures, *, weight_levels: bool) -> None:
        weighted = weight_levels or textures.weights is not None
        super().__init__(ctx)
        self.n_pulls = terms.n_pulls
        layout = textures.blocks
        with self.building():
            self.program = self.own(Program(ctx, "sim/fullscreen.vert", "sim/verlet_block.frag", defines={
                "PULLS": terms.n_pulls, "SPRING_WEIGHTS": weighted,
                "SPRING_WEIGHT_LEVELS": weight_levels, **layout.shader_defines(),
                **terms.extra.defines()}, chunks=terms.extra.chunks()))
            units = {f"u_position{m}": m for m in range(layout.members)}
            units.update({f"u_previous{m}": textures.units["previous"] + m for m in range(layout.members)})
            # (the layout's uniforms are unused where no neighbour block is read: a single node)
            uniforms = {k: v for k, v in layout.shader_uniforms().items() if k in self.program.members}
            if not layout.dense:
                uniforms["u_block_neighbours"] = textures.units["neighbours"]
            if textures.weights is not None:
                uniforms["u_weights"] = textures.units["weights"]
            self.program.set(**uniforms, **units, u_node=textures.units["node"], u_spacing=terms.spacing,
                             u_k_structural=terms.k_structural, u_k_shear=terms.k_shear, u_damping=terms.damping,
                             u_mass_damping=terms.mass_damping, u_gravity=terms.gravity)
            self.vao = self.own(ctx.vertex_array(self.program.gl, []))
        self._dt: float | None = None

    def run(self, textures: BlockedTextures, current: int, previous: int, target: int, dt: float,
            pull: np.ndarray | None) -> None:
        """Draw one step: read set ``current`` and ``previous``, write set ``target``."""
        if dt != self._dt:
            self.program.set(u_dt=dt)
            self._dt = dt
        self.program.set(**pull_uniforms(pull, self.n_pulls, "BlockedVerletPass.run"))
        textures.bind(current, previous)
        textures.framebuffers[target].use()
        self.vao.render(moderngl.TRIANGLES, vertices=3)
        textures.changed()
