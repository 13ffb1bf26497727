"""Nodes driven from outside instead of simulated: positions from a ``.npy`` file (one frame or a
sequence) or an analytic motion (rigid transform, bend, twist), so deformgl's mappings can serve
any other simulator. Positions are uploaded to a state texture (CPU -> GPU, no read-back) and a
pass computes their normals (Mosegaard & Sørensen 2005, eq. 3).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import moderngl
import numpy as np

from deformgl.errors import InputError
from deformgl.inputs import max_mesh_bytes
from deformgl.sim.backends.verlet_data import NodeTextures
from deformgl.grid.nodes import NodeGrid
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner


def load_node_frames(path: Path | str, count: int, offset: np.ndarray) -> np.ndarray:
    """Read node positions from ``path``: (N, 3) or (F, N, 3), in the mesh's own coordinates.

    The ``.npy`` header (shape, dtype) is checked before any data is read, and the data may be
    at most ``DEFORMGL_MAX_MESH_BYTES`` (docs/INPUTS.md).

    Args:
        path: the ``.npy`` file.
        count: N, the number of nodes of the grid.
        offset: (3,) subtracted from every position (the scene's recentring).

    Returns:
        (F, N, 3) float64 frames.

    Raises:
        InputError: no file name, a directory, a missing or unreadable file, not a ``.npy`` file
            (an ``.npz`` archive included), too large, wrong shape or dtype, or a non-finite
            coordinate or one beyond float32 (named by frame and node). One line, starting with the file.
    """
    name = os.fspath(path)
    if not name.strip():
        raise InputError("nodes.file: no file name given (an empty path)")
    file = Path(name)
    if file.is_dir():
        raise InputError(f"{name}: node positions: a directory, not a .npy file")
    try:
        with open(file, "rb") as stream:
            magic = stream.read(6)
            stream.seek(0)
            if magic != b"\x93NUMPY":
                kind = "a .npz archive" if magic[:4] == b"PK\x03\x04" else "not a .npy file"
                raise InputError(f"{name}: node positions must be a .npy array, got {kind}")
            version = np.lib.format.read_magic(stream)
            read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                           else np.lib.format.read_array_header_2_0)
            shape, _, dtype = read_header(stream)
            header_end = stream.tell()
            _check_frames_header(name, shape, dtype, count)
            limit = max_mesh_bytes()
            size = int(np.prod(shape)) * dtype.itemsize
            if size > limit:
                raise InputError(f"{name}: node positions hold {size:,} bytes, more than the limit "
                                 f"of {limit:,} (set DEFORMGL_MAX_MESH_BYTES to raise it)")
            if file.stat().st_size < header_end + size:
                raise InputError(f"{name}: truncated: header declares {shape} {dtype} values "
                                 f"({size:,} bytes), file holds {file.stat().st_size - header_end:,}")
            stream.seek(0)
            data = np.load(stream, allow_pickle=False)
    except InputError:
        raise
    except (OSError, ValueError, EOFError) as exc:
        text = getattr(exc, "strerror", None) or " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(f"{name}: cannot read node positions: {text}") from None
    if data.ndim == 2:
        data = data[None]
    data = data.astype(np.float64)
    bad = ~np.isfinite(data).all(axis=2)
    if bad.any():
        f, n = np.argwhere(bad)[0]
        coords = ", ".join(f"{c:.6g}" for c in data[f, n])
        raise InputError(f"{name}: frame {f}, node {n} has a non-finite coordinate ({coords}); "
                         f"{int(bad.sum())} node positions are bad")
    big = (np.abs(data) > np.finfo(np.float32).max).any(axis=2)  # infinite in the float32 state texture
    if big.any():
        f, n = np.argwhere(big)[0]
        coords = ", ".join(f"{c:.6g}" for c in data[f, n])
        raise InputError(f"{name}: frame {f}, node {n} has a coordinate beyond float32 ({coords}); "
                         f"{int(big.sum())} node positions are bad")
    return data - offset


def _check_frames_header(name: str, shape: tuple[int, ...], dtype: np.dtype, count: int) -> None:
    """Refuse a .npy header whose shape is not (count, 3) / (F, count, 3) or whose dtype is not
    real numbers."""
    if len(shape) not in (2, 3) or tuple(shape[-2:]) != (count, 3) or (len(shape) == 3 and shape[0] == 0):
        raise InputError(f"{name}: node positions must have shape ({count}, 3) or (frames, {count}, 3) "
                         f"for this grid, got {tuple(shape)}")
    if dtype.kind not in "iuf":
        raise InputError(f"{name}: node positions must be real numbers, got dtype {dtype}")


@dataclass(frozen=True)
class Motion:
    """An analytic motion of the nodes, evaluated at ``amount`` in [0, 1] of its full extent.

    Attributes:
        kind: "rigid" (rotate about an axis through the centre, then translate), "bend" (the
            grid's extent along ``along`` is wrapped onto an arc of ``angle`` degrees in the plane
            of ``along`` and ``towards``), "twist" (rotation about ``along`` growing linearly to
            ``angle`` degrees over the extent).
        axis: rotation axis index for rigid; along/towards: axis indices for bend and twist.
        angle: degrees at amount 1.
        translate: (3,) translation at amount 1 (rigid), world units.
    """

    kind: str
    angle: float
    axis: int = 1
    along: int = 0
    towards: int = 1
    translate: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def apply(self, rest: np.ndarray, amount: float = 1.0, bounds: np.ndarray | None = None) -> np.ndarray:
        """Positions (N, 3) of points at ``amount`` of the motion, from rest positions.

        Args:
            rest: (N, 3) points.
            amount: fraction of the motion.
            bounds: (2, 3) box whose centre and extent define the motion (default: the points'
                own bounding box). Pass the nodes' box to move a detailed mesh exactly as the
                nodes move.
        """
        box = np.array([rest.min(axis=0), rest.max(axis=0)]) if bounds is None else np.asarray(bounds)
        theta = np.radians(self.angle) * amount
        centre = (box[0] + box[1]) / 2.0
        p = rest - centre
        if self.kind == "rigid":
            return rotate(p, self.axis, theta) + centre + amount * np.asarray(self.translate)
        lo, hi = box[0, self.along], box[1, self.along]
        s = (rest[:, self.along] - lo) / max(hi - lo, 1e-300)  # 0..1 along the extent
        if self.kind == "twist":
            return rotate(p, self.along, theta * (s - 0.5)) + centre
        if self.kind == "bend":
            if abs(theta) < 1e-12:
                return rest.copy()
            length = hi - lo
            radius = length / theta
            phi = (s - 0.5) * theta
            h = p[:, self.towards]
            out = p.copy()
            out[:, self.along] = (radius - h) * np.sin(phi)
            out[:, self.towards] = radius - (radius - h) * np.cos(phi)
            return out + centre
        raise ValueError(f"unknown motion kind {self.kind!r}")


def rotate(p: np.ndarray, axis: int, angle: float | np.ndarray) -> np.ndarray:
    """Rotate points (N, 3) about coordinate axis ``axis`` by ``angle`` radians (scalar or (N,))."""
    a, b = [(1, 2), (2, 0), (0, 1)][axis]
    c, s = np.cos(angle), np.sin(angle)
    out = p.copy()
    out[:, a] = c * p[:, a] - s * p[:, b]
    out[:, b] = s * p[:, a] + c * p[:, b]
    return out


class DrivenNodes(GLOwner):
    """Node state for positions given from outside: upload, then the normals pass (Mosegaard & Sørensen 2005, eq. 3).

    ``position_texture`` is what the render passes read, like a simulation's.

    Args:
        ctx: GL context.
        textures: the node textures (static node data and state) of the grid.
        grid: the node grid.
    """

    def __init__(self, ctx: moderngl.Context, textures: NodeTextures, grid: NodeGrid) -> None:
        super().__init__(ctx)
        self.textures, self.grid = textures, grid
        layout = textures.layout
        with self.building():
            self.program = self.own(Program(ctx, "sim/fullscreen.vert", "sim/node_normals.frag",
                                            defines=layout.shader_defines()))
            self.program.set(u_position=0, u_node=1, **layout.shader_uniforms())
            self.vao = self.own(ctx.vertex_array(self.program.gl, []))

    @property
    def position_texture(self) -> moderngl.Texture:
        """The state texture with the latest positions and packed normals."""
        return self.textures.state[0]

    def set_positions(self, positions: np.ndarray) -> None:
        """Upload (N, 3) node positions and compute their normals on the GPU."""
        layout = self.textures.layout
        image = layout.scatter(self.grid.ijk, np.hstack([positions, np.zeros((len(positions), 1))]))
        self.textures.state[1].write(image.tobytes())
        self.textures.state[1].use(0)
        self.textures.bind_static(1)
        self.textures.framebuffers[0].use()
        self.vao.render(moderngl.TRIANGLES, vertices=3)
