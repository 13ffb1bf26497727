"""Post-process anti-aliasing: FXAA over a rendered colour texture (``shaders/render/fxaa.frag``,
Lottes 2011, the NVIDIA FXAA 3.11 white paper: its PC quality algorithm at preset 12), the
per-scene alternative to MSAA (``[render] aa``).

One full-screen triangle; five taps per pixel where the image is flat, up to 19 on an edge: on
llvmpipe a fixed cost per pixel, independent of the scene's triangle count, where MSAA
multiplies the rasterisation and shading of every triangle edge by its sample count.
"""

from __future__ import annotations

import moderngl

from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner, restore_framebuffer


class FxaaPass(GLOwner):
    """Draws ``colour`` (an RGBA8 texture, LINEAR filtering, clamp-to-edge) anti-aliased into a
    framebuffer of the same size.

    Args:
        ctx: GL context.
    """

    def __init__(self, ctx: moderngl.Context) -> None:
        super().__init__(ctx)
        with self.building():
            self.program = self.own(Program(ctx, "sim/fullscreen.vert", "render/fxaa.frag"))
            self.vao = self.own(ctx.vertex_array(self.program.gl, []))

    def apply(self, colour: moderngl.Texture, out: moderngl.Framebuffer) -> None:
        """Write FXAA of ``colour`` into ``out`` (every pixel, without depth test); then depth
        testing is on again (as :meth:`RenderTarget.begin` leaves it) and the previously bound
        framebuffer is bound again."""
        previous = self.ctx.fbo
        out.use()
        w, h = colour.size
        self.ctx.viewport = (0, 0, w, h)
        self.ctx.disable(moderngl.DEPTH_TEST)
        colour.use(0)
        self.program.set(u_colour=0, u_texel=(1.0 / w, 1.0 / h))
        self.vao.render(moderngl.TRIANGLES, vertices=3)
        self.ctx.enable(moderngl.DEPTH_TEST)
        restore_framebuffer(self.ctx, previous)
