"""Shader preprocessor: includes, defines, line numbers, errors. No GL needed."""

import pytest

from deformgl.gl import preprocessor as glsl
from deformgl.errors import ShaderError


@pytest.fixture
def shader_files(monkeypatch):
    files = {}

    def fake_read(name):
        if name not in files:
            raise ShaderError(f"shaders/{name}: no such shader file in the deformgl package")
        return files[name]

    monkeypatch.setattr(glsl, "read_shader_file", fake_read)
    return files


def test_defines_injected_after_version_with_line_directive(shader_files):
    shader_files["a.frag"] = "#version 330 core\nvoid main() {}\n"
    src = glsl.preprocess("a.frag", {"FOO": True, "N": 3, "OFF": False})
    lines = src.text.splitlines()
    assert lines[0] == "#version 330 core"
    assert lines[1:3] == ["#define FOO", "#define N 3"]
    assert lines[3] == "#line 2 0"
    assert "OFF" not in src.text


def test_include_gets_own_source_number_and_parent_line_restored(shader_files):
    shader_files["a.frag"] = "#version 330 core\n#include \"lib/b.glsl\"\nfloat x;\n"
    shader_files["lib/b.glsl"] = "float b;\n"
    src = glsl.preprocess("a.frag")
    lines = src.text.splitlines()
    i = lines.index("#line 1 1")
    assert lines[i + 1] == "float b;"
    assert lines[i + 2] == "#line 3 0"
    assert src.files == ["a.frag", "lib/b.glsl"]


def test_include_once_and_nested(shader_files):
    shader_files["a.frag"] = '#version 330\n#include "b.glsl"\n#include "c.glsl"\n'
    shader_files["b.glsl"] = '#include "c.glsl"\nfloat b;\n'
    shader_files["c.glsl"] = "float c;\n"
    text = glsl.preprocess("a.frag").text
    assert text.count("float c;") == 1
    assert text.index("float c;") < text.index("float b;")


def test_missing_include_names_both_files_and_line(shader_files):
    shader_files["a.frag"] = '#version 330\nfloat a;\n#include "lib/nope.glsl"\n'
    with pytest.raises(ShaderError, match=r'shaders/a.frag:3: cannot resolve #include "lib/nope.glsl".*shaders/lib/nope.glsl'):
        glsl.preprocess("a.frag")


def test_version_must_be_first_line(shader_files):
    shader_files["a.frag"] = "// comment\n#version 330\n"
    with pytest.raises(ShaderError, match="#version must be the first line"):
        glsl.preprocess("a.frag")


def test_include_depth_is_capped(shader_files):
    shader_files["a.frag"] = '#version 330\n#include "d0.glsl"\n'
    for i in range(glsl.MAX_INCLUDE_DEPTH + 2):
        shader_files[f"d{i}.glsl"] = f'#include "d{i + 1}.glsl"\n'
    with pytest.raises(ShaderError, match="nesting deeper"):
        glsl.preprocess("a.frag")


def test_explain_log_maps_source_numbers_to_files(shader_files):
    shader_files["a.frag"] = '#version 330\n#include "lib/b.glsl"\n'
    shader_files["lib/b.glsl"] = "x\n"
    src = glsl.preprocess("a.frag")
    assert src.explain_log("1:1(2): error: syntax error") == "shaders/lib/b.glsl:1: error: syntax error"
    assert src.explain_log("0:7(1): error: x").startswith("shaders/a.frag:7:")


def test_bad_define_name_rejected():
    with pytest.raises(ShaderError, match="invalid #define"):
        glsl.format_defines({"1BAD": True})


def test_real_shader_files_ship_in_the_package():
    # Read through importlib.resources: works only if the files are package data.
    text = glsl.read_shader_file("sim/verlet.frag")
    assert text.startswith("#version 330")
    full = glsl.preprocess("sim/verlet.frag", {"PULLS": 0}).text
    assert "vec3 unpack_normal" in full and "SpringSum spring_sum" in full


def test_every_shader_file_of_the_source_tree_is_in_the_installed_package():
    from importlib import resources
    from pathlib import Path

    source = Path(__file__).resolve().parent.parent / "shaders"
    wanted = {p.relative_to(source).as_posix() for p in source.rglob("*")
              if p.is_file() and p.suffix in {".glsl", ".vert", ".frag", ".geom"}}
    assert wanted, "no shader files found in the source tree"
    root = resources.files("deformgl.shaders")
    missing = [name for name in sorted(wanted) if not root.joinpath(*name.split("/")).is_file()]
    assert not missing, f"shader files not shipped in the package: {missing}"


@pytest.mark.parametrize("name, defines", [
    ("sim/integrators/step.frag", {"EULER": True, "NB_LAYERS": 5, "NB_COUNT": 18, "SPRING_DAMPING": True}),
    ("sim/integrators/step.frag", {"VERLET": True, "DENSE": True, "NB_LAYERS": 5, "NB_COUNT": 18}),
    ("feedback/euler.vert", {"NODE_ROW": 64, "SPRING_ROW": 64, "SPRING_DAMPING": True}),
    ("sim/verlet.frag", {"PULLS": 0, "COMPACT": True}),
    ("studies/step_ablation.frag", {"STAGE": 4, "DENSE": True}),
])
def test_shared_helpers_come_from_one_library_file(name, defines):
    """node_texel and spring_force are defined once, in shaders/lib/, and pasted once per program."""
    chunks = {}
    if name == "studies/step_ablation.frag":  # (the step profile's own shader, out of the package)
        from studies.step_profile import ablation_source

        chunks = {name: ablation_source()}
    src = glsl.preprocess(name, defines, chunks=chunks)
    own = chunks[name] if chunks else glsl.read_shader_file(name)
    for helper, lib in (("ivec2 node_texel(", "lib/node_texel.glsl"), ("vec3 spring_force(", "lib/spring_force.glsl")):
        count = src.text.count(helper)
        if lib in src.files:
            assert count == 1, (name, helper)
            assert helper not in own
        else:
            assert count == 0, (name, helper)
    assert "lib/node_texel.glsl" in src.files or name.startswith("feedback/")
