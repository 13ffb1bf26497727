"""The node grid: which nodes exist, their 18 implicit neighbours, and the compact texture layout.

Mosegaard & Sørensen 2005, section 3.1: particles on a regular 3D grid, each connected to the
18 nearest neighbours that exist: 6 at distance h (set D1) and 12 at distance h*sqrt(2) (set D2).

All model data here is immutable: a :class:`NodeGrid` is built once from a voxelization and never
changes; per-node arrays are in node order (C order of ``np.nonzero(occupied)``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:
    from deformgl.grid.fill import CellFill

#: The 18 neighbour offsets: first the 6 at distance 1 (D1), then the 12 at sqrt(2) (D2).
#: Bit j of a node's neighbour mask is set when the neighbour at NEIGHBOUR_OFFSETS[j] exists.
#: ``shaders/lib/springs.glsl`` unrolls the same offsets in the same order.
NEIGHBOUR_OFFSETS = np.array(
    [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1),
     (1, 1, 0), (1, -1, 0), (-1, 1, 0), (-1, -1, 0),
     (1, 0, 1), (1, 0, -1), (-1, 0, 1), (-1, 0, -1),
     (0, 1, 1), (0, 1, -1), (0, -1, 1), (0, -1, -1)], dtype=np.int64)
N_STRUCTURAL = 6
#: Texture unit of the compact layout's neighbour-index texture.
NEIGHBOUR_UNIT = 3
N_NEIGHBOURS = 18
#: Rest length of each neighbour's spring, in grid spacings (Mosegaard & Sørensen 2005, eq. 2: 1 and sqrt(2)).
REST_LENGTH_UNITS = np.linalg.norm(NEIGHBOUR_OFFSETS, axis=1)


def node_strides(shape: tuple[int, int, int]) -> tuple[int, int, int]:
    """Node-number step of a +1 move along x, y, z on a full grid of ``shape`` (nx, ny, nz)."""
    _, ny, nz = shape
    return ny * nz, nz, 1


@dataclass(frozen=True, eq=False)
class NodeGrid:
    """A regular grid of nodes, some of which exist.

    Attributes:
        origin: (3,) float64, world position of grid index (0, 0, 0).
        spacing: grid spacing h in world units.
        occupied: (nx, ny, nz) bool, True where a node exists.
        fill: the mesh's material in the cells (:class:`~deformgl.grid.fill.CellFill`, cells of
            this grid), or None: every cell whose 8 corners exist is full.
    """

    origin: np.ndarray
    spacing: float
    occupied: np.ndarray
    fill: CellFill | None = None

    def __post_init__(self) -> None:
        self.origin.setflags(write=False)
        self.occupied.setflags(write=False)
        if self.fill is not None and self.fill.cells != tuple(max(n - 1, 0) for n in self.occupied.shape):
            raise ValueError(f"NodeGrid: the fill's cells {self.fill.cells} are not those of a grid of "
                             f"{self.occupied.shape} nodes")

    @property
    def shape(self) -> tuple[int, int, int]:
        """Grid dimensions (nx, ny, nz), including empty positions."""
        return tuple(int(n) for n in self.occupied.shape)  # type: ignore[return-value]

    @property
    def index_dtype(self) -> type:
        """Integer type of node numbers and grid indices: int32 while the grid's box has fewer
        than 2**31 positions (every grid :func:`~deformgl.grid.voxelize.voxelize` or a cloth of
        up to 16384**2 builds), else int64. Half the bytes of the per-node index arrays."""
        return np.int32 if self.occupied.size < 2**31 else np.int64

    @cached_property
    def ijk(self) -> np.ndarray:
        """(N, 3) grid index of each existing node, in node order (:attr:`index_dtype`)."""
        ijk = np.argwhere(self.occupied)
        return ijk.astype(self.index_dtype, copy=False)

    @property
    def count(self) -> int:
        """Number of existing nodes N."""
        return int(self.ijk.shape[0])

    @property
    def full(self) -> bool:
        """Every node of the box exists (blocks, cloth sheets): node (i, j, k) is then node number
        ``i ny nz + j nz + k`` (``np.argwhere`` order), see :func:`node_strides`."""
        return self.count == self.occupied.size

    @cached_property
    def index(self) -> np.ndarray:
        """(nx, ny, nz) node number at each grid position, -1 where no node exists
        (:attr:`index_dtype`)."""
        dtype = self.index_dtype
        idx: np.ndarray = np.full(self.shape, -1, dtype=dtype)
        idx[self.occupied] = np.arange(self.count, dtype=dtype)
        return idx

    @cached_property
    def rest_positions(self) -> np.ndarray:
        """(N, 3) float64 world positions of the nodes at rest."""
        return self.origin + self.spacing * self.ijk.astype(np.float64)

    @cached_property
    def neighbours(self) -> np.ndarray:
        """(N, 18) node number of each neighbour in NEIGHBOUR_OFFSETS order, -1 if absent
        (:attr:`index_dtype`)."""
        padded = np.pad(self.index, 1, constant_values=-1)
        base = self.ijk + 1
        out: np.ndarray = np.empty((self.count, N_NEIGHBOURS), dtype=self.index_dtype)
        offsets = NEIGHBOUR_OFFSETS.astype(base.dtype)
        for j, off in enumerate(offsets):
            q = base + off
            out[:, j] = padded[q[:, 0], q[:, 1], q[:, 2]]
        return out

    @cached_property
    def neighbour_mask(self) -> np.ndarray:
        """(N,) uint32: bit j set when neighbour j exists (18 bits, exact in a float32)."""
        bits = (self.neighbours >= 0).astype(np.uint32) << np.arange(N_NEIGHBOURS, dtype=np.uint32)
        return np.bitwise_or.reduce(bits, axis=1).astype(np.uint32)

    @cached_property
    def springs(self) -> np.ndarray:
        """(S, 2) int64 node pairs (a < b), each spring once; structural springs first."""
        pairs = []
        own: np.ndarray = np.arange(self.count, dtype=self.index_dtype)
        for j in range(N_NEIGHBOURS):
            nb = self.neighbours[:, j]
            a = np.nonzero(nb > own)[0]
            pairs.append(np.stack([a, nb[a].astype(np.int64)], axis=1))
        return np.concatenate(pairs, axis=0)

    def bbox_fraction(self, points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Points expressed as fractions of the box [lo, hi] (0 at lo, 1 at hi; flat axes give 0)."""
        extent = np.where(hi - lo > 0, hi - lo, 1.0)
        return (points - lo) / extent


class _TexelLayout(Protocol):
    """What :class:`TexelImages` needs of the layout class it is mixed into."""

    @property
    def size(self) -> tuple[int, int]: ...

    def texel(self, ijk: np.ndarray) -> np.ndarray: ...


class TexelImages:
    """Mixin moving per-node values between node order and texture images; the layout class
    provides ``size`` (width, height) and ``texel(ijk)``."""

    def scatter(self: _TexelLayout, ijk: np.ndarray, values: np.ndarray, fill: float = 0.0) -> np.ndarray:
        """Place per-node ``values`` (N, C) into a (height, width, C) float32 texture image."""
        w, h = self.size
        img = np.full((h, w, values.shape[1]), fill, dtype=np.float32)
        t = self.texel(ijk)
        img[t[:, 1], t[:, 0]] = values
        return img

    def gather(self: _TexelLayout, ijk: np.ndarray, image: np.ndarray) -> np.ndarray:
        """Read per-node values (N, C) back out of a (height, width, C) texture image."""
        t = self.texel(ijk)
        return image[t[:, 1], t[:, 0]]


def texture_width(count: int, max_size: int, what: str) -> int:
    """A near-square texture's width for ``count`` texels, a power of two (at least 16, at most
    ``max_size``).

    Raises:
        ValueError: ``count`` texels (``what``, e.g. "1000 nodes") need more than a ``max_size`` x
            ``max_size`` texture.
    """
    n = max(count, 1)
    width = 1 << max(4, int(np.ceil(np.log2(np.sqrt(n)))))
    width = min(width, 1 << int(np.floor(np.log2(max_size))))
    if -(-n // width) > max_size:
        raise ValueError(f"{what} need more than {max_size}x{max_size} texels (the GL texture limit)")
    return width


def layout_uniforms(width: int, *, prefix: str = "u_") -> dict[str, int]:
    """The uniforms of ``shaders/lib/node_texel.glsl`` (the node layout every pass reads node state
    through) for a node texture ``width`` nodes wide: ``u_width_log2``. ``prefix`` names another
    texture's width (``"u_src_"``: ``u_src_width_log2``, the multigrid level a pass reads from).

    Raises:
        ValueError: ``width`` is not a power of two.
    """
    width = int(width)
    if width < 1 or width & (width - 1):
        raise ValueError(f"layout_uniforms: a node texture {width} texels wide; the layout needs a power of two")
    return {f"{prefix}width_log2": width.bit_length() - 1}


def node_texels(numbers: np.ndarray, width: int) -> np.ndarray:
    """(N, 2) int64 texel of node (or block) ``numbers`` in a texture ``width`` texels wide: the
    host side of ``shaders/lib/node_texel.glsl`` ``node_texel``, ``(n % width, n // width)``."""
    numbers = np.asarray(numbers)
    return np.stack([numbers % width, numbers // width], axis=-1)


@dataclass(frozen=True, eq=False)
class CompactLayout(TexelImages):
    """Existing nodes packed densely in node order: node n is texel (n % width, n // width).

    Only existing nodes occupy texels (the last row may be partly empty), so a pass costs work
    for existing nodes only and the working set stays small; the 18 neighbours of each node are
    looked up in a neighbour-index texture (5 RGBA32I layers, an absent neighbour points at the
    node itself and is weighted 0), or on :attr:`dense` grids computed. ``width`` is a power of
    two.
    """

    index: np.ndarray  # (nx, ny, nz) node number, -1 where absent (NodeGrid.index)
    count: int
    width: int
    arithmetic: bool = True  # False: the index texture even on dense grids (the tests and studies that compare them)

    @classmethod
    def for_grid(cls, grid: NodeGrid, max_size: int, *, arithmetic: bool = True) -> "CompactLayout":
        """A near-square power-of-two-wide layout for ``grid`` (``arithmetic``: see :attr:`dense`).

        Raises:
            ValueError: more nodes than a ``max_size`` x ``max_size`` texture holds.
        """
        return cls(grid.index, grid.count, texture_width(grid.count, max_size, f"{grid.count} nodes"), arithmetic)

    @property
    def size(self) -> tuple[int, int]:
        """Texture (width, height) in texels."""
        return self.width, max(1, -(-self.count // self.width))

    @property
    def dense(self) -> bool:
        """Every node of the grid's box exists (blocks, cloth sheets): node n's neighbour at offset
        (dx, dy, dz) is node ``n + dx ny nz + dy nz + dz`` (``np.argwhere`` order), so no
        neighbour-index texture is needed (unless built with ``arithmetic=False``)."""
        return self.arithmetic and self.count == self.index.size

    @property
    def strides(self) -> tuple[int, int, int]:
        """Node-number step of a +1 move along x, y, z (dense grids)."""
        return node_strides(self.index.shape)

    def shader_defines(self) -> dict[str, object]:
        """Defines selecting this layout in ``shaders/lib/springs.glsl``: COMPACT, and
        COMPACT_DENSE when neighbours are found by arithmetic (:attr:`dense`)."""
        return {"COMPACT": True, "COMPACT_DENSE": self.dense}

    def shader_uniforms(self) -> dict[str, object]:
        """Uniforms of the COMPACT variant (the neighbour texture is bound to unit 3), or of
        COMPACT_DENSE (node-number strides)."""
        if self.dense:
            return {**layout_uniforms(self.width), "u_strides": self.strides}
        return {**layout_uniforms(self.width), "u_neighbours": NEIGHBOUR_UNIT}

    def node_texel(self, nodes: np.ndarray) -> np.ndarray:
        """(N, 2) int64 texel of node numbers."""
        return node_texels(nodes, self.width)

    def texel(self, ijk: np.ndarray) -> np.ndarray:
        """(N, 2) int64 texel of existing nodes at grid indices ``ijk`` (N, 3)."""
        ijk = np.asarray(ijk)
        return self.node_texel(self.index[ijk[:, 0], ijk[:, 1], ijk[:, 2]])


    def neighbour_layers(self, neighbours: np.ndarray) -> np.ndarray:
        """(5, height, width, 4) int32 neighbour node numbers, absent ones replaced by the node."""
        n = len(neighbours)
        own = np.arange(n, dtype=neighbours.dtype)[:, None]  # (int32 on NodeGrid: half the bytes)
        nb = np.where(neighbours >= 0, neighbours, own)
        nb = np.concatenate([nb, np.repeat(own, 20 - nb.shape[1], axis=1)], axis=1)  # (N, 20)
        w, h = self.size
        out = np.zeros((5, h * w, 4), dtype=np.int32)
        out[:, :n, :] = nb.reshape(n, 5, 4).transpose(1, 0, 2)
        return out.reshape(5, h, w, 4)
