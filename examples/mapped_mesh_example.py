"""Draw a mapped detailed mesh with deformgl's shader pack and moderngl only (no deformgl import).

Usage: python examples/mapped_mesh_example.py SHADERS_DIR INPUTS.npz OUT.png

INPUTS.npz holds what any application would have (``deformgl render ... --pack-inputs`` writes
one): ``state`` (H, W, 4) float32, the node state texture (xyz position, w packed normal);
per-vertex attributes ``texel1..3`` (V, 2) int32, ``weights``, ``offset``, ``offset_world``,
``normal``, ``normal_world`` (V, 3) float32, ``curvature`` (V,) float32 (1 = eq. 8 basis);
``faces`` (F, 3) int32; ``view_projection`` (4, 4) float32 row-major; ``eye`` (3,);
``light_direction``, ``light_colour``, ``material_colour`` (3,); ``ambient``, ``specular``,
``shininess`` scalars; ``size`` (2,) int; ``background`` (3,).
See shaders/README.md for the contract of each shader.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import moderngl
import numpy as np
from PIL import Image


def load_source(shaders: Path, name: str, defines: dict[str, str]) -> str:
    """Resolve ``#include "x"`` (each file once) and put defines after ``#version``."""
    seen: set[str] = set()

    def expand(rel: str) -> list[str]:
        out = []
        for line in (shaders / rel).read_text().splitlines():
            m = re.match(r'\s*#\s*include\s+"([^"]+)"', line)
            if m:
                if m.group(1) not in seen:
                    seen.add(m.group(1))
                    out += expand(m.group(1))
            else:
                out.append(line)
        return out

    lines = expand(name)
    return "\n".join([lines[0], *[f"#define {k} {v}" for k, v in defines.items()], *lines[1:]]) + "\n"


def main(shaders: Path, inputs: Path, out: Path) -> None:
    d = np.load(inputs)
    ctx = moderngl.create_standalone_context(backend="egl", require=330)
    h, w, _ = d["state"].shape
    state = ctx.texture((w, h), 4, np.ascontiguousarray(d["state"], dtype="f4").tobytes(), dtype="f4")
    state.filter = (moderngl.NEAREST, moderngl.NEAREST)
    defines = {"CURVATURE": "1"} if np.any(d["curvature"] > 0.5) else {}
    prog = ctx.program(vertex_shader=load_source(shaders, "render/mapped_mesh.vert", defines),
                       fragment_shader=load_source(shaders, "render/mapped_mesh.frag", defines))
    names = ["texel1", "texel2", "texel3", "weights", "offset", "offset_world", "normal", "normal_world"]
    formats = ["2i", "2i", "2i", "3f", "3f", "3f", "3f", "3f"]
    if defines:
        names.append("curvature")
        formats.append("1f")
    buffers = [ctx.buffer(np.ascontiguousarray(d[n], dtype="i4" if f.endswith("i") else "f4").tobytes())
               for n, f in zip(names, formats)]
    ibo = ctx.buffer(np.ascontiguousarray(d["faces"], dtype="i4").tobytes())
    vao = ctx.vertex_array(prog, [(b, f, f"in_{n}") for b, f, n in zip(buffers, formats, names)],
                           index_buffer=ibo, index_element_size=4)
    prog["u_position"] = 0
    prog["u_view_projection"].write(np.ascontiguousarray(d["view_projection"].T, dtype="f4").tobytes())
    prog["u_eye"] = tuple(map(float, d["eye"]))
    for key in ("light_direction", "light_colour", "material_colour"):
        prog[f"u_{key}"] = tuple(map(float, d[key]))
    for key in ("ambient", "specular", "shininess"):
        prog[f"u_{key}"] = float(d[key])
    size = tuple(int(v) for v in d["size"])
    colour = ctx.renderbuffer(size, 4, samples=4)
    depth = ctx.depth_renderbuffer(size, samples=4)
    fbo = ctx.framebuffer(colour, depth)
    resolved = ctx.simple_framebuffer(size)
    fbo.use()
    fbo.clear(*map(float, d["background"]), 1.0, depth=1.0)
    ctx.enable(moderngl.DEPTH_TEST)
    state.use(0)
    vao.render(moderngl.TRIANGLES)
    ctx.copy_framebuffer(resolved, fbo)
    pixels = np.frombuffer(resolved.read(components=3, alignment=1), dtype=np.uint8)
    Image.fromarray(pixels.reshape(size[1], size[0], 3)[::-1]).save(out)


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    main(Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]))
