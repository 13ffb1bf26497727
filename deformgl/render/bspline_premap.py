"""A detailed mesh drawn through a spline body's field (issue 44, item 4): one fragment per vertex
(``shaders/render/bspline_premap.frag``) evaluates the quadratic B-spline field the body was solved
with at the vertex's rest place, ``x(X) = sum_a N_a(X) x_a`` over its knot span's 27 control points,
and turns its rest normal by the field's cofactor ``det(F) F^-T``; what was solved is what is drawn.
Its outputs are :class:`~deformgl.render.premap.FragmentPremap`'s (the mapped position and the
unnormalised normal, vertex v at texel (v % W, v // W)), so ``render/mapped_premapped.vert`` draws
them.

Textures (the channel layouts: ``shaders/render/bspline_premap.frag``): the vertices' span nodes,
RGBA32I array of 7 layers; their span coordinates and rest normals, RGBA32F array of 2 layers; the
two RGBA32F outputs, rewritten by every :meth:`BSplinePremap.run`.
"""

from __future__ import annotations

import moderngl
import numpy as np

from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner
from deformgl.render.camera import View
from deformgl.render.mapped import culled
from deformgl.render.passes import Lighting
from deformgl.render.premap import PremapPass
from deformgl.sim.terms.spline.basis import SPAN_OFFSETS
from deformgl.sim.terms.spline.body import SplineBody

__all__ = ["BSplinePremap", "FieldMeshPass"]


def vertex_spans(body: SplineBody, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each vertex's knot span: its 27 node numbers (V, 27) and the vertex's span coordinates
    (V, 3). The span of the nearest node where that span holds material, else the nearest one that
    does among its 26 neighbours (a surface vertex just outside the material's spans: the span's
    polynomial continued there, |s| <= 3/2).

    Raises:
        ValueError: one line naming the first vertex with no span of the body within a node.
    """
    grid = body.grid
    t = (np.asarray(vertices, np.float64) - grid.origin) / body.spacing
    span_at = np.full(grid.shape, -1, np.int64)
    span_at[tuple(grid.ijk[body.span_nodes[:, 13]].T)] = np.arange(len(body.span_nodes))
    nearest = np.rint(t).astype(np.int64)
    best = np.full(len(t), -1, np.int64)
    distance = np.full(len(t), np.inf)
    for offset in SPAN_OFFSETS:
        c = nearest + offset
        ok = np.all((c >= 0) & (c < np.array(grid.shape)), axis=1)
        span = np.full(len(t), -1, np.int64)
        span[ok] = span_at[tuple(c[ok].T)]
        d = np.abs(t - c).max(axis=1)
        better = (span >= 0) & (d < distance - 1e-12)
        best[better], distance[better] = span[better], d[better]
    if np.any(best < 0):
        bad = int(np.argmax(best < 0))
        raise ValueError(f"spline mapping: vertex {bad} at {np.asarray(vertices)[bad].tolist()} m is more than a node "
                         f"from the body's spans")
    nodes = body.span_nodes[best]
    return nodes, t - grid.ijk[nodes[:, 13]]


class BSplinePremap(PremapPass):
    """Maps the vertices of a detailed mesh through ``body``'s field in one fragment pass.

    Args:
        ctx: GL context.
        body: the spline body (its control points are the nodes of the position textures).
        layout: the node layout's uniforms of the position textures
            (:func:`deformgl.grid.nodes.layout_uniforms`).
        vertices: (V, 3) the vertices' rest positions, m.
        normals: (V, 3) their rest normals.

    Raises:
        ValueError: one line naming the first vertex outside the body's knot spans, or arrays of
            the wrong shape or not finite.
    """

    def __init__(self, ctx: moderngl.Context, body: SplineBody, layout: dict[str, int], vertices: np.ndarray,
                 normals: np.ndarray) -> None:
        vertices = np.asarray(vertices, np.float64)
        normals = np.asarray(normals, np.float64)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or normals.shape != vertices.shape:
            raise ValueError(f"spline mapping: vertices {vertices.shape} and normals {normals.shape}, expected (V, 3) each")
        if not (np.isfinite(vertices).all() and np.isfinite(normals).all()):
            raise ValueError("spline mapping: vertices or normals not finite")
        nodes, spans = vertex_spans(body, vertices)
        super().__init__(ctx)
        count = len(vertices)
        self.count = count
        max_size = int(ctx.info["GL_MAX_TEXTURE_SIZE"])
        width = 1 << max(4, int(np.ceil(np.log2(np.sqrt(max(count, 1))))))
        width = min(width, 1 << int(np.floor(np.log2(max_size))))
        height = max(1, -(-count // width))
        if height > max_size:
            raise ValueError(f"spline mapping: {count} vertices need more than {max_size}x{max_size} texels")
        self.size = (width, height)
        table = np.zeros((7, width * height, 4), np.int32)
        padded = np.zeros((count, 28), np.int32)
        padded[:, :27] = nodes
        table[:, :count] = padded.reshape(count, 7, 4).transpose(1, 0, 2)
        data = np.zeros((2, width * height, 4), np.float32)
        data[0, :count, :3] = spans
        data[1, :count, :3] = normals
        with self.building():
            self.nodes = self.own(ctx.texture_array((width, height, 7), 4, table.tobytes(), dtype="i4"))
            self.data = self.own(ctx.texture_array((width, height, 2), 4, data.tobytes(), dtype="f4"))
            for t in (self.nodes, self.data):
                t.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self.outputs = []
            for _ in range(2):
                out = self.own(ctx.texture(self.size, 4, dtype="f4"))
                out.filter = (moderngl.NEAREST, moderngl.NEAREST)
                self.outputs.append(out)
            self.fbo = self.own(ctx.framebuffer(color_attachments=self.outputs))
            self.program = self.own(Program(ctx, "sim/fullscreen.vert", "render/bspline_premap.frag"))
            self.program.set(u_position=0, u_vertex_nodes=1, u_vertex_data=2, u_h=body.spacing, **layout)
            self.vao = self.own(ctx.vertex_array(self.program.gl, []))
        self.inputs = [self.nodes, self.data]


class FieldMeshPass(GLOwner):
    """A detailed mesh drawn through a spline body's field: :class:`BSplinePremap` then
    ``render/mapped_premapped.vert`` (a scene's ``model = "spline"``: what was solved is what is
    drawn). The interface of :class:`~deformgl.render.mapped.MappedMeshPass` the renderer uses:
    :meth:`draw` and :meth:`capture`.

    Args:
        ctx: GL context.
        body: the spline body.
        layout: the node layout's uniforms of the position textures.
        vertices, normals: (V, 3) the mesh's rest vertices (m) and normals; faces: (F, 3).
        front_face: "ccw" or "cw" culls the faces wound the other way; None draws every face.
    """

    def __init__(self, ctx: moderngl.Context, body: SplineBody, layout: dict[str, int], vertices: np.ndarray,
                 normals: np.ndarray, faces: np.ndarray, *, front_face: str | None = None) -> None:
        super().__init__(ctx)
        self.front_face = front_face
        self.count = len(vertices)
        #: the mapping's per-vertex data :class:`~deformgl.render.mapped.MappedMeshPass` keeps for the
        #: exports: none here (the field is the body's: :mod:`deformgl.scene.spline_fields`)
        self.data = None
        with self.building():
            self.premap = self.own(BSplinePremap(ctx, body, layout, vertices, normals))
            self.program = self.own(Program(ctx, "render/mapped_premapped.vert", "render/mapped_mesh.frag",
                                            defines={"NORMAL_MAP": False}))
            self.ibo = self.own(ctx.buffer(np.ascontiguousarray(faces, dtype="i4").tobytes()))
            self.vao = self.own(ctx.vertex_array(self.program.gl, [], index_buffer=self.ibo, index_element_size=4))
            self.program.set(**self.premap.layout_uniforms)

    def draw(self, positions: moderngl.Texture, view: View, lighting: Lighting) -> None:
        """Draw the mesh with node positions from ``positions``."""
        self.premap.run(positions)
        with culled(self.ctx, self.front_face):
            self.program.set(**self.premap.bind(), u_view_projection=tuple(view.view_projection.T.astype("f4").ravel()),
                             u_eye=tuple(view.eye), **lighting.uniforms())
            self.vao.render(moderngl.TRIANGLES)

    def capture(self, positions: moderngl.Texture) -> tuple[np.ndarray, np.ndarray]:
        """(V, 3) float32 deformed vertices and normals (not normalised) as drawn; one read-back."""
        self.premap.run(positions)
        return self.premap.read()
