"""deformgl export-shaders: the pack as a standalone folder an application vendors. No GL."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import pytest

from deformgl.cli import main
from deformgl.gl.preprocessor import ES_PRECISION
from deformgl.pack.export_shaders import PACK_VERSION, export_shaders, pack_files
from deformgl.pack.variants import all_variants
from test_glslang import needs_glslang
from test_shader_sources import SHADERS

_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"\s*$', re.MULTILINE)


def resolve(folder, name, seen=None):
    """An application's own resolver: paste each include once."""
    seen = set() if seen is None else seen
    text = (folder / name).read_text(encoding="utf-8")

    def paste(m):
        if m.group(1) in seen:
            return ""
        seen.add(m.group(1))
        return resolve(folder, m.group(1), seen)
    return _INCLUDE.sub(paste, text)


@pytest.mark.parametrize("profile", ["core", "es"])
def test_the_folder_holds_every_shader_with_header_readme_and_version(tmp_path, profile):
    out = tmp_path / "pack"
    assert main(["export-shaders", str(out), "--profile", profile]) == 0
    files = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    assert files == sorted([*pack_files(), "README.md", "pack.json"])
    assert len(pack_files()) == len([p for p in SHADERS.rglob("*") if p.suffix in {".glsl", ".vert", ".frag"}])
    info = json.loads((out / "pack.json").read_text())
    assert (info["version"], info["profile"], info["license"]) == (PACK_VERSION, profile, "MIT")
    assert f"Pack version: **{PACK_VERSION}**" in (out / "README.md").read_text()
    for name in pack_files():
        text = (out / name).read_text()
        assert "SPDX-License-Identifier: MIT" in text.split("\n", 12)[-2] + text[:600], name
        if name.endswith((".vert", ".frag")):
            first = text.splitlines()[0]
            assert first == ("#version 330 core" if profile == "core" else "#version 300 es"), name
            if profile == "es":
                assert "precision highp float;" in text.splitlines()[1:3]


@needs_glslang
@pytest.mark.parametrize("profile", ["core", "es"])
def test_every_exported_stage_compiles_standalone(tmp_path, profile):
    """Resolved by the 15-line resolver above with one built variant's defines after the header:
    the reference compiler accepts each top-level file of the folder."""
    out = tmp_path / "pack"
    export_shaders(out, profile)
    first = {}
    for v in all_variants():
        for name in (v.vertex, v.fragment):
            if name:
                first.setdefault(name, v.define_map)
    work = tmp_path / "resolved"
    work.mkdir()
    paths = []
    for i, (name, defines) in enumerate(sorted(first.items())):
        lines = resolve(out, name).splitlines()
        head = 1 if profile == "core" else 1 + len(ES_PRECISION)  # #version (and the precision lines)
        defs = [f"#define {k}" if v is True else f"#define {k} {v}" for k, v in defines.items()
                if v is not False and v is not None]
        path = work / f"s{i}.{name.rsplit('.', 1)[1]}"
        path.write_text("\n".join(lines[:head] + defs + lines[head:]) + "\n")
        paths.append(path.name)
    assert len(paths) >= 20
    res = subprocess.run([shutil.which("glslangValidator"), *paths], cwd=work, capture_output=True, text=True)
    assert res.returncode == 0 and "ERROR" not in res.stdout and "WARNING" not in res.stdout, res.stdout[-2000:]


def test_bad_profile_and_a_file_in_the_way_are_one_line_errors(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["export-shaders", str(tmp_path / "x"), "--profile", "gles"])
    assert exc.value.code == 2
    (tmp_path / "file").write_text("x")
    assert main(["export-shaders", str(tmp_path / "file")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("deformgl: error: ") and "not a folder" in err[-1]
