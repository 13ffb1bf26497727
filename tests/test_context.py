"""The headless context, its report, and programs that fail loudly."""

import pytest

from deformgl.gl import context as context_mod
from deformgl.gl.context import context_info, create_context, device_from_env
from deformgl.errors import GLError, ShaderError
from deformgl.gl.programs import Program


def test_context_is_gl33_core_and_info_reports_capabilities(ctx):
    assert ctx.version_code >= 330
    info = context_info(ctx)
    assert info.renderer and info.renderer != "?"
    assert info.max_texture_size >= 4096
    assert info.max_vertex_texture_units >= 1  # vertex texture fetch is what the mappings need
    assert info.rgba32f_render_target
    text = "\n".join(info.lines())
    for key in ("renderer:", "GL version:", "max texture size:", "vertex texture units:",
                "RGBA32F render targets: yes"):
        assert key in text


def test_device_from_env(monkeypatch):
    monkeypatch.delenv("DEFORMGL_DEVICE", raising=False)
    assert device_from_env(None) is None
    monkeypatch.setenv("DEFORMGL_DEVICE", "2")
    assert device_from_env(None) == 2
    assert device_from_env(0) == 0  # the flag wins over the environment
    monkeypatch.setenv("DEFORMGL_DEVICE", "gpu0")
    with pytest.raises(GLError, match="DEFORMGL_DEVICE='gpu0'"):
        device_from_env(None)


def test_missing_device_says_what_failed_and_what_to_install(ctx):
    with pytest.raises(GLError) as err:
        create_context(99)
    msg = str(err.value)
    assert "EGL device 99" in msg and "libegl1" in msg and "libgl1-mesa-dri" in msg
    assert "\n" not in msg


def test_egl_failure_is_a_glerror_not_a_traceback(monkeypatch):
    def broken(**kwargs):
        raise Exception("eglInitialize failed")

    monkeypatch.setattr(context_mod.moderngl, "create_standalone_context", broken)
    with pytest.raises(GLError, match="eglInitialize failed.*apt-get install libegl1 libgl1-mesa-dri"):
        create_context()


def test_unknown_uniform_names_program_and_uniform(ctx):
    prog = Program(ctx, "render/grid_surface.vert", "render/lit_surface.frag")
    try:
        prog.set(u_ambient=0.3)
        with pytest.raises(ShaderError, match=r"render/grid_surface.vert\+render/lit_surface.frag has no active uniform 'u_ambeint'"):
            prog.set(u_ambeint=0.3)
    finally:
        prog.release()


def test_compile_error_names_the_included_file(ctx, monkeypatch):
    from deformgl.gl import preprocessor as glsl

    real = glsl.read_shader_file

    def patched(name):
        if name == "lib/octahedral.glsl":
            return real(name) + "\nthis is not glsl;\n"
        return real(name)

    monkeypatch.setattr(glsl, "read_shader_file", patched)
    with pytest.raises(ShaderError, match=r"shaders/lib/octahedral.glsl:\d+: error"):
        Program(ctx, "render/grid_surface.vert", "render/lit_surface.frag")
