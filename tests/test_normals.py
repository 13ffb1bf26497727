"""Packed normals (eq. 3): round trip <= 0.5 degrees everywhere, exact float32 integers, GLSL == NumPy."""

import numpy as np
import pytest

from deformgl.glsl import read_shader_file
from deformgl.normals import NO_NORMAL, pack_normals, unpack_normals


def directions(n=200_000, seed=1):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    axes = np.concatenate([np.eye(3), -np.eye(3), [[1, 1, 0], [-1, 0, -1], [0, -1, -1e-9]]])
    v = np.concatenate([v, axes])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1.0, 1.0)))


def test_round_trip_error_below_half_degree_for_every_direction():
    v = directions()
    assert angle_deg(unpack_normals(pack_normals(v)), v).max() <= 0.5


def test_packed_values_are_exact_integers_below_2_24():
    p = pack_normals(directions())
    assert p.dtype == np.float32
    assert np.all(np.isfinite(p)) and np.all(p >= 0) and np.all(p < 2 ** 24)
    assert np.all(p == np.floor(p))
    # no denormals: every non-zero value is at least the smallest normal float32
    nz = p[p != 0]
    assert np.all(np.abs(nz) >= np.finfo(np.float32).tiny)


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
    # float32 vs float64 rounding may move a coordinate by one 12-bit level, never more
    qx, qy = np.divmod(code.astype(np.int64), 4096)
    rx, ry = np.divmod(ref.astype(np.int64), 4096)
    assert max(np.abs(qx - rx).max(), np.abs(qy - ry).max()) <= 1
    assert np.mean(code == ref) > 0.99
    assert angle_deg(n.astype(np.float64), v.astype(np.float64)).max() <= 0.5
    assert np.all(code == np.floor(code)) and np.all(code < 2 ** 24)
    for obj in (vao, out, vbo, prog, fbo):
        obj.release()
