"""Packed normals (Mosegaard & Sørensen 2005, eq. 3): round trip <= 0.5 degrees everywhere, exact float32 integers, GLSL == NumPy."""

import numpy as np
import pytest

from deformgl.gl.preprocessor import read_shader_file
from deformgl.sim.normals import LEVELS, NO_NORMAL, pack_normals, unpack_normals


def directions(n=200_000, seed=1):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    axes = np.concatenate([np.eye(3), -np.eye(3), [[1, 1, 0], [-1, 0, -1], [0, -1, -1e-9]]])
    v = np.concatenate([v, axes])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def angle_deg(a, b):
    """Angle between vectors, well conditioned near 0 (arccos of a float32 dot product is not)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.sum(a * b, axis=1)))


def test_round_trip_error_for_every_direction():
    v = directions()
    err = angle_deg(unpack_normals(pack_normals(v)), v)
    assert err.max() <= 0.5  # the foundation's requirement
    assert err.max() <= 0.006  # what 15.5 bits per octahedral coordinate give


def test_packed_values_are_normal_positive_floats():
    p = pack_normals(directions())
    assert p.dtype == np.float32
    assert np.all(np.isfinite(p)) and np.all(p > 0)
    # no denormals: every value is at least the smallest normal float32
    assert np.all(p >= np.finfo(np.float32).tiny)
    # and distinct directions keep distinct codes (no collapse through float conversion)
    assert len(np.unique(p)) > 0.99 * len(p)


def test_zero_sum_packs_no_normal_and_unpacks_to_zero():
    p = pack_normals(np.array([[0.0, 0.0, 0.0], [1e-9, 0, 0]]))
    assert np.all(p == NO_NORMAL)
    assert np.all(unpack_normals(p) == 0.0)


def test_length_does_not_matter():
    v = directions(1000)
    assert np.array_equal(pack_normals(v), pack_normals(v * 7.5))


GLSL_TEST = """#version 330 core
{lib}
in vec3 in_v;
out float out_code;
out vec3 out_n;
void main() {{
    out_code = pack_normal(in_v);
    out_n = unpack_normal(out_code);
}}
"""


def test_glsl_packing_matches_numpy_and_round_trips(ctx):
    v = directions(50_000, seed=3).astype("f4")
    prog = ctx.program(vertex_shader=GLSL_TEST.format(lib=read_shader_file("lib/octahedral.glsl")),
                       varyings=["out_code", "out_n"])
    vbo = ctx.buffer(v.tobytes())
    out = ctx.buffer(reserve=len(v) * 16)
    vao = ctx.vertex_array(prog, [(vbo, "3f", "in_v")])
    # Mesa skips every draw, transform feedback included, while no complete framebuffer is bound
    fbo = ctx.simple_framebuffer((1, 1))
    fbo.use()
    vao.transform(out, vertices=len(v))
    res = np.frombuffer(out.read(), dtype="f4").reshape(-1, 4)
    code, n = res[:, 0], res[:, 1:]
    ref = pack_normals(v.astype(np.float64))
    # float32 vs float64 rounding may move a coordinate by one quantisation level, never more
    steps = LEVELS + 1
    c = code.view(np.uint32).astype(np.int64) - (1 << 23)
    r = ref.view(np.uint32).astype(np.int64) - (1 << 23)
    assert max(np.abs(c // steps - r // steps).max(), np.abs(c % steps - r % steps).max()) <= 1
    assert np.mean(code == ref) > 0.9
    assert angle_deg(n.astype(np.float64), v.astype(np.float64)).max() <= 0.006
    assert np.all(code >= np.finfo(np.float32).tiny) and np.all(np.isfinite(code))
    for obj in (vao, out, vbo, prog, fbo):
        obj.release()


def test_codes_survive_a_float32_render_target_bit_exactly(ctx):
    """Write codes through a fragment shader into an RGBA32F target and read the bits back."""
    codes = pack_normals(directions(4096, seed=5))[:4096]
    tex_in = ctx.texture((64, 64), 1, codes.tobytes(), dtype="f4")
    tex_out = ctx.texture((64, 64), 4, dtype="f4")
    fbo = ctx.framebuffer([tex_out])
    prog = ctx.program(vertex_shader="""#version 330 core
void main() { gl_Position = vec4(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0, 0.0, 1.0); }""",
                       fragment_shader="""#version 330 core
uniform sampler2D u_in; out vec4 o;
void main() { o = vec4(0.0, 0.0, 0.0, texelFetch(u_in, ivec2(gl_FragCoord.xy), 0).r); }""")
    vao = ctx.vertex_array(prog, [])
    fbo.use()
    tex_in.use(0)
    prog["u_in"] = 0
    vao.render(vertices=3)
    out = np.frombuffer(tex_out.read(), dtype="f4").reshape(-1, 4)[:, 3]
    assert np.array_equal(out.view(np.uint32), codes.view(np.uint32))
    for obj in (vao, prog, fbo, tex_out, tex_in):
        obj.release()
