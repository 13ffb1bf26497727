"""The blocked node layout: several nodes per fragment (issue 30).

The grid's box is cut into blocks of ``bx x by x bz`` grid positions. Every block that holds at
least one node is one texel (block b at ``(b % width, b // width)``, as nodes in
:class:`~deformgl.grid.nodes.CompactLayout`), and member m of a block (block-local position
``(lx, ly, lz)``, ``m = (lx by + ly) bz + lz``, C order as node numbers) is that texel of the
state's texture m: a pass that owns a block fetches the block's union neighbourhood once and
writes its members' new positions through one render target each (multiple render targets).
Neighbouring nodes share most of their 18 neighbours (Mosegaard & Sørensen 2005, section 3.1),
so a 1x2x2 block fetches 40 positions for 4 nodes instead of 4 x 19.

Where every block of the box holds a node (:attr:`BlockedLayout.dense`: blocks, cloth sheets) a
neighbour block's number is computed from block strides; otherwise a block-neighbour table (the
block numbers of the 18 blocks at :data:`~deformgl.grid.nodes.NEIGHBOUR_OFFSETS` and the 8 at the
corners, the block itself where absent, 7 RGBA32I layers) holds them. A member without a node (a block on the
boundary of a shape, or past the end of a box whose sides the block does not divide) has no
flag bits in the node texture and keeps its texel unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from deformgl.grid.nodes import NEIGHBOUR_OFFSETS, NodeGrid, layout_uniforms, node_strides, node_texels, texture_width

__all__ = ["BLOCK_SHAPES", "CORNER_OFFSETS", "BlockedLayout", "parse_block"]

#: The 8 corner offsets (2 qx - 1, 2 qy - 1, 2 qz - 1), q = qx + 2 qy + 4 qz: slots 18-25 of the
#: block-neighbour table (``shaders/sim/verlet_block.frag`` offset_slot).
CORNER_OFFSETS = np.array([(2 * (q & 1) - 1, 2 * ((q >> 1) & 1) - 1, 2 * ((q >> 2) & 1) - 1) for q in range(8)],
                          dtype=np.int64)

#: The block shapes the passes are built for (x, y, z nodes): at most 8 members, one render target
#: each (GL_MAX_DRAW_BUFFERS is 8 on llvmpipe, WebGL2 guarantees 4).
BLOCK_SHAPES = ((1, 1, 1), (1, 1, 2), (1, 2, 1), (2, 1, 1), (1, 2, 2), (2, 1, 2), (2, 2, 1),
                (1, 1, 4), (1, 4, 1), (4, 1, 1), (2, 2, 2))


def parse_block(text: str) -> tuple[int, int, int]:
    """A block shape from ``"1x2x2"`` (x, y, z), or a ValueError naming the shapes there are."""
    try:
        shape = tuple(int(v) for v in text.lower().split("x"))
    except ValueError:
        shape = ()
    if shape not in BLOCK_SHAPES:
        names = ", ".join("x".join(map(str, s)) for s in BLOCK_SHAPES)
        raise ValueError(f"block {text!r} is not one of {names}")
    return shape


def _block_shape(shape: tuple[int, ...], block: tuple[int, ...]) -> tuple[int, int, int]:
    """Blocks along x, y, z of a box of ``shape`` nodes."""
    return tuple(-(-int(n) // b) for n, b in zip(shape, block))  # type: ignore[return-value]


def _block_numbers(index: np.ndarray, block: tuple[int, ...]) -> np.ndarray:
    """(Bx, By, Bz) int64 number of each block holding a node of ``index`` (C order), else -1."""
    occupied = np.zeros(_block_shape(index.shape, block), bool)
    occupied[tuple((np.argwhere(index >= 0) // np.array(block)).T)] = True
    out = np.full(occupied.shape, -1, np.int64)
    out[occupied] = np.arange(int(occupied.sum()))
    return out


@dataclass(frozen=True, eq=False)
class BlockedLayout:
    """Blocks of ``block`` (x, y, z) grid positions, one texel each, one texture per member.

    Attributes:
        index: (nx, ny, nz) node number, -1 where absent (:attr:`NodeGrid.index`).
        block: (bx, by, bz) grid positions per block.
        width: texture width in blocks (a power of two).
        arithmetic: False: the block-neighbour table even where every block exists (to measure it).
    """

    index: np.ndarray
    block: tuple[int, int, int]
    width: int
    arithmetic: bool = True

    @classmethod
    def for_grid(cls, grid: NodeGrid, block: tuple[int, int, int], max_size: int, *,
                 arithmetic: bool = True) -> "BlockedLayout":
        """A near-square power-of-two-wide layout of ``grid`` in blocks of ``block``.

        Raises:
            ValueError: a block shape not in :data:`BLOCK_SHAPES`; more blocks than a
                ``max_size`` x ``max_size`` texture holds.
        """
        block = tuple(int(b) for b in block)  # type: ignore[assignment]
        if block not in BLOCK_SHAPES:
            raise ValueError(f"BlockedLayout: block {block} is not one of {BLOCK_SHAPES}")
        n = int((_block_numbers(grid.index, block) >= 0).sum())
        return cls(grid.index, block, texture_width(n, max_size, f"{n} blocks of {'x'.join(map(str, block))} nodes"),
                   arithmetic)

    @property
    def members(self) -> int:
        """Nodes per block (render targets of a pass that writes one value per node)."""
        bx, by, bz = self.block
        return bx * by * bz

    @property
    def block_grid(self) -> tuple[int, int, int]:
        """Blocks along x, y, z of the grid's box."""
        return _block_shape(self.index.shape, self.block)

    @cached_property
    def block_index(self) -> np.ndarray:
        """(Bx, By, Bz) int64 block number, -1 where a block holds no node."""
        return _block_numbers(self.index, self.block)

    @property
    def count(self) -> int:
        """Number of blocks stored (texels in use per texture)."""
        return int((self.block_index >= 0).sum())

    @property
    def size(self) -> tuple[int, int]:
        """Texture (width, height) in texels (blocks)."""
        return self.width, max(1, -(-self.count // self.width))

    @property
    def dense(self) -> bool:
        """Every block of the box holds a node: a neighbour block is found by block strides."""
        return self.arithmetic and self.count == int(np.prod(self.block_grid))

    @property
    def strides(self) -> tuple[int, int, int]:
        """Block-number step of a +1 block move along x, y, z (:attr:`dense` layouts)."""
        return node_strides(self.block_grid)

    def shader_defines(self) -> dict[str, object]:
        """Defines of ``shaders/lib/node_texel.glsl``'s BLOCKED variant: the block shape,
        BLOCKED_DENSE where neighbour blocks are computed, BLOCK_FLAT_X/Y/Z along an axis the grid
        is one node thick (``shaders/sim/verlet_block.frag``)."""
        bx, by, bz = self.block
        flat = {f"BLOCK_FLAT_{a}": n == 1 for a, n in zip("XYZ", self.index.shape)}
        return {"BLOCKED": True, "BLOCK_X": bx, "BLOCK_Y": by, "BLOCK_Z": bz, "BLOCKED_DENSE": self.dense, **flat}

    def shader_uniforms(self) -> dict[str, object]:
        """Uniforms of the BLOCKED variant: the texture width, and on :attr:`dense` layouts the
        block strides (else the pass binds the block-neighbour table, ``u_block_neighbours``)."""
        uniforms: dict[str, object] = {**layout_uniforms(self.width)}
        if self.dense:
            uniforms["u_block_strides"] = self.strides
        return uniforms

    def place(self, ijk: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(member (N,), texel (N, 2)) int64 of the nodes at grid indices ``ijk`` (N, 3)."""
        ijk = np.asarray(ijk, np.int64)
        b = np.array(self.block)
        blocks = self.block_index[tuple((ijk // b).T)]
        local = ijk % b
        member = (local[:, 0] * b[1] + local[:, 1]) * b[2] + local[:, 2]
        return member, node_texels(blocks, self.width)

    def scatter(self, ijk: np.ndarray, values: np.ndarray, fill: float = 0.0) -> np.ndarray:
        """Per-node ``values`` (N, C) as (members, height, width, C) float32 images."""
        w, h = self.size
        images = np.full((self.members, h, w, values.shape[1]), fill, dtype=np.float32)
        member, t = self.place(ijk)
        images[member, t[:, 1], t[:, 0]] = values
        return images

    def gather(self, ijk: np.ndarray, images: np.ndarray) -> np.ndarray:
        """Per-node values (N, C) out of (members, height, width, C) images."""
        member, t = self.place(ijk)
        return images[member, t[:, 1], t[:, 0]]

    def neighbour_layers(self) -> np.ndarray:
        """(7, height, width, 4) int32: the block numbers of each block's 26 neighbour blocks, the 18
        at :data:`NEIGHBOUR_OFFSETS` (slots 0-17, what springs reach) then the 8 at
        :data:`CORNER_OFFSETS` (slots 18-25, body diagonals of the cell term), the block itself where
        absent or outside the box."""
        blocks = self.block_index
        bijk = np.argwhere(blocks >= 0)
        own = blocks[tuple(bijk.T)]
        padded = np.pad(blocks, 1, constant_values=-1)
        cols = [padded[tuple((bijk + 1 + off).T)] for off in np.concatenate([NEIGHBOUR_OFFSETS, CORNER_OFFSETS])]
        nb = np.stack(cols, axis=1)
        nb = np.where(nb >= 0, nb, own[:, None])
        nb = np.concatenate([nb, np.repeat(own[:, None], 2, axis=1)], axis=1)  # (blocks, 28)
        order = np.argsort(own)
        w, h = self.size
        out = np.zeros((7, h * w, 4), dtype=np.int32)
        out[:, : len(own), :] = nb[order].reshape(len(own), 7, 4).transpose(1, 0, 2)
        return out.reshape(7, h, w, 4)
