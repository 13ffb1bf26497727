"""Drawing a detailed mesh deformed by the nodes (Mosegaard & Sørensen 2005, 3.3) and capturing
what the vertex shader computed with transform feedback (for mesh export and tests).

Vertex attributes (static buffers, built once from a binding), per vertex of the detailed mesh:

| attribute | type | meaning |
| --- | --- | --- |
| in_texel1..3 | ivec2 | state-texture texels of the three nodes of its triangle |
| in_weights | vec3 | Mosegaard & Sørensen 2005, eq. 4 weights |
| in_offset | vec3 | eq. 7 offset in its basis (constant or curvature, as chosen per vertex) |
| in_offset_world | vec3 | Mosegaard & Sørensen 2005, eq. 5 rest offset (fallback for a degenerate basis) |
| in_normal, in_normal_world | vec3 | vertex normal in the basis / at rest in world space |
| in_curvature | float | 1 = curvature basis (Mosegaard & Sørensen 2005, eq. 8), 0 = constant (eq. 6); CURVATURE variant only |
| in_tangent, in_tangent_world, in_uv | vec4, vec3, vec2 | NORMAL_MAP variant only |
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import moderngl
import numpy as np

from deformgl.render.camera import View
from deformgl.grid.nodes import CompactLayout, NodeGrid
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner
from deformgl.render.passes import FeedbackCapture, Lighting
from deformgl.render.mapped_data import MappedVertices
from deformgl.render.premap import FragmentPremap

#: Where :class:`MappedMeshPass` maps the vertices (its ``mapping_pass``).
MAPPING_PASSES = ("vertex", "feedback", "fragment")


def closed_front_face(vertices: np.ndarray, faces: np.ndarray) -> str | None:
    """The front-face winding that lets back faces be culled without changing the image: "ccw"
    for a closed, consistently wound mesh whose faces wind outward (positive volume), "cw" for
    one wound inward, None for an open or inconsistently wound mesh (whose back faces can be
    seen). Closed and consistent: every edge is crossed as often from a to b as from b to a (no
    hole, no flipped face; edges shared by four faces, as scanned meshes have, are fine), and
    every shell (edge-connected part) encloses its volume with the same winding. Such a
    surface seen from outside shows only faces turned to the eye; the depth test would hide the
    others, so culling them only saves their rasterisation (on llvmpipe, about half the
    triangles of a mapped mesh's draw). Not so where the deformed surface folds over or
    intersects itself, or the camera is inside it: there a back face is what the eye sees."""
    import scipy.sparse
    import scipy.sparse.csgraph
    f = np.asarray(faces, np.int64)
    if len(f) == 0:
        return None
    directed = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    n = int(f.max()) + 1
    forward, count_f = np.unique(directed[:, 0] * n + directed[:, 1], return_counts=True)
    backward, count_b = np.unique(directed[:, 1] * n + directed[:, 0], return_counts=True)
    if not (np.array_equal(forward, backward) and np.array_equal(count_f, count_b)):
        return None
    # every shell (edge-connected component) must wind the same way: an inward-wound shell beside
    # an outward one would lose its near faces
    # (faces meet through any shared edge, those of four faces included; every shell is closed,
    # as the balance above holds for each one: shells share no edge)
    v = np.asarray(vertices, np.float64)
    _, edge = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True)
    edge = edge.ravel()
    incidence = scipy.sparse.coo_matrix((np.ones(len(edge)), (np.repeat(np.arange(len(f)), 3), edge)),
                                        shape=(len(f), int(edge.max()) + 1)).tocsr()
    _, labels = scipy.sparse.csgraph.connected_components(incidence @ incidence.T, directed=False)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    volumes = np.bincount(labels, weights=np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0)
    # (flat or tiny shells, under a millionth of the largest's volume, look alike either way: the
    # res3 dragon has a 6-face sliver of 1.6e-12 m^3 beside its 4.8e-4 m^3 body)
    signs = np.sign(volumes[np.abs(volumes) > 1e-6 * float(np.abs(volumes).max(initial=0.0))])
    if not np.all(np.isfinite(volumes)) or len(signs) == 0 or np.any(signs != signs[0]):
        return None
    return "ccw" if signs[0] > 0 else "cw"


@contextmanager
def culled(ctx: moderngl.Context, front_face: str | None) -> Iterator[None]:
    """Cull the faces not wound ``front_face`` ("ccw", "cw") inside the block; None: cull nothing.
    Culling is off and the front face "ccw" again afterwards (the state every other pass expects)."""
    if front_face is None:
        yield
        return
    ctx.front_face = front_face
    ctx.enable(moderngl.CULL_FACE)
    try:
        yield
    finally:
        ctx.disable(moderngl.CULL_FACE)
        ctx.front_face = "ccw"


def _f4(a: np.ndarray) -> np.ndarray:
    """``a`` as contiguous float32 (the vertex buffers' type)."""
    return np.ascontiguousarray(a, dtype="f4")


class MappedMeshPass(GLOwner):
    """The detailed mesh drawn through ``shaders/render/mapped_mesh.vert``.

    Args:
        ctx: GL context.
        grid: the node grid; layout: where each node lies in the state texture.
        faces: (F, 3) triangles of the detailed mesh.
        data: per-vertex mapping data.
        normal_map: (H, W, 3) uint8 tangent-space normal map, or None (compiles no normal mapping).
        normal_map_strength: 0..1 scale of the map's perturbation.
        mapping_pass: where the vertices are mapped: "vertex" (default) in the drawing vertex
            shader (the paper's way: the shader runs once per index on renderers without a
            post-transform cache); "feedback" once per vertex into a buffer with transform
            feedback, then that buffer is drawn as a plain mesh; "fragment" once per vertex in a
            fragment pass into textures (:class:`~deformgl.render.premap.FragmentPremap`; on
            llvmpipe in its parallel fragment threads), which the draw's vertex shader fetches.
        front_face: "ccw" or "cw" culls the faces wound the other way in :meth:`draw`
            (:func:`closed_front_face` says when that leaves a closed mesh's image as it is);
            None (default) draws every face.
    """

    def __init__(self, ctx: moderngl.Context, grid: NodeGrid, layout: CompactLayout, faces: np.ndarray,
                 data: MappedVertices, *, normal_map: np.ndarray | None = None,
                 normal_map_strength: float = 1.0, mapping_pass: str = "vertex",
                 front_face: str | None = None) -> None:
        if mapping_pass not in MAPPING_PASSES:
            raise ValueError(f"mapping_pass must be one of {', '.join(MAPPING_PASSES)}, got {mapping_pass!r}")
        if front_face not in (None, "ccw", "cw"):
            raise ValueError(f"front_face must be None, 'ccw' or 'cw', got {front_face!r}")
        super().__init__(ctx)
        self.front_face = front_face
        self.data = data
        self.faces = faces
        self.count = len(data.weights)
        self.curvature = bool(np.any(data.use_curvature))
        self.normal_mapped = normal_map is not None
        self.defines: dict[str, object] = {"CURVATURE": self.curvature, "NORMAL_MAP": self.normal_mapped}
        texels = [layout.texel(grid.ijk[data.tri_nodes[:, c]]).astype("i4") for c in range(3)]
        columns = [("in_texel1", "2i", texels[0]), ("in_texel2", "2i", texels[1]),
                   ("in_texel3", "2i", texels[2]), ("in_weights", "3f", _f4(data.weights)),
                   ("in_offset", "3f", _f4(data.offset)), ("in_offset_world", "3f", _f4(data.offset_world)),
                   ("in_normal", "3f", _f4(data.normal)), ("in_normal_world", "3f", _f4(data.normal_world))]
        if self.curvature:
            columns.append(("in_curvature", "1f", _f4(data.use_curvature.astype(np.float64))))
        if self.normal_mapped:
            assert data.tangent is not None and data.tangent_world is not None and data.uv is not None
            columns += [("in_tangent", "4f", _f4(data.tangent)), ("in_tangent_world", "3f", _f4(data.tangent_world)),
                        ("in_uv", "2f", _f4(data.uv))]
        self.program: Program | None = None
        self.vao: moderngl.VertexArray | None = None
        self.normal_map_texture: moderngl.Texture | None = None
        self._capture: FeedbackCapture | None = None
        self.mapping_pass = mapping_pass
        self.stage_one: FeedbackCapture | None = None
        self.premap: FragmentPremap | None = None
        self.cached: Program | None = None
        self.mapped: moderngl.Buffer | None = None
        self.cached_vao: moderngl.VertexArray | None = None
        with self.building():
            self.buffers = [self.own(ctx.buffer(arr.tobytes())) for _, _, arr in columns]
            self.content = [(buf, fmt, name) for buf, (name, fmt, _) in zip(self.buffers, columns)]
            self.ibo = self.own(ctx.buffer(np.ascontiguousarray(faces, dtype="i4").tobytes()))
            if normal_map is not None:
                h, w, _ = normal_map.shape
                self.normal_map_texture = self.own(
                    ctx.texture((w, h), 3, np.ascontiguousarray(normal_map[::-1]).tobytes()))
                self.normal_map_texture.build_mipmaps()
                self.normal_map_texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
            map_uniforms: dict[str, object] = ({"u_normal_map": 1, "u_normal_map_strength": float(normal_map_strength)}
                            if normal_map is not None else {})
            if mapping_pass == "vertex":
                self.program = self.own(Program(ctx, "render/mapped_mesh.vert", "render/mapped_mesh.frag",
                                                defines=self.defines))
                self.vao = self.own(ctx.vertex_array(self.program.gl, self.content, index_buffer=self.ibo,
                                                     index_element_size=4))
                self.program.set(**map_uniforms)
            elif mapping_pass == "feedback":
                self._build_two_stage(map_uniforms)
            else:
                self.premap = self.own(FragmentPremap(ctx, grid, layout, data, self.defines))
                self.program = self.own(Program(ctx, "render/mapped_premapped.vert", "render/mapped_mesh.frag",
                                                defines={"NORMAL_MAP": self.normal_mapped}))
                self.vao = self.own(ctx.vertex_array(self.program.gl, [], index_buffer=self.ibo,
                                                     index_element_size=4))
                self.program.set(**self.premap.layout_uniforms, **map_uniforms)

    def _build_two_stage(self, map_uniforms: dict[str, object]) -> None:
        """Stage one maps each vertex once into ``self.mapped`` by transform feedback; stage two
        draws that buffer as a plain indexed mesh."""
        ctx = self.ctx
        names, fmt = ["v_world", "v_normal"], "3f 3f"
        attrs = ["in_world", "in_normal"]
        if self.normal_mapped:
            names += ["v_tangent", "v_handedness", "v_uv"]
            fmt += " 3f 1f 2f"
            attrs += ["in_tangent", "in_handedness", "in_uv"]
        width = 6 + (6 if self.normal_mapped else 0)
        self.stage_one = self.own(FeedbackCapture(ctx, "render/mapped_mesh.vert", self.defines, tuple(names),
                                                  self.content, width=width))
        self.mapped = self.own(ctx.buffer(reserve=self.count * width * 4))
        self.cached = self.own(Program(ctx, "render/mapped_cached.vert", "render/mapped_mesh.frag",
                                       defines={"NORMAL_MAP": self.normal_mapped}))
        self.cached_vao = self.own(ctx.vertex_array(self.cached.gl, [(self.mapped, fmt, *attrs)],
                                                    index_buffer=self.ibo, index_element_size=4))
        self.cached.set(**map_uniforms)

    def draw(self, positions: moderngl.Texture, view: View, lighting: Lighting) -> None:
        """Draw the mapped mesh with node positions from ``positions`` (culling back faces with
        ``front_face``; face culling is off again afterwards)."""
        if self.premap is not None:  # (a full-screen triangle: before any face culling)
            self.premap.run(positions)
        with culled(self.ctx, self.front_face):
            self._draw(positions, view, lighting)

    def _draw(self, positions: moderngl.Texture, view: View, lighting: Lighting) -> None:
        if self.normal_map_texture is not None:
            self.normal_map_texture.use(1)
        uniforms = dict(u_view_projection=tuple(view.view_projection.T.astype("f4").ravel()),
                        u_eye=tuple(view.eye), **lighting.uniforms())
        if self.stage_one is not None:
            assert self.mapped is not None and self.cached is not None and self.cached_vao is not None
            self.stage_one.run_into(positions, self.count, self.mapped)
            self.cached.set(**uniforms)
            self.cached_vao.render(moderngl.TRIANGLES)
            return
        assert self.program is not None and self.vao is not None
        if self.premap is not None:  # (mapped by draw(), which bound the normal map after it)
            self.program.set(**self.premap.bind(), **uniforms)
            self.vao.render(moderngl.TRIANGLES)
            return
        positions.use(0)
        self.program.set(u_position=0, **uniforms)
        self.vao.render(moderngl.TRIANGLES)

    def capture(self, positions: moderngl.Texture) -> tuple[np.ndarray, np.ndarray]:
        """The deformed vertices and normals exactly as this pass draws them: the fragment
        pass's outputs with ``mapping_pass="fragment"``, else transform feedback of the same
        vertex shader and variant; one read-back.

        Returns:
            (V, 3) float32 positions and (V, 3) float32 normals (not normalised).
        """
        if self.premap is not None:
            self.premap.run(positions)
            return self.premap.read()
        if self._capture is None:
            self._capture = self.own(FeedbackCapture(self.ctx, "render/mapped_mesh.vert", self.defines,
                                                     ("v_world", "v_normal"), self.content))
        data = self._capture.run(positions, self.count)
        return data[:, :3], data[:, 3:]


class StaticMeshPass(GLOwner):
    """A mesh drawn as stored (positions and normals in a static buffer): the speed baseline.
    ``front_face``: as :class:`MappedMeshPass`'s."""

    def __init__(self, ctx: moderngl.Context, vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray,
                 front_face: str | None = None) -> None:
        super().__init__(ctx)
        self.front_face = front_face
        with self.building():
            self.program = self.own(Program(ctx, "render/static_mesh.vert", "render/mapped_mesh.frag"))
            self.vbo = self.own(ctx.buffer(np.hstack([_f4(vertices), _f4(normals)]).tobytes()))
            self.ibo = self.own(ctx.buffer(np.ascontiguousarray(faces, dtype="i4").tobytes()))
            self.vao = self.own(ctx.vertex_array(self.program.gl, [(self.vbo, "3f 3f", "in_position", "in_normal")],
                                                 index_buffer=self.ibo, index_element_size=4))

    def draw(self, view: View, lighting: Lighting) -> None:
        """Draw the mesh."""
        self.program.set(u_view_projection=tuple(view.view_projection.T.astype("f4").ravel()),
                         u_eye=tuple(view.eye), **lighting.uniforms())
        with culled(self.ctx, self.front_face):
            self.vao.render(moderngl.TRIANGLES)
