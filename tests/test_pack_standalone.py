"""The exported shader pack is a reference an application can start from (issue 26, item 3).

Every stage of the pack that ``deformgl export-shaders OUT --profile core|es`` writes, taken the
way the pack's README tells an application (paste each ``#include``, once per stage; its own
``#define``s after the header lines) with no ``#define`` of the application's own, compiles in the
Khronos reference compiler: every define a stage needs has a default in the pack, every uniform is
declared. No GL; needs glslangValidator (Debian glslang-tools, an optional system tool).
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from deformgl.pack.export_shaders import export_shaders, pack_files
from test_glslang import needs_glslang

#: Stage files by extension, as glslangValidator picks the stage.
STAGE_SUFFIXES = (".vert", ".frag", ".geom")
_INCLUDE = re.compile(r'^[ \t]*#[ \t]*include[ \t]+"([^"]+)"[ \t]*$', re.MULTILINE)


def paste_includes(folder: Path, name: str, pasted: set[str] | None = None) -> str:
    """The README's words, and nothing of deformgl's own preprocessor: each ``#include "x"`` line
    is replaced by the text of ``x`` from the pack folder (with its own includes pasted), and an
    include already pasted into this stage by nothing."""
    pasted = set() if pasted is None else pasted

    def paste(m: re.Match[str]) -> str:
        target = m.group(1)
        if target in pasted:
            return ""
        pasted.add(target)
        return paste_includes(folder, target, pasted)

    return _INCLUDE.sub(paste, (folder / name).read_text(encoding="utf-8"))


def standalone_failures(out: Path, work: Path) -> tuple[list[str], dict[str, str]]:
    """Compile every stage file of the exported pack in ``out`` on its own, includes pasted, no
    define added; returns the stages and, for each that fails, the compiler's errors/warnings."""
    exe = shutil.which("glslangValidator")
    assert exe is not None
    work.mkdir(parents=True, exist_ok=True)
    stages = [n for n in pack_files() if n.endswith(STAGE_SUFFIXES)]
    failures = {}
    for i, name in enumerate(stages):
        path = work / f"s{i}{Path(name).suffix}"
        path.write_text(paste_includes(out, name), encoding="utf-8")
        res = subprocess.run([exe, path.name], cwd=work, capture_output=True, text=True, timeout=120)
        found = [line.strip() for line in (res.stdout + res.stderr).splitlines()
                 if "ERROR" in line or "WARNING" in line]
        if res.returncode != 0 or found:
            failures[name] = "\n    ".join(found[:4]) or f"exit status {res.returncode}"
    return stages, failures


@needs_glslang
@pytest.mark.parametrize("profile", ["core", "es"])
def test_every_exported_stage_compiles_with_no_define_of_the_application(tmp_path, profile):
    out = tmp_path / "pack"
    export_shaders(out, profile)
    stages, failures = standalone_failures(out, tmp_path / "resolved")
    exported = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.suffix in STAGE_SUFFIXES)
    assert sorted(stages) == exported and len(stages) >= 30
    assert not failures, (f"{len(failures)} of {len(stages)} exported {profile} stages fail to compile "
                          "standalone:\n" + "\n".join(f"{k}:\n    {v}" for k, v in failures.items()))


def test_the_resolver_follows_the_readme(tmp_path):
    """Pasted once per stage, nested includes too; a stage's other lines untouched."""
    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / "a.glsl").write_text('#include "lib/b.glsl"\nfloat a() { return b(); }\n')
    (tmp_path / "lib" / "b.glsl").write_text("float b() { return 1.0; }\n")
    (tmp_path / "s.frag").write_text('#version 330 core\n#include "lib/a.glsl"\n  #include "lib/b.glsl"\nvoid main() {}\n')
    text = paste_includes(tmp_path, "s.frag")
    assert text.count("float b()") == 1 and text.count("float a()") == 1 and "#include" not in text
    assert text.startswith("#version 330 core\nfloat b()") and text.endswith("void main() {}\n")
