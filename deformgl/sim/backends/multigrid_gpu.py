"""The multigrid V-cycle of the implicit step on the GPU: the coarse levels' textures and passes
(``shaders/sim/implicit/multigrid.frag``), the twin of :class:`deformgl.sim.multigrid.Hierarchy`.

The hierarchy (its prolongations, Galerkin coarse operators and dampings) is built on the CPU in
float64 from the start state's step matrix (:func:`deformgl.sim.implicit.assemble`) and uploaded
once, in float32; every step's cycle smooths the finest level with that step's own matrix-free A
and block inverse (``implicit.frag``'s MG_SMOOTH and MG_RESIDUAL, drawn by the owner's
``fine_pass``). Nothing is read back: the cycle is a fixed sequence of passes.

GPU textures per coarse level l (a compact node layout of its own: node n at texel
``(n % w, n / w)``, RGBA32F unless said):

* static: the stencil's neighbours (RGBA32I array, 7 layers: the (at most :data:`MAX_STENCIL`)
  block columns of the node's row of A_l, -1 past the row's end), the stencil (81 layers: row r
  of block j is layer 3 j + r, xyz), the smoother W = w D^-1 (3 layers, its rows), the restriction's sources
  (RGBA32I array, 7 layers: the at most 27 finer nodes, -1 past them) and weights (7 layers),
  and at the finer level's layout its prolongation's sources and weights (2 layers each: at most
  8 coarser nodes); the coarsest level instead holds its dense inverse, a (F, 3F) texture
  (texel (j, 3 i + r): row 3 i + r of A^-1 at columns 3 j .. 3 j + 2);
* per cycle: the level's right-hand side, its x (two, ping-pong) and its residual (xyz).
The finest level's x (two) and residual are the owner's layout.
"""

from __future__ import annotations

from collections.abc import Callable

import moderngl
import numpy as np
import scipy.sparse as sp

from deformgl.errors import GLError
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner
from deformgl.grid.nodes import layout_uniforms
from deformgl.sim.backends.compact_textures import compact_image, float_texture, layer_texture
from deformgl.sim.multigrid import SWEEPS, Hierarchy, diagonal_blocks

__all__ = ["GpuMultigrid", "MAX_STENCIL", "level_width"]

#: The most blocks a coarse operator's row may hold (``STENCIL_COUNT`` of multigrid.frag): the
#: 3x3x3 stencil of a body of the 18-neighbour lattice (with its terms), the 5x5 of a sheet with
#: flexion springs or terms that read the flexion neighbours; a 3D body with flexion springs (a
#: 5x5x5 coarse stencil) is refused.
MAX_STENCIL = 27
_UNITS = {"u_stencil_nb": 0, "u_stencil": 1, "u_rhs": 2, "u_vec": 3, "u_smoother": 4, "u_src": 5,
          "u_transfer_nb": 6, "u_transfer_w": 7, "u_inverse": 8, "u_r": 9, "u_z": 10}
#: ``fine_pass(name, rhs, x, out)``: the owner draws ``implicit.frag``'s pass ``name``
#: ("MG_SMOOTH_ZERO", "MG_SMOOTH", "MG_RESIDUAL") on the finest level.
FinePass = Callable[[str, moderngl.Texture, moderngl.Texture | None, moderngl.Texture], None]


def level_width(count: int, max_size: int) -> int:
    """The power-of-two texture width of a level of ``count`` nodes (as
    :meth:`~deformgl.grid.nodes.CompactLayout.for_grid`)."""
    width = 1 << max(4, int(np.ceil(np.log2(np.sqrt(max(count, 1))))))
    return min(width, 1 << int(np.floor(np.log2(max_size))))


def _rows(m: sp.csr_matrix, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(R, width) column indices (-1 past a row's end) and values of a CSR matrix's rows."""
    m = m.tocsr()
    m.sort_indices()
    counts = np.diff(m.indptr)
    rows = np.repeat(np.arange(m.shape[0]), counts)
    slot = np.arange(m.nnz) - m.indptr[rows]
    idx = np.full((m.shape[0], width), -1, np.int64)
    val = np.zeros((m.shape[0], width))
    idx[rows, slot] = m.indices
    val[rows, slot] = m.data
    return idx, val


class GpuMultigrid:
    """The coarse levels of a :class:`~deformgl.sim.multigrid.Hierarchy` on the GPU, owned by
    ``owner`` (the implicit backend; released with it).

    Args:
        owner, ctx: the GL owner of every texture and program, and its context.
        hierarchy: the float64 hierarchy (built from the start state's step matrix).
        free: (N,) bool, the finest level's free nodes (the hierarchy's rows, in node order).
        fine_width: the finest level's texture width (the owner's compact layout).
        max_size: GL_MAX_TEXTURE_SIZE.
        fbo: the owner's framebuffer of a set of targets (made once, kept: ``fbo(*textures)``).
    """

    def __init__(self, owner: GLOwner, ctx: moderngl.Context, hierarchy: Hierarchy, free: np.ndarray,
                 fine_width: int, max_size: int,
                 fbo: Callable[..., moderngl.Framebuffer]) -> None:
        self.owner, self.ctx, self._fbo = owner, ctx, fbo
        if hierarchy.depth < 2:
            raise ValueError("cg_preconditioner 'multigrid' needs a grid of at least 3 nodes along some axis "
                             "(it has no coarser level); use 'block-jacobi'")
        self.omega = hierarchy.levels[0].omega
        self.fine_count, self.fine_width = len(free), fine_width
        rows_to_nodes = np.nonzero(free)[0]
        self.levels: list[dict] = []
        widths = [fine_width]
        for level in hierarchy.levels[1:]:
            count = level.matrix.shape[0] // 3
            widths.append(level_width(count, max_size))
            if -(-count // widths[-1]) > max_size:
                raise GLError(f"multigrid: a coarse level of {count} nodes does not fit a texture")
        self._programs: dict[tuple, Program] = {}
        self._vaos: dict[tuple, moderngl.VertexArray] = {}
        self.bytes_allocated = 0
        finer_nodes = rows_to_nodes  # the finer level's node numbers of the prolongation's rows
        finer_count = self.fine_count
        for l, level in enumerate(hierarchy.levels[1:], start=1):
            assert level.prolong is not None
            count = level.matrix.shape[0] // 3
            width = widths[l]
            size = (width, max(1, -(-count // width)))
            node_p = level.prolong[0::3, 0::3].tocsr()  # the node weights (P kron I3)
            entry: dict = {"count": count, "width": width, "size": size}
            # restriction: coarse node c <- the finer nodes of column c of P
            r_idx, r_w = _rows(node_p.T.tocsr(), 28)
            r_idx = np.where(r_idx >= 0, finer_nodes[np.maximum(r_idx, 0)], -1)
            entry["restrict"] = (self._table(size, r_idx, "i4"), self._table(size, r_w, "f4"))
            # prolongation: the finer level's nodes <- their coarse nodes (rows of P), at its layout
            p_idx, p_w = _rows(node_p, 8)
            full_idx = np.full((finer_count, 8), -1, np.int64)
            full_w = np.zeros((finer_count, 8))
            full_idx[finer_nodes], full_w[finer_nodes] = p_idx, p_w
            finer_size = (widths[l - 1], max(1, -(-finer_count // widths[l - 1])))
            entry["prolong"] = (self._table(finer_size, full_idx, "i4"), self._table(finer_size, full_w, "f4"))
            if l < len(hierarchy.levels) - 1:
                bsr = level.matrix.tobsr(blocksize=(3, 3))
                width_s = int(np.max(np.diff(bsr.indptr))) if count else 1
                if width_s > MAX_STENCIL:
                    raise ValueError(f"multigrid: a coarse operator holds {width_s} blocks per node (more than "
                                  f"{MAX_STENCIL}: a 3D body with flexion springs); use 'block-jacobi'")
                block_rows = np.repeat(np.arange(count), np.diff(bsr.indptr))
                slot = np.arange(bsr.nnz // 9) - bsr.indptr[block_rows]
                nb = np.full((count, 28), -1, np.int64)
                nb[block_rows, slot] = bsr.indices
                stencil = np.zeros((count, MAX_STENCIL, 3, 4))
                stencil[block_rows, slot, :, :3] = bsr.data
                smooth = level.omega * np.linalg.inv(diagonal_blocks(level.matrix))
                entry["stencil_nb"] = self._table(size, nb, "i4")
                entry["stencil"] = self._table(size, stencil.reshape(count, -1), "f4")
                entry["smoother"] = self._table(size, np.pad(smooth, ((0, 0), (0, 0), (0, 1))).reshape(count, -1), "f4")
            else:
                img = np.zeros((3 * count, count, 4), np.float32)  # (rows 3i + r, columns j)
                img[:, :, :3] = hierarchy.coarse_inverse.reshape(3 * count, count, 3)
                entry["inverse"] = float_texture(owner, ctx, (count, 3 * count), img)
                self.bytes_allocated += img.nbytes
            for name in ("rhs", "x", "x_out", "res"):
                entry[name] = float_texture(owner, ctx, size, compact_image(size, np.zeros((count, 3))))
            self.bytes_allocated += 16 * 4 * size[0] * size[1]
            self.levels.append(entry)
            finer_nodes, finer_count = np.arange(count), count

    def _table(self, size: tuple[int, int], table: np.ndarray, dtype: str) -> moderngl.TextureArray:
        self.bytes_allocated += 16 * size[0] * size[1] * -(-table.shape[1] // 4)
        return layer_texture(self.owner, self.ctx, size, table.astype(np.int32 if dtype == "i4" else np.float32), dtype)

    @property
    def depth(self) -> int:
        """Levels, the finest included."""
        return len(self.levels) + 1

    def _program(self, name: str, **defines: object) -> tuple[Program, moderngl.VertexArray]:
        key = (name, *sorted(defines.items()))
        if key not in self._programs:
            program = self.owner.own(Program(self.ctx, "sim/fullscreen.vert", "sim/implicit/multigrid.frag",
                                             defines={name: True, **defines}))
            program.set(**{k: v for k, v in _UNITS.items() if k in program.members})
            self._programs[key] = program
            self._vaos[key] = self.owner.own(self.ctx.vertex_array(program.gl, []))
        return self._programs[key], self._vaos[key]

    def _draw(self, name: str, uniforms: dict[str, object], reads: dict[str, object],
              *targets: moderngl.Texture, **defines: object) -> None:
        program, vao = self._program(name, **defines)
        program.set(**{k: v for k, v in uniforms.items() if k in program.members})
        for sampler, tex in reads.items():
            tex.use(_UNITS[sampler])  # type: ignore[attr-defined]
        self._fbo(*targets).use()
        vao.render(moderngl.TRIANGLES, vertices=3)

    def _level_cycle(self, l: int) -> None:
        """The cycle on coarse level ``l`` (1-based) from its ``rhs``: its result in ``x``."""
        lv = self.levels[l - 1]
        base = {"u_count": lv["count"], **layout_uniforms(lv["width"])}
        if "inverse" in lv:
            self._draw("COARSEST", base, {"u_rhs": lv["rhs"], "u_inverse": lv["inverse"]}, lv["x"])
            return
        stencil = {"u_stencil_nb": lv["stencil_nb"], "u_stencil": lv["stencil"], "u_rhs": lv["rhs"]}
        self._draw("LEVEL_SMOOTH", base, {**stencil, "u_smoother": lv["smoother"]}, lv["x"], FROM_ZERO=True)
        for _ in range(SWEEPS - 1):
            self._smooth(lv, base, stencil)
        self._draw("LEVEL_RESIDUAL", base, {**stencil, "u_vec": lv["x"]}, lv["res"])
        self._descend(l, lv["res"], lv["width"])
        below = self.levels[l]
        self._draw("PROLONG", {**base, **layout_uniforms(below["width"], prefix="u_src_")},
                   {"u_vec": lv["x"], "u_src": below["x"], "u_transfer_nb": below["prolong"][0],
                    "u_transfer_w": below["prolong"][1]}, lv["x_out"])
        lv["x"], lv["x_out"] = lv["x_out"], lv["x"]
        for _ in range(SWEEPS):
            self._smooth(lv, base, stencil)

    def _smooth(self, lv: dict, base: dict, stencil: dict) -> None:
        self._draw("LEVEL_SMOOTH", base, {**stencil, "u_vec": lv["x"], "u_smoother": lv["smoother"]}, lv["x_out"])
        lv["x"], lv["x_out"] = lv["x_out"], lv["x"]

    def _descend(self, l: int, residual: moderngl.Texture, width: int) -> None:
        """Restrict level ``l``'s residual into level ``l + 1``'s rhs and cycle there."""
        below = self.levels[l]
        self._draw("RESTRICT", {"u_count": below["count"], **layout_uniforms(below["width"]),
                                **layout_uniforms(width, prefix="u_src_")},
                   {"u_src": residual, "u_transfer_nb": below["restrict"][0], "u_transfer_w": below["restrict"][1]},
                   below["rhs"])
        self._level_cycle(l + 1)

    def cycle(self, r: moderngl.Texture, x: moderngl.Texture, x_out: moderngl.Texture, res: moderngl.Texture,
              fine_pass: FinePass) -> moderngl.Texture:
        """``M^-1 r`` on the finest level (``x``, ``x_out`` and ``res`` its scratch textures, at
        the owner's layout); returns the texture that holds it."""
        fine_pass("MG_SMOOTH_ZERO", r, None, x)
        for _ in range(SWEEPS - 1):
            fine_pass("MG_SMOOTH", r, x, x_out)
            x, x_out = x_out, x
        fine_pass("MG_RESIDUAL", r, x, res)
        self._descend(0, res, self.fine_width)
        below = self.levels[0]
        self._draw("PROLONG", {"u_count": self.fine_count, **layout_uniforms(self.fine_width),
                               **layout_uniforms(below["width"], prefix="u_src_")},
                   {"u_vec": x, "u_src": below["x"], "u_transfer_nb": below["prolong"][0],
                    "u_transfer_w": below["prolong"][1]}, x_out)
        x, x_out = x_out, x
        for _ in range(SWEEPS):
            fine_pass("MG_SMOOTH", r, x, x_out)
            x, x_out = x_out, x
        return x

    def rz(self, r: moderngl.Texture, z: moderngl.Texture, prod: moderngl.Texture,
           p: moderngl.Texture | None = None) -> None:
        """Per texel ``r . z`` and ``r . r`` into ``prod``; with ``p``, also ``p = z``."""
        uniforms: dict[str, object] = {"u_count": self.fine_count, **layout_uniforms(self.fine_width)}
        if p is None:
            self._draw("RZ", uniforms, {"u_r": r, "u_z": z}, prod)
        else:
            self._draw("RZ", uniforms, {"u_r": r, "u_z": z}, prod, p, RZ_INIT=True)
