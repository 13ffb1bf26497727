"""The textures the fragment-pass solvers keep per node in a compact layout
(:class:`~deformgl.grid.nodes.CompactLayout`: node n at texel ``(n % width, n / width)``): RGBA32F
images of per-node values, and texture arrays of per-node tables four columns a layer
(neighbour numbers, spring weights, multipliers). Shared by
:class:`~deformgl.sim.backends.explicit_gpu.FragmentIntegrator`, the implicit Euler and XPBD
backends; every texture is owned by the caller's :class:`~deformgl.gl.resources.GLOwner`."""

from __future__ import annotations

import moderngl
import numpy as np

from deformgl.gl.resources import GLOwner

__all__ = ["compact_image", "float_texture", "layer_texture"]


def compact_image(size: tuple[int, int], values: np.ndarray) -> np.ndarray:
    """(H, W, 4) float32 image of ``size`` (W, H) holding row n of ``values`` (N, <= 4) at texel n;
    the rest 0."""
    w, h = size
    img = np.zeros((h * w, 4), np.float32)
    img[: len(values), : values.shape[1]] = values
    return img.reshape(h, w, 4)


def float_texture(owner: GLOwner, ctx: moderngl.Context, size: tuple[int, int],
                  image: np.ndarray | None = None) -> moderngl.Texture:
    """An RGBA32F texture of ``size`` (NEAREST, no wrap), from ``image`` or uninitialised."""
    data = None if image is None else np.ascontiguousarray(image, dtype="f4").tobytes()
    tex = owner.own(ctx.texture(size, 4, data, dtype="f4"))
    tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
    tex.repeat_x = tex.repeat_y = False
    return tex


def layer_texture(owner: GLOwner, ctx: moderngl.Context, size: tuple[int, int], table: np.ndarray,
                  dtype: str, layers: int | None = None) -> moderngl.TextureArray:
    """A texture array of ``size`` (W, H) holding the (N, C) ``table`` four columns a layer: layer
    l, channel c of texel n is ``table[n, 4 l + c]`` (``layers`` default ceil(C / 4); columns and
    texels beyond the table 0). ``dtype``: "i4" (RGBA32I) or "f4" (RGBA32F)."""
    w, h = size
    n = len(table)
    layers = -(-table.shape[1] // 4) if layers is None else layers
    kind = np.int32 if dtype == "i4" else np.float32
    padded = np.zeros((n, 4 * layers), kind)
    padded[:, : table.shape[1]] = table
    img = np.zeros((layers, h * w, 4), kind)
    img[:, :n, :] = padded.reshape(n, layers, 4).transpose(1, 0, 2)
    tex = owner.own(ctx.texture_array((w, h, layers), 4, img.tobytes(), dtype=dtype))
    tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
    return tex
