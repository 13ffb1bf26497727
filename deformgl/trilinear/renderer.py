"""The GPU side of the trilinear scene graph (Knuth, Kohlhammer & Kuijper, section 4.2):
:class:`TrilinearRenderer` draws a :class:`~deformgl.trilinear.batches.ComposedScene` with one
instanced draw per batch, grid transforms packed in one 3D-texture atlas.

Per-instance data (float32, one row per leaf):

* affine: 12 floats, rows of the 3x4 matrix acting on local vertex positions;
* cuboid: box minimum (4), 1 / box size (4), six vec4 of the 3x8 rows (Knuth, Kohlhammer &
  Kuijper, eq. 2 ``C`` or eq. 1 corners);
* grid: (box minimum, nx), (cells / box size, ny), (block offset + 0.5 texel, nz).

The grid atlas is an RGBA32F 3D texture (W, H, D): texel (ox + i, oy + j, oz + k) is the image
of lattice point (i, j, k) of the block at offset (ox, oy, oz); w is 1.
"""

from __future__ import annotations

import moderngl
import numpy as np

from deformgl.gl.es_context import is_es
from deformgl.errors import GLError, InputError
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner, restore_framebuffer
from deformgl.render.camera import View
from deformgl.render.passes import Lighting
from deformgl.trilinear.batches import PATHS, Batch, ComposedScene
from deformgl.trilinear.graph_nodes import Geometry
from deformgl.trilinear.cuboid import coefficient_matrix
from deformgl.trilinear.normal_transform import NORMAL_MODES
_INSTANCE_ATTRIBUTES = {
    "affine": ("i_row0", "i_row1", "i_row2"),
    "cuboid": ("i_box_lo", "i_box_scale", "i_xa", "i_xb", "i_ya", "i_yb", "i_za", "i_zb"),
    "grid": ("i_grid_lo", "i_grid_scale", "i_grid_origin"),
}


def pack_atlas(shapes: list[tuple[int, int, int]], max_size: int) -> tuple[np.ndarray, tuple[int, int, int]]:
    """Place blocks of (sx, sy, sz) texels in a 3D atlas: rows along x, rows stacked in y,
    layers in z.

    Returns:
        (k, 3) texel offsets and the atlas size (W, H, D).

    Raises:
        GLError: a block or the atlas does not fit ``max_size`` on an axis.
    """
    offsets = np.zeros((len(shapes), 3), dtype=np.int64)
    x = y = z = row_h = layer_d = width = height = 0
    for i, (sx, sy, sz) in enumerate(shapes):
        if max(sx, sy, sz) > max_size:
            raise GLError(f"a grid of {sx}x{sy}x{sz} points exceeds the 3D texture limit {max_size}")
        if x + sx > max_size:
            x, y, row_h = 0, y + row_h, 0
        if y + sy > max_size:
            x, y, z, row_h, layer_d = 0, 0, z + layer_d, 0, 0
        offsets[i] = (x, y, z)
        x += sx
        row_h, layer_d = max(row_h, sy), max(layer_d, sz)
        width, height = max(width, x), max(height, y + row_h)
    depth = z + layer_d
    if depth > max_size:
        raise GLError(f"the grid atlas needs {depth} layers, more than the 3D texture limit {max_size}")
    return offsets, (max(width, 1), max(height, 1), max(depth, 1))


def atlas_image(grids: list[np.ndarray], offsets: np.ndarray, size: tuple[int, int, int]) -> np.ndarray:
    """The RGBA32F atlas (D, H, W, 4): stacked lattices written at their offsets, w = 1."""
    w, h, d = size
    image = np.zeros((d, h, w, 4), dtype=np.float32)
    image[..., 3] = 1.0
    start = 0
    for stack in grids:
        k, sx, sy, sz = stack.shape[:4]
        off = offsets[start:start + k]
        i, j, l = np.meshgrid(np.arange(sx), np.arange(sy), np.arange(sz), indexing="ij")
        xs = off[:, 0, None] + i.ravel()[None]
        ys = off[:, 1, None] + j.ravel()[None]
        zs = off[:, 2, None] + l.ravel()[None]
        image[zs, ys, xs, :3] = stack.reshape(k, -1, 3)
        start += k
    return image


def instance_data(batch: Batch, *, cuboid_form: int = 4, origins: np.ndarray | None = None) -> np.ndarray:
    """Per-instance float32 rows of a batch, in the attribute order of ``transform.vert``.

    Args:
        batch: the batch.
        cuboid_form: 4 packs the rows of ``C`` (Knuth, Kohlhammer & Kuijper, eq. 2), 1 the rows of
            the corners (eq. 1 there).
        origins: grid path: (k, 3) block offsets + 0.5 in the atlas.
    """
    k = batch.count
    if batch.path == "affine":
        return batch.need("affine", batch.affine).reshape(k, 12).astype(np.float32)
    out = np.zeros((k, 4 * len(_INSTANCE_ATTRIBUTES[batch.path])), dtype=np.float32)
    if batch.path == "cuboid":
        corners = batch.need("corners", batch.corners)
        out[:, 0:3] = batch.box_lo
        out[:, 4:7] = 1.0 / batch.need("box_size", batch.box_size)
        rows = coefficient_matrix(corners) if cuboid_form == 4 else np.swapaxes(corners, 1, 2)
        out[:, 8:] = rows.reshape(k, 24)
        return out
    cells = np.concatenate([np.repeat(np.array(s.shape[1:4])[None] - 1, len(s), 0) for s in batch.grids])
    out[:, 0:3], out[:, 3] = batch.box_lo, cells[:, 0]
    out[:, 4:7], out[:, 7] = cells / batch.box_size, cells[:, 1]
    out[:, 8:11], out[:, 11] = origins, cells[:, 2]
    return out


def shader_defines(path: str, normals: str, cuboid_form: int = 4) -> dict[str, object]:
    """The ``#define``s of ``trilinear/transform.vert`` for a draw path and normal mode."""
    if path not in PATHS or normals not in NORMAL_MODES:
        raise InputError(f"unknown draw path {path!r} or normal mode {normals!r}")
    return {"TRANSFORM_PATH": PATHS.index(path), "CUBOID_FORM": cuboid_form,
            "NORMALS_TANGENT": int(normals == "tangent")}


class TrilinearRenderer(GLOwner):
    """Draws a :class:`ComposedScene`: one instanced draw per batch, grids in one 3D atlas.

    Programs are ``trilinear/transform.vert`` + ``trilinear/lit.frag`` with defines
    ``TRANSFORM_PATH`` (0 affine, 1 cuboid, 2 grid), ``CUBOID_FORM`` and ``NORMALS_TANGENT``;
    :meth:`capture` runs the same vertex shader with transform feedback.

    Args:
        ctx: GL context.
        cuboid_form: 4 evaluates single cuboids by Knuth, Kohlhammer & Kuijper, eq. 4 (default),
            1 by their eq. 1.
    """

    def __init__(self, ctx: moderngl.Context, *, cuboid_form: int = 4) -> None:
        if cuboid_form not in (1, 4):
            raise InputError(f"cuboid_form must be 1 (Knuth, Kohlhammer & Kuijper, eq. 1) or 4 (eq. 4), got {cuboid_form}")
        super().__init__(ctx)
        self.cuboid_form = cuboid_form
        self.max_3d = int(ctx.info.get("GL_MAX_3D_TEXTURE_SIZE", 256))
        self.programs: dict[tuple, Program] = {}
        # keyed by id(geometry); the geometry is kept so that its id is not reused
        self.meshes: dict[int, tuple[Geometry, moderngl.Buffer, moderngl.Buffer | None]] = {}
        self.instances: dict[tuple, list] = {}   # key -> [buffer, capacity, {vao kind: vao}]
        self.atlas: moderngl.Texture3D | None = None
        self.atlas_size = (0, 0, 0)
        self._capture_fbo: moderngl.Framebuffer | None = None
        self._capture_rb: moderngl.Renderbuffer | None = None

    def defines(self, path: str, normals: str) -> dict[str, object]:
        """The shader variant of a path and normal mode (:func:`shader_defines`)."""
        return shader_defines(path, normals, self.cuboid_form)

    def program(self, path: str, normals: str, capture: bool = False) -> Program:
        """The (cached) program of a path and normal mode, for drawing or for capture."""
        key = (path, normals, capture)
        if key not in self.programs:
            if capture:
                prog = Program(self.ctx, "trilinear/transform.vert", None, defines=self.defines(path, normals),
                               varyings=("v_world", "v_normal"))
            else:
                prog = Program(self.ctx, "trilinear/transform.vert", "trilinear/lit.frag",
                               defines=self.defines(path, normals))
            self.programs[key] = self.own(prog)
        return self.programs[key]

    def _mesh(self, geometry: Geometry) -> tuple[moderngl.Buffer, moderngl.Buffer | None]:
        """The (cached) vertex and index buffers of a mesh."""
        key = id(geometry)
        if key not in self.meshes:
            data = np.concatenate([geometry.vertices, geometry.normals], axis=1).astype(np.float32)
            vbo = self.own(self.ctx.buffer(data.tobytes()))
            ibo = (self.own(self.ctx.buffer(geometry.triangles.astype(np.int32).tobytes()))
                   if len(geometry.triangles) else None)
            self.meshes[key] = (geometry, vbo, ibo)
        return self.meshes[key][1:]

    def _upload_atlas(self, batches: list[Batch]) -> dict[int, np.ndarray]:
        """Pack and upload all grid lattices; returns per batch (by id) the (k, 3) origins."""
        grid_batches = [b for b in batches if b.path == "grid"]
        if not grid_batches:
            return {}
        grids = [s for b in grid_batches for s in b.grids]
        shapes = [(int(s.shape[1]), int(s.shape[2]), int(s.shape[3])) for s in grids for _ in range(len(s))]
        offsets, size = pack_atlas(shapes, self.max_3d)
        image = atlas_image(grids, offsets, size)
        if self.atlas is None or self.atlas_size != size:
            if is_es(self.ctx) and "GL_OES_texture_float_linear" not in self.ctx.extensions:
                # without it an RGBA32F texture with LINEAR filtering is incomplete in ES: every
                # fetch returns (0, 0, 0, 1) and grid-transformed vertices collapse to the origin
                raise GLError("this OpenGL ES context has no OES_texture_float_linear: the trilinear "
                              "grid path (hardware-filtered RGBA32F 3D atlas) cannot run on it")
            if self.atlas is not None:
                self.disown(self.atlas)
            self.atlas = self.own(self.ctx.texture3d(size, 4, dtype="f4"))
            self.atlas.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self.atlas.repeat_x = self.atlas.repeat_y = self.atlas.repeat_z = False
            self.atlas_size = size
        self.atlas.write(image.tobytes())
        origins, start = {}, 0
        for b in grid_batches:
            origins[id(b)] = offsets[start:start + b.count] + 0.5
            start += b.count
        return origins

    def _vertex_array(self, batch: Batch, data: np.ndarray, capture: bool) -> moderngl.VertexArray:
        """The batch's vertex array with ``data`` written to its (grown when needed) instance buffer."""
        key = (id(batch.geometry), batch.path, batch.normals, batch.colour)
        entry = self.instances.get(key)
        if entry is None or entry[1] < data.nbytes:
            if entry is not None:
                for vao in entry[2].values():
                    self.disown(vao)
                self.disown(entry[0])
            entry = [self.own(self.ctx.buffer(reserve=max(data.nbytes, 64))), max(data.nbytes, 64), {}]
            self.instances[key] = entry
        entry[0].write(data.tobytes())
        if capture not in entry[2]:
            vbo, ibo = self._mesh(batch.geometry)
            prog = self.program(batch.path, batch.normals, capture)
            names = _INSTANCE_ATTRIBUTES[batch.path]
            layout = [(vbo, "3f 3f", "in_position", "in_normal"),
                      (entry[0], " ".join(["4f"] * len(names)) + "/i", *names)]
            if capture or ibo is None:
                entry[2][capture] = self.own(self.ctx.vertex_array(prog.gl, layout))
            else:
                entry[2][capture] = self.own(self.ctx.vertex_array(prog.gl, layout, index_buffer=ibo,
                                                                   index_element_size=4))
        return entry[2][capture]

    def _bind_grid(self, prog: Program) -> None:
        """Bind the grid atlas to unit 0 for ``prog``."""
        assert self.atlas is not None
        self.atlas.use(0)
        prog.set(u_grid_atlas=0, u_atlas_texel=tuple(1.0 / s for s in self.atlas_size))

    def draw(self, scene: ComposedScene, view: View, lighting: Lighting) -> None:
        """Draw every batch into the bound framebuffer (call ``RenderTarget.begin`` first)."""
        origins = self._upload_atlas(scene.batches)
        vp = tuple(view.view_projection.T.astype("f4").ravel())
        light = lighting.uniforms()
        for batch in scene.batches:
            if not len(batch.geometry.triangles):
                continue
            data = instance_data(batch, cuboid_form=self.cuboid_form, origins=origins.get(id(batch)))
            vao = self._vertex_array(batch, data, capture=False)
            prog = self.program(batch.path, batch.normals)
            prog.set(u_view_projection=vp, u_eye=tuple(float(e) for e in view.eye),
                     **{**light, "u_material_colour": batch.colour})
            if batch.path == "grid":
                self._bind_grid(prog)
            vao.render(moderngl.TRIANGLES, instances=batch.count)

    def capture(self, scene: ComposedScene) -> list[tuple[np.ndarray, np.ndarray]]:
        """Run the drawing vertex shader with transform feedback, per batch: (k, N, 3) world
        positions and (k, N, 3) normals, float32 as the GPU computed them.

        Binds a 1x1 framebuffer of its own while capturing (Mesa skips draws without a complete
        framebuffer), then binds back the caller's.
        """
        if self._capture_fbo is None:
            self._capture_rb = self.own(self.ctx.renderbuffer((1, 1)))
            self._capture_fbo = self.own(self.ctx.framebuffer(color_attachments=[self._capture_rb]))
        previous = self.ctx.fbo
        self._capture_fbo.use()
        try:
            return self._capture_batches(scene)
        finally:
            restore_framebuffer(self.ctx, previous)

    def _capture_batches(self, scene: ComposedScene) -> list[tuple[np.ndarray, np.ndarray]]:
        """The transform-feedback runs of :meth:`capture`, into the bound framebuffer."""
        origins = self._upload_atlas(scene.batches)
        out = []
        for batch in scene.batches:
            data = instance_data(batch, cuboid_form=self.cuboid_form, origins=origins.get(id(batch)))
            vao = self._vertex_array(batch, data, capture=True)
            prog = self.program(batch.path, batch.normals, capture=True)
            prog.set(u_view_projection=tuple(np.identity(4, dtype="f4").ravel()))
            if batch.path == "grid":
                self._bind_grid(prog)
            n = len(batch.geometry.vertices)
            result = self.ctx.buffer(reserve=batch.count * n * 6 * 4)
            try:
                vao.transform(result, moderngl.POINTS, vertices=n, instances=batch.count)
                got = np.frombuffer(result.read(), dtype=np.float32).reshape(batch.count, n, 6)
            finally:
                result.release()
            out.append((got[..., :3].copy(), got[..., 3:].copy()))
        return out
