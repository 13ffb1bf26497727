"""``deformgl export-shaders OUT --profile core|es``: the shader pack as a standalone folder.

The folder holds every shader file of ``deformgl.shaders`` in its sub-folders, each with a
license header, top-level stage files (``.vert``, ``.frag``) headed by the profile's ``#version``
line (and, for ``es``, the precision statements of
:data:`deformgl.gl.preprocessor.ES_PRECISION`), the contract ``README.md`` and ``pack.json``
(pack version, profile, files). An application vendors it without deformgl: it pastes each
``#include "x"`` (once per program) and puts its ``#define``s right after the header lines, as
``README.md`` says. Written as one :class:`~deformgl.files.OutputSet`: all files or none.
"""

from __future__ import annotations

import argparse
import json
from importlib.resources.abc import Traversable
from pathlib import Path

from deformgl.data import package_folder
from deformgl.errors import InputError
from deformgl.files import OutputSet, write_atomic
from deformgl.gl.preprocessor import ES_PRECISION, PROFILES, read_shader_file

__all__ = ["LICENSE_HEADER", "PACK_VERSION", "add_parser", "export_shaders", "pack_files", "shader_text"]

#: The pack's version: the major number changes when an input, output or define of a shader
#: changes incompatibly, the minor one when the pack gains something compatibly (1.2.0: every
#: define has a default, so every stage compiles standalone; 1.3.0: the lattice's volumetric
#: term, CELLS, CELL_CENTRE, CELL_BARRIER, sim/cells/; 2.0.0: the physics terms as chunks,
#: terms/active.glsl, terms/feedback.glsl, terms/xpbd.glsl with TERMS, TERM_<PREFIX>,
#: FEEDBACK_TERMS and XPBD_TERMS in place of CELLS, every term's files under terms/; 3.0.0: the
#: compact layout only, no z-slice atlas, NEIGHBOUR_BRANCH, DRAW_POINTS, sim/node_points.vert or
#: sim/node_rects.vert; 3.1.0: the spline cells and their anchor, terms/spline*.{glsl,frag},
#: render/bspline_premap.frag,
#: TERM_SPLINE, texel_item_slot); shaders/README.md states it too, a test keeps them equal.
PACK_VERSION = "3.1.0"
LICENSE_HEADER = ("// deformgl shader pack {version}, profile {profile} (GLSL {language}).\n"
                  "// SPDX-License-Identifier: MIT. Copyright (c) the deformgl authors.\n"
                  "// Contract (inputs, outputs, defines, extensions): README.md of this folder.\n")
_SUFFIXES = (".glsl", ".vert", ".frag", ".geom")
_LANGUAGE = {"core": "3.30 core", "es": "ES 3.00"}


def _walk(node: Traversable, prefix: str) -> list[str]:
    out = []
    for child in sorted(node.iterdir(), key=lambda c: c.name):
        name = f"{prefix}{child.name}"
        if child.is_dir() and not child.name.startswith("__"):
            out += _walk(child, name + "/")
        elif child.is_file() and child.name.endswith(_SUFFIXES):
            out.append(name)
    return out


def pack_files() -> list[str]:
    """Every shader file of the pack, relative to the shaders folder, sorted."""
    return _walk(package_folder("shaders"), "")


def shader_text(name: str, profile: str) -> str:
    """The exported text of ``shaders/<name>`` in ``profile``."""
    if profile not in PROFILES:
        raise InputError(f"--profile: {profile!r} is not one of {', '.join(PROFILES)}")
    text = read_shader_file(name)
    header = LICENSE_HEADER.format(version=PACK_VERSION, profile=profile, language=_LANGUAGE[profile])
    lines = text.splitlines()
    if lines and lines[0].lstrip().startswith("#version"):
        head = [lines[0]] if profile == "core" else ["#version 300 es", *ES_PRECISION]
        return "\n".join([*head, header.rstrip("\n"), *lines[1:]]) + "\n"
    return header + text


def _write(path: Path, text: str) -> None:
    data = text.encode("utf-8")
    write_atomic(path, lambda f: f.write(data))


def pack_contents(out: Path, profile: str) -> dict[Path, str]:
    """Every file of the pack in folder ``out`` (its folders created) and its text."""
    if profile not in PROFILES:
        raise InputError(f"--profile: {profile!r} is not one of {', '.join(PROFILES)}")
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    names = pack_files()
    targets = {name: out / name for name in names}
    meta, readme = out / "pack.json", out / "README.md"
    for path in {p.parent for p in targets.values()}:
        path.mkdir(parents=True, exist_ok=True)
    contract = package_folder("shaders").joinpath("README.md").read_text(encoding="utf-8")
    info = {"name": "deformgl shader pack", "version": PACK_VERSION, "profile": profile,
            "language": f"GLSL {_LANGUAGE[profile]}", "license": "MIT", "files": names}
    files = {path: shader_text(name, profile) for name, path in targets.items()}
    files[readme] = contract
    files[meta] = json.dumps(info, indent=1) + "\n"
    return files


def write_pack(files: dict[Path, str]) -> None:
    """Write :func:`pack_contents` (atomically each; in the active output set, if any)."""
    for path, text in files.items():
        _write(path, text)


def export_shaders(out: Path, profile: str) -> list[Path]:
    """Write the pack into folder ``out`` (created), all files or none; returns the files written."""
    files = pack_contents(out, profile)
    with OutputSet(list(files), "shader pack file"):
        write_pack(files)
    return list(files)


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Adds ``export-shaders`` to a CLI's subparsers."""
    p = subparsers.add_parser(
        "export-shaders", help="write the shader pack as a standalone folder (core or es profile)",
        description="Write every shader of the pack, with a license header, the contract README.md "
                    "and pack.json, into OUT: GLSL 3.30 core (--profile core) or GLSL ES 3.00 for "
                    "WebGL2 / OpenGL ES 3 (--profile es). All files or none are written.")
    p.add_argument("out", type=Path, metavar="OUT", help="output folder (created)")
    p.add_argument("--profile", choices=PROFILES, default="core", help="shader language profile (default core)")
    return p


def run(args: argparse.Namespace) -> int:
    files = export_shaders(args.out, args.profile)
    print(f"wrote {len(files)} files of shader pack {PACK_VERSION} ({args.profile}) to {args.out}")
    return 0
