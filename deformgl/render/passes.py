"""Offscreen rendering: an MSAA (or FXAA) target resolved to RGB, and the draw passes that use it."""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

from deformgl.render.camera import View
from deformgl.errors import GLError
from deformgl.grid.nodes import CompactLayout, NodeGrid
from deformgl.gl.programs import Program, profile_of
from deformgl.gl.resources import GLOwner, restore_framebuffer
from deformgl.render.fxaa import FxaaPass
from deformgl.render.sheet_normals import sheet_neighbours
from deformgl.grid.surface import grid_surface


@dataclass(frozen=True)
class Lighting:
    """Light and material of the lit passes (colours in [0, 1])."""

    direction: tuple[float, float, float]
    colour: tuple[float, float, float] = (1.0, 1.0, 1.0)
    ambient: float = 0.2
    material: tuple[float, float, float] = (0.85, 0.6, 0.35)
    specular: float = 0.3
    shininess: float = 32.0

    def uniforms(self) -> dict[str, object]:
        """Uniform values of ``shaders/lib/blinn_phong.glsl``."""
        d = np.asarray(self.direction, dtype=np.float64)
        return {"u_light_direction": tuple(d / np.linalg.norm(d)), "u_light_colour": self.colour,
                "u_ambient": self.ambient, "u_material_colour": self.material,
                "u_specular": self.specular, "u_shininess": self.shininess}


class RenderTarget(GLOwner):
    """Colour + depth framebuffer, multisampled when ``samples > 1``, resolved for read-back;
    or, with ``fxaa``, single-sampled into a colour texture that :class:`FxaaPass` filters
    into the read-back buffer.

    Args:
        ctx: GL context.
        size: (width, height) pixels.
        samples: MSAA samples (0 or 1: none).
        fxaa: post-process anti-aliasing instead (requires ``samples`` 0 or 1).
    """

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int], samples: int = 4, *,
                 fxaa: bool = False) -> None:
        super().__init__(ctx)
        self.size = size
        max_samples = int(ctx.info.get("GL_MAX_SAMPLES", 1))
        if samples > max_samples:
            raise GLError(f"{samples}x MSAA requested, the renderer supports at most {max_samples}x")
        self.samples = samples if samples > 1 else 0
        if fxaa and self.samples:
            raise GLError(f"FXAA and {samples}x MSAA requested together: choose one")
        self.resolved: moderngl.Renderbuffer | None = None
        self.resolve_fbo: moderngl.Framebuffer | None = None
        self.fxaa: FxaaPass | None = None
        self.colour: moderngl.Renderbuffer | moderngl.Texture
        with self.building():
            if fxaa:
                texture = self.own(ctx.texture(size, 4))
                texture.filter = (moderngl.LINEAR, moderngl.LINEAR)
                texture.repeat_x = texture.repeat_y = False
                self.colour = texture
                self.fxaa = self.own(FxaaPass(ctx))
            else:
                self.colour = self.own(ctx.renderbuffer(size, 4, samples=self.samples))
            self.depth = self.own(ctx.depth_renderbuffer(size, samples=self.samples))
            self.fbo = self.own(ctx.framebuffer(color_attachments=[self.colour], depth_attachment=self.depth))
            if self.samples or fxaa:
                self.resolved = self.own(ctx.renderbuffer(size, 4))
                self.resolve_fbo = self.own(ctx.framebuffer(color_attachments=[self.resolved]))

    def resolve(self) -> moderngl.Framebuffer:
        """The framebuffer holding the finished image: the MSAA resolve or the FXAA output
        (written now), else the target itself."""
        if self.resolve_fbo is None:
            return self.fbo
        if self.fxaa is not None and isinstance(self.colour, moderngl.Texture):
            self.fxaa.apply(self.colour, self.resolve_fbo)
        else:
            self.ctx.copy_framebuffer(self.resolve_fbo, self.fbo)
        return self.resolve_fbo

    def begin(self, background: tuple[float, float, float]) -> None:
        """Bind, clear to ``background`` and enable depth testing."""
        self.fbo.use()
        self.ctx.viewport = (0, 0, *self.size)
        self.fbo.clear(*background, 1.0, depth=1.0)
        # (ES has no PROGRAM_POINT_SIZE switch: gl_PointSize always counts there)
        self.ctx.enable(moderngl.DEPTH_TEST if profile_of(self.ctx) == "es"
                        else moderngl.DEPTH_TEST | moderngl.PROGRAM_POINT_SIZE)

    def read_rgb(self, source: moderngl.Framebuffer | None = None) -> np.ndarray:
        """Resolve (if multisampled or FXAA) and read the image: (height, width, 3) uint8, top row
        first. ``source``: read what :meth:`resolve` returned before, as it is."""
        if source is None:
            source = self.resolve()
        w, h = self.size
        if profile_of(self.ctx) == "es":  # (ES reads RGBA/UNSIGNED_BYTE; RGB is not guaranteed)
            rgba = np.frombuffer(source.read(components=4, alignment=1), dtype=np.uint8).reshape(h, w, 4)
            return rgba[::-1, :, :3].copy()
        data = source.read(components=3, alignment=1)
        return np.frombuffer(data, dtype=np.uint8).reshape(h, w, 3)[::-1].copy()



class FeedbackCapture(GLOwner):
    """Captures a vertex shader's outputs with transform feedback: the same shader file and
    variant as a draw pass, built with ``varyings``, rasterizer discarded.

    Args:
        ctx: GL context.
        vertex: vertex shader file; defines: its variant; varyings: captured outputs (vec3 each).
        content: the draw pass's vertex array content (attributes feeding no captured output are
            inactive in the capture program and skipped).
    """

    def __init__(self, ctx: moderngl.Context, vertex: str, defines: dict[str, object],
                 varyings: tuple[str, ...], content: list, width: int | None = None) -> None:
        super().__init__(ctx)
        self.width = 3 * len(varyings) if width is None else width  # floats per vertex
        with self.building():
            self.program = self.own(Program(ctx, vertex, defines=defines, varyings=varyings))
            self.vao = self.own(ctx.vertex_array(self.program.gl, content, skip_errors=True))
            # Mesa skips every draw, transform feedback included, without a complete framebuffer.
            # (simple_framebuffer would make renderbuffers that releasing the framebuffer leaves)
            self.colour = self.own(ctx.renderbuffer((1, 1)))
            self.fbo = self.own(ctx.framebuffer(color_attachments=[self.colour]))

    def run_into(self, positions: moderngl.Texture, count: int, out: moderngl.Buffer) -> None:
        """Write the outputs for node positions from ``positions`` into ``out`` (stays on the GPU)."""
        previous = self.ctx.fbo
        self.fbo.use()
        positions.use(0)
        self.program.set(u_position=0)
        self.vao.transform(out, moderngl.POINTS, vertices=count)
        restore_framebuffer(self.ctx, previous)

    def run(self, positions: moderngl.Texture, count: int) -> np.ndarray:
        """(count, width) float32 outputs for node positions from ``positions`` (one read-back)."""
        out = self.ctx.buffer(reserve=count * self.width * 4)
        try:
            self.run_into(positions, count, out)
            return np.frombuffer(out.read(), dtype="f4").reshape(count, self.width).copy()
        finally:
            out.release()



class GridSurfacePass(GLOwner):
    """Draws the node-grid surface with the one-to-one mapping (3.2), optionally with the
    node/spring overlay (figure 2b). Vertex and index buffers are static, built once.

    Args:
        ctx: GL context.
        grid: the node grid.
        layout: where each node lies in the state texture.
        overlay: also draw nodes and surface springs as points and lines.
    """

    def __init__(self, ctx: moderngl.Context, grid: NodeGrid, layout: CompactLayout, *,
                 overlay: bool = False) -> None:
        super().__init__(ctx)
        self.surface = grid_surface(grid)
        # per vertex: its node's texel, then its sheet neighbours' (u+, u-, v+, v-; itself off sheets)
        nodes = np.concatenate([self.surface.nodes[:, None], sheet_neighbours(grid, self.surface)], axis=1)
        texels = layout.texel(grid.ijk[nodes.ravel()]).astype("i4").reshape(len(nodes), 10)
        self._capture: FeedbackCapture | None = None
        self.overlay: Program | None = None
        with self.building():
            self.program = self.own(Program(ctx, "render/grid_surface.vert", "render/lit_surface.frag"))
            self.vbo = self.own(ctx.buffer(texels.tobytes()))
            self.ibo = self.own(ctx.buffer(self.surface.triangles.astype("i4").tobytes()))
            self.vao = self.own(ctx.vertex_array(self.program.gl, self._content(),
                                                 index_buffer=self.ibo, index_element_size=4))
            if overlay:
                self.overlay = self.own(Program(ctx, "render/grid_lines.vert", "render/flat_colour.frag"))
                self.line_ibo = self.own(ctx.buffer(self.surface.edges().astype("i4").tobytes()))
                plain = [(self.vbo, "2i 32x", "in_texel")]  # (the overlay reads the node's texel only)
                self.line_vao = self.own(ctx.vertex_array(self.overlay.gl, plain,
                                                          index_buffer=self.line_ibo, index_element_size=4))
                self.point_vao = self.own(ctx.vertex_array(self.overlay.gl, plain))

    def _content(self) -> list:
        """The vertex array content of the surface's programs: the node's texel, then its sheet
        neighbours' (:func:`~deformgl.render.sheet_normals.sheet_neighbours`)."""
        return [(self.vbo, "2i 4i 4i", "in_texel", "in_across_u", "in_across_v")]

    def draw(self, positions: moderngl.Texture, view: View, lighting: Lighting) -> None:
        """Draw with node positions from ``positions`` (texture unit 0)."""
        positions.use(0)
        vp = tuple(view.view_projection.T.astype("f4").ravel())
        self.program.set(u_position=0, u_view_projection=vp, u_eye=tuple(view.eye), **lighting.uniforms())
        if len(self.surface.triangles):
            self.vao.render(moderngl.TRIANGLES)
        if self.overlay is not None:
            self.overlay.set(u_position=0, u_view_projection=vp, u_colour=(0.1, 0.1, 0.1))
            self.line_vao.render(moderngl.LINES)
            self.overlay.set(u_colour=(0.8, 0.1, 0.1))
            self.point_vao.render(moderngl.POINTS)

    def capture(self, positions: moderngl.Texture) -> tuple[np.ndarray, np.ndarray]:
        """Surface vertices (one per node of ``surface.nodes``) and normals as the vertex shader
        computes them, by transform feedback; one read-back."""
        if self._capture is None:
            self._capture = self.own(FeedbackCapture(self.ctx, "render/grid_surface.vert", {},
                                                     ("v_world", "v_normal"), self._content()))
        data = self._capture.run(positions, len(self.surface.nodes))
        return data[:, :3], data[:, 3:]
