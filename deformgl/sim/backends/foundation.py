"""Grid spring-mass simulation in fragment passes on RGBA32F textures (Mosegaard & Sørensen 2005, 3.1).

Textures (channel layouts are also listed in docs/ARCHITECTURE.md):

* node data, static, RGBA32F (H, W, 4): R mass kg, G flag bits (exists 1, fixed 2, pull g 4<<g),
  B neighbour mask (18 bits), A 0.
* state, three rotating RGBA32F (H, W, 4): xyz position, w packed eq. 3 normal. Position Verlet
  needs the current and previous positions; the pass writes the third, then the roles rotate.

Texels outside the grid (padding, empty nodes) hold position 0 and are never changed.
"""

from __future__ import annotations

from collections.abc import Callable

import moderngl
import numpy as np

from deformgl.errors import GLError
from deformgl.grid.nodes import NEIGHBOUR_UNIT, AtlasLayout, CompactLayout
from deformgl.sim.model import MAX_PULLS, SpringModel
from deformgl.sim.normals import pack_normals
from deformgl.gl.programs import Program
from deformgl.sim.reference import spring_sums

PullSchedule = Callable[[float], np.ndarray]
DRAW_MODES = ("rects", "points", "quad")
LAYOUTS = ("compact", "indexed", "atlas")


def tile_rectangles(layout: AtlasLayout, ijk: np.ndarray) -> np.ndarray:
    """(6 * tiles, 2) triangle corners, in texels, of the rectangle around each tile's nodes."""
    texels = layout.texel(ijk)
    corners = []
    for k in np.unique(ijk[:, 2]):
        t = texels[ijk[:, 2] == k]
        (x0, y0), (x1, y1) = t.min(axis=0), t.max(axis=0) + 1
        corners += [(x0, y0), (x1, y0), (x1, y1), (x0, y0), (x1, y1), (x0, y1)]
    return np.array(corners, dtype=np.float64)


class NodeTextures:
    """The GL textures of a simulation: one static node-data texture and the rotating state.

    Args:
        ctx: GL context.
        model: the spring model.
        n_state: number of state textures (3 for position Verlet).
        layout: "compact" (existing nodes packed densely, neighbours from an index texture, or
            by node-number offsets on dense grids), "indexed" (compact with the index texture
            always, to measure what the offsets save) or "atlas" (z-slices as tiles, neighbours
            by tile arithmetic); see docs/ARCHITECTURE.md.
    """

    def __init__(self, ctx: moderngl.Context, model: SpringModel, n_state: int = 3,
                 layout: str = "compact") -> None:
        if layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
        max_size = int(ctx.info["GL_MAX_TEXTURE_SIZE"])
        grid = model.grid
        try:
            self.layout: AtlasLayout | CompactLayout = (
                CompactLayout.for_grid(grid, max_size, arithmetic=layout == "compact")
                if layout in ("compact", "indexed") else AtlasLayout.for_grid(grid.shape, max_size))
        except ValueError as exc:
            raise GLError(f"{exc}; use a coarser grid") from None
        self.neighbours: moderngl.TextureArray | None = None
        if isinstance(self.layout, CompactLayout) and not self.layout.dense:
            layers = self.layout.neighbour_layers(grid.neighbours)
            w, h = self.layout.size
            self.neighbours = ctx.texture_array((w, h, 5), 4, layers.tobytes(), dtype="i4")
            self.neighbours.filter = (moderngl.NEAREST, moderngl.NEAREST)
        size = self.layout.size
        node = np.stack([model.mass, model.flags(), grid.neighbour_mask, np.zeros(grid.count)], axis=1)
        self.node = self._texture(ctx, self.layout.scatter(grid.ijk, node))
        rest = np.concatenate(
            [grid.rest_positions, pack_normals(spring_sums(model, grid.rest_positions).unit_sum)[:, None]],
            axis=1)
        image = self.layout.scatter(grid.ijk, rest)
        self.state = [self._texture(ctx, image) for _ in range(n_state)]
        self.framebuffers = [ctx.framebuffer(color_attachments=[t]) for t in self.state]
        self.size = size

    @staticmethod
    def _texture(ctx: moderngl.Context, image: np.ndarray) -> moderngl.Texture:
        h, w, c = image.shape
        tex = ctx.texture((w, h), c, data=np.ascontiguousarray(image, dtype="f4").tobytes(), dtype="f4")
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        tex.repeat_x = tex.repeat_y = False
        return tex

    def bind_static(self, node_unit: int) -> None:
        """Bind the node-data texture (and the neighbour-index texture of compact layouts)."""
        self.node.use(node_unit)
        if self.neighbours is not None:
            self.neighbours.use(NEIGHBOUR_UNIT)

    def release(self) -> None:
        """Release every texture and framebuffer."""
        for obj in [*self.framebuffers, *self.state, self.node, self.neighbours]:
            if obj is not None:
                obj.release()
        self.framebuffers, self.state = [], []


class VerletPass:
    """The position-Verlet fragment pass: one program, one draw per step.

    Args:
        ctx: GL context.
        model: spring model (decides the compiled variant: pulls, stiffness groups).
        textures: the textures it reads and writes.
        draw: ``"rects"`` (default) draws, per z-slice tile, the rectangle around its existing
            nodes and skips empty texels inside it with a test; ``"points"`` draws one point per
            existing node (no test, but llvmpipe pays per primitive); ``"quad"`` covers the
            whole atlas, padding included. ``deformgl bench sim`` measures all three.
        branch: test each neighbour's mask bit with a branch instead of weighting by it.
    """

    def __init__(self, ctx: moderngl.Context, model: SpringModel, textures: NodeTextures, *,
                 draw: str = "rects", branch: bool = False) -> None:
        if draw not in DRAW_MODES:
            raise ValueError(f"draw must be one of {DRAW_MODES}, got {draw!r}")
        self.ctx = ctx
        layout = textures.layout
        if isinstance(layout, CompactLayout) and draw == "rects":
            draw = "quad"  # a compact layout is one rectangle of existing nodes already
        self.draw = draw
        self.n_pulls = model.n_pulls
        vert = {"points": "sim/node_points.vert", "rects": "sim/node_rects.vert",
                "quad": "sim/fullscreen.vert"}[draw]
        self.program = Program(ctx, vert, "sim/verlet.frag", defines={
            "NEIGHBOUR_BRANCH": branch, "DRAW_POINTS": draw == "points", "PULLS": model.n_pulls,
            **layout.shader_defines()})
        self.program.set(**layout.shader_uniforms(),
                         u_spacing=model.grid.spacing, u_k_structural=model.k_structural,
                         u_k_shear=model.k_shear, u_damping=model.damping,
                         u_gravity=tuple(model.gravity), u_position=0, u_previous=1, u_node=2)
        self.vbo: moderngl.Buffer | None
        if draw == "points":
            self.program.set(u_target_size=textures.size)
            texels = layout.texel(model.grid.ijk).astype("i4")
            self.vbo = ctx.buffer(texels.tobytes())
            self.vao = ctx.vertex_array(self.program.gl, [(self.vbo, "2i", "in_texel")])
            self.vertices = len(texels)
            self.mode = moderngl.POINTS
        elif draw == "rects" and isinstance(layout, AtlasLayout):  # (compact: "quad", above)
            self.program.set(u_target_size=textures.size)
            corners = tile_rectangles(layout, model.grid.ijk)
            self.vbo = ctx.buffer(corners.astype("f4").tobytes())
            self.vao = ctx.vertex_array(self.program.gl, [(self.vbo, "2f", "in_texel_corner")])
            self.vertices = len(corners)
            self.mode = moderngl.TRIANGLES
        else:
            self.vbo = None
            self.vao = ctx.vertex_array(self.program.gl, [])
            self.vertices = 3
            self.mode = moderngl.TRIANGLES
        self._dt: float | None = None

    def run(self, textures: NodeTextures, current: int, previous: int, target: int, dt: float,
            pull: np.ndarray | None) -> None:
        """Draw one step: read state[current], state[previous], write state[target]."""
        if dt != self._dt:
            self.program.set(u_dt=dt)
            self._dt = dt
        if self.n_pulls:
            if pull is None:
                raise TypeError(f"VerletPass.run: {self.n_pulls} pull group(s) need pull forces")
            forces = [tuple(map(float, f)) for f in pull[: self.n_pulls]]
            # moderngl takes a length-1 uniform array as a plain value
            self.program.set(u_pull_force=forces if self.n_pulls > 1 else forces[0])
        textures.state[current].use(0)
        textures.state[previous].use(1)
        textures.bind_static(2)
        fbo = textures.framebuffers[target]
        fbo.use()
        self.vao.render(self.mode, vertices=self.vertices)

    def release(self) -> None:
        """Release the program, vertex array and buffer."""
        self.vao.release()
        if self.vbo is not None:
            self.vbo.release()
        self.program.release()


class FragmentSimulation:
    """Position-Verlet simulation of a :class:`SpringModel` on the GPU, in fragment passes.

    Nothing is read back to the CPU while stepping; :meth:`positions` and :meth:`normals` read the
    current state once, for tests, checks and export.

    Args:
        ctx: GL context.
        model: the spring model.
        dt: time step (s).
        pull_force: callable ``t -> (MAX_PULLS, 3)`` force per node of each pull group, or None.
        draw, branch: pass variants, see :class:`VerletPass`.
        layout: texture layout, see :class:`NodeTextures`.
    """

    def __init__(self, ctx: moderngl.Context, model: SpringModel, dt: float,
                 pull_force: PullSchedule | None = None, *, draw: str = "rects",
                 branch: bool = False, layout: str = "compact") -> None:
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        self.ctx = ctx
        self.model = model
        self.dt = float(dt)
        self.pull_force = pull_force
        self.textures = NodeTextures(ctx, model, layout=layout)
        try:
            self.verlet = VerletPass(ctx, model, self.textures, draw=draw, branch=branch)
        except BaseException:
            self.textures.release()
            raise
        self.current, self.previous, self.spare = 0, 1, 2
        self.steps_done = 0

    @property
    def time(self) -> float:
        """Simulated time (s)."""
        return self.steps_done * self.dt

    @property
    def position_texture(self) -> moderngl.Texture:
        """The state texture holding the latest positions and packed normals."""
        return self.textures.state[self.current]

    @property
    def count(self) -> int:
        """Nodes simulated."""
        return self.model.grid.count

    def position_slot(self) -> tuple[moderngl.Texture, int, int, int]:
        """(texture, nodes per row, texels per node, slot of the position) of the latest
        positions, for :class:`~deformgl.census.NodeCensus` (compact layout only: node n is
        texel (n % width, n // width); w, the packed normal, is not looked at)."""
        if not isinstance(self.textures.layout, CompactLayout):
            raise ValueError("position_slot: the atlas layout does not store node n at (n % width, n // width)")
        return self.position_texture, self.textures.layout.width, 1, 0

    def step(self, n: int = 1) -> None:
        """Advance n steps on the GPU (no read-back)."""
        no_pull = np.zeros((MAX_PULLS, 3))
        for _ in range(n):
            pull = self.pull_force(self.time) if self.pull_force and self.model.n_pulls else no_pull
            self.verlet.run(self.textures, self.current, self.previous, self.spare, self.dt, pull)
            self.current, self.previous, self.spare = self.spare, self.current, self.previous
            self.steps_done += 1

    def read_state(self, which: int | None = None) -> np.ndarray:
        """(N, 4) float32 texel of every node from a state texture (default: current)."""
        tex = self.textures.state[self.current if which is None else which]
        w, h = self.textures.size
        image = np.frombuffer(tex.read(), dtype="f4").reshape(h, w, 4)
        return self.textures.layout.gather(self.model.grid.ijk, image)

    def positions(self) -> np.ndarray:
        """(N, 3) float32 current node positions (one read-back)."""
        return self.read_state()[:, :3]

    def normals(self) -> np.ndarray:
        """(N,) float32 packed eq. 3 normals stored with the current positions (one read-back)."""
        return self.read_state()[:, 3]

    def release(self) -> None:
        """Release every GL object of the simulation."""
        self.verlet.release()
        self.textures.release()
