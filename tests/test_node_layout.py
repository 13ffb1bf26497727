"""One node layout for every pass: no shader outside the layout's library computes where a node's
state lives. ``shaders/lib/node_texel.glsl`` is the one place that turns a node number (and a slot)
into a texel (``node_texel``, ``node_slot_texel``, ``slot_texel``, ``width_texel``, ``row_texel``)
and back (``texel_node``); ``deformgl.grid.nodes.layout_uniforms`` is the one place that sets its
uniform. No GL needed.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from deformgl.grid.nodes import CompactLayout, layout_uniforms
from deformgl.sim.census import NodeCensus

ROOT = Path(__file__).resolve().parent.parent
SHADERS = ROOT / "shaders"
GLSL_SUFFIXES = {".glsl", ".vert", ".frag"}

#: The layout's own library: the one place a texel is computed from a node number.
LAYOUT_LIBRARIES = {"lib/node_texel.glsl"}

#: Texel arithmetic on node numbers: a row's width in a ``%`` or ``/`` (the feedback backend's
#: NODE_ROW and SPRING_ROW, the census's row, a texture's width or size), a shift by a width's
#: log2, texels per node (slots) multiplied in, an x | y << 16 texel code unpacked.
NODE_TEXEL_ARITHMETIC = [
    re.compile(r"[%/]\s*\(?\s*(NODE_ROW|SPRING_ROW|\w*_ROW)\b"),
    re.compile(r"[%/*]\s*u_\w*(row|width)\b"),
    re.compile(r"\bu_\w*(row|width)\s*[%/*+]"),
    re.compile(r"(<<|>>)\s*\(?\s*u_\w*width_log2"),
    re.compile(r"\(\s*1\s*<<\s*u_\w*\)\s*-\s*1"),
    re.compile(r"\bu_\w*slots\s*\*|\*\s*u_\w*slots\b"),
    re.compile(r"[%/]\s*(size|textureSize\s*\([^)]*\))\.x\b"),
    re.compile(r"&\s*0xffff\b"),
]

_COMMENT = re.compile(r"//[^\n]*|/\*.*?\*/", re.DOTALL)


def computed_texels(source: str) -> list[str]:
    """The code lines of a GLSL source (comments removed) that compute a node's texel."""
    code = _COMMENT.sub("", source)
    return [line.strip() for line in code.splitlines()
            if any(p.search(line) for p in NODE_TEXEL_ARITHMETIC)]


def shader_files() -> list[Path]:
    return sorted(p for p in SHADERS.rglob("*") if p.suffix in GLSL_SUFFIXES)


# Lines the passes held before they read node state through the layout's functions (the
# feedback state and cell table, its node and spring tables, the census, a multigrid level,
# the premap's texel codes): the scan must find each of them.
BEFORE = [
    "    return texelFetch(tex, ivec2(k * (node % NODE_ROW) + s, node / NODE_ROW), 0);",
    "    ivec2 base = ivec2(7 * (i % NODE_ROW), i / NODE_ROW);",
    "    return texelFetch(u_nodes, ivec2(n % NODE_ROW, n / NODE_ROW), 0);",
    "        ivec2 st = ivec2(e % SPRING_ROW, e / SPRING_ROW);",
    "    if (node.y * u_row + node.x >= u_count) discard;",
    "    vec4 x = texelFetch(u_state, ivec2(u_slots * node.x + u_slot, node.y), 0);",
    "    vec3 b = texelFetch(u_before, ivec2(u_before_slots * node.x + u_before_slot, node.y), 0).xyz;",
    "    return ivec2(n & ((1 << u_src_width_log2) - 1), n >> u_src_width_log2);",
    "    return ivec2(code & 0xffff, code >> 16);",
    "    int n = texel.y * size.x + texel.x; ivec2 t = ivec2(m % size.x, m / size.x);",
]


@pytest.mark.parametrize("line", BEFORE)
def test_the_scan_finds_texel_arithmetic(line):
    assert computed_texels(line) == [line.strip()]


def test_the_scan_passes_layout_calls_and_comments():
    ok = ("ivec2 t = node_slot_texel(n, 7, s);\n"
          "ivec2 st = row_texel(e, SPRING_ROW);\n"
          "if (texel_node(node) >= u_count) discard;  // node n at (n % NODE_ROW, n / NODE_ROW)\n"
          "/* slot s at (K * (n % NODE_ROW) + s, n / NODE_ROW) */\n"
          "vec4 x = texelFetch(u_state, slot_texel(node, u_slots, u_slot), 0);\n")
    assert computed_texels(ok) == []


def test_no_pass_computes_a_node_texel_itself():
    offenders = {}
    for path in shader_files():
        name = path.relative_to(SHADERS).as_posix()
        if name in LAYOUT_LIBRARIES:
            continue
        found = computed_texels(path.read_text())
        if found:
            offenders[name] = found
    assert not offenders, ("node texels computed outside lib/node_texel.glsl (call node_texel, "
                           f"node_slot_texel, slot_texel, width_texel or row_texel): {offenders}")


def test_the_layout_library_defines_every_function():
    src = (SHADERS / "lib/node_texel.glsl").read_text()
    for fn in ("ivec2 node_texel(int n)", "int texel_node(ivec2 texel)", "ivec2 node_slot_texel(int n, int slots, int slot)",
               "ivec2 slot_texel(ivec2 node, int slots, int slot)", "ivec2 width_texel(int i, int width_log2)",
               "ivec2 row_texel(int i, int row)", "ivec2 packed_texel(int code)"):
        assert fn in src, fn


def test_layout_uniforms_is_the_log2_of_the_compact_layouts_width():
    index = -__import__("numpy").ones((7, 5, 3), int)
    index.ravel()[:100] = range(100)
    layout = CompactLayout(index, 100, 16)
    assert layout_uniforms(16) == {"u_width_log2": 4}
    assert layout.shader_uniforms()["u_width_log2"] == 4
    assert layout_uniforms(1024, prefix="u_src_") == {"u_src_width_log2": 10}
    assert layout_uniforms(1) == {"u_width_log2": 0}


@pytest.mark.parametrize("width", [0, 3, 12, -4])
def test_layout_uniforms_refuses_a_width_not_a_power_of_two(width):
    with pytest.raises(ValueError, match=f"layout_uniforms: a node texture {width} texels wide"):
        layout_uniforms(width)


def test_the_census_reads_the_node_layout_and_refuses_another_row(ctx):
    with pytest.raises(ValueError, match="NodeCensus: row 12: the node layout's width is a power of two"):
        NodeCensus(ctx, count=30, row=12)


def test_the_copy_study_reports_the_gain_and_the_steps_a_copy_costs():
    from studies.layout_copy import format_rows

    row = {"grid": "heart", "nodes": 24537, "block": (2, 2, 1),
           "times": {"compact": [5.0, 4.0, 6.0], "blocked": [3.0, 3.0, 4.0], "copy": [0.5, 0.4, 0.6],
                     "census": [0.2, 0.3, 0.25], "draw": [14.0, 15.0, 16.0]}}
    text = format_rows([row], "machine", 3)
    assert text.splitlines()[0] == "machine"
    line = text.splitlines()[2]
    # gains 2, 1, 2 ms/step; copies 0.5, 0.4, 0.6 ms: 0.25, 0.4, 0.3 steps' gain
    assert "blocks 2x2x1" in line and "gain 2.000 (1.000-2.000)" in line
    assert "copy 0.500 (0.400-0.600) = 0.3 steps' gain" in line and "mapped draw 15.000 (14.000-16.000)" in line
