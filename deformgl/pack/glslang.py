"""Validate program variants with the Khronos reference compiler, ``glslangValidator``.

Each stage of each :class:`~deformgl.pack.variants.Variant` is preprocessed by deformgl's own
preprocessor (:func:`deformgl.gl.preprocessor.preprocess`) in a profile (``core``: GLSL 3.30,
``es``: GLSL ES 3.00) and compiled by ``glslangValidator`` (Debian ``glslang-tools``). Defines a
file never mentions cannot change it, so a stage is compiled once per distinct set of the
defines it mentions. Programs are linked (``-l``: vertex outputs against fragment inputs; the ES
profile's vertex-only programs with ``lib/empty.frag``) once per pair of files and values of the
defines both stages mention (only those can make the two sides' interfaces disagree; a link is a process of its own, and
the thousands of integrator variants, whose vertex stage mentions no define, link once; every
stage source is compiled). Any error or warning is reported.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import tempfile
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

from deformgl.errors import InputError
from deformgl.gl.preprocessor import preprocess
from deformgl.gl.programs import ES_EMPTY_FRAGMENT
from deformgl.pack.variants import Variant

__all__ = ["ES_EMPTY_FRAGMENT", "Report", "glslang_path", "validate"]

_IDENT = re.compile(r"\b[A-Z_][A-Z0-9_]*\b")
_BATCH = 150  # files per glslangValidator call


def glslang_path() -> str:
    """The ``glslangValidator`` executable; InputError with the install line when absent."""
    path = shutil.which("glslangValidator")
    if path is None:
        raise InputError("glslangValidator not found: install it (Debian/Ubuntu: apt-get install glslang-tools)")
    return path


@lru_cache(maxsize=None)
def _mentioned(name: str, profile: str) -> frozenset[str]:
    """Upper-case identifiers in a file and its includes (the defines it can depend on)."""
    return frozenset(_IDENT.findall(preprocess(name, {}, profile).text))


def stage_defines(name: str, defines: dict[str, object], profile: str) -> tuple[tuple[str, object], ...]:
    """The defines of ``defines`` that file ``name`` (with its includes) mentions."""
    used = _mentioned(name, profile)
    return tuple(sorted((k, v) for k, v in defines.items() if k in used and v is not False and v is not None))


def _stages(v: Variant, profile: str) -> list[tuple[str, tuple[tuple[str, object], ...]]]:
    d = v.define_map
    frag = v.fragment or (ES_EMPTY_FRAGMENT if profile == "es" else None)
    out = [(v.vertex, stage_defines(v.vertex, d, profile))]
    if frag:
        out.append((frag, stage_defines(frag, d, profile)))
    return out


@dataclass
class Report:
    """What :func:`validate` found: counts and every message (``label: line``)."""

    profile: str
    programs: int = 0
    stage_sources: int = 0
    linked: int = 0
    problems: list[str] = field(default_factory=list)


def _run(exe: str, args: list[str], cwd: str) -> str:
    res = subprocess.run([exe, *args], cwd=cwd, capture_output=True, text=True, timeout=600)
    return res.stdout + res.stderr


def _findings(output: str, labels: dict[str, str]) -> list[str]:
    """Error and warning lines of a glslangValidator output, prefixed by the variant label of the
    file they follow."""
    found, current = [], "?"
    for line in output.splitlines():
        s = line.strip()
        if s in labels:
            current = labels[s]
            continue
        if re.match(r"(ERROR|WARNING|error|warning)\b", s) or "ERROR:" in s or "WARNING:" in s:
            found.append(f"{current}: {s}")
    return found


def validate(variants: Iterable[Variant], profile: str = "core", *, jobs: int = 2) -> Report:
    """Compile every distinct stage source and link every distinct program of ``variants``."""
    exe = glslang_path()
    report = Report(profile)
    sources: dict[tuple, str] = {}
    programs: dict[tuple, list[tuple]] = {}
    for v in variants:
        report.programs += 1
        stages = _stages(v, profile)
        for st in stages:
            sources.setdefault(st, "")
        if len(stages) > 1:
            (vname, vdef), (fname, fdef) = stages
            both = _mentioned(vname, profile) & _mentioned(fname, profile)
            shared = tuple((k, val) for k, val in vdef + fdef if k in both)
            programs.setdefault((vname, fname, shared), stages)
    report.stage_sources, report.linked = len(sources), len(programs)
    with tempfile.TemporaryDirectory(prefix="deformgl-glslang-") as tmp:
        names: dict[tuple, str] = {}
        labels: dict[str, str] = {}
        for i, (name, defines) in enumerate(sources):
            ext = name.rsplit(".", 1)[1]
            fname = f"s{i}.{ext}"
            Path(tmp, fname).write_text(preprocess(name, dict(defines), profile).text, encoding="utf-8")
            names[(name, defines)] = fname
            labels[fname] = f"{profile} {name} [{' '.join(k if v is True else f'{k}={v}' for k, v in defines)}]"
        files = list(names.values())
        batches = [["--enhanced-msgs", *files[i:i + _BATCH]] for i in range(0, len(files), _BATCH)]
        links = [["-l", *(names[st] for st in stages)] for stages in programs.values()]
        with ThreadPoolExecutor(max(1, jobs)) as pool:
            outputs = list(pool.map(lambda a: (a, _run(exe, a, tmp)), batches + links))
        for args, output in outputs:
            link = args[0] == "-l"
            if link:
                lab = {f: labels[f] for f in args[1:]}
                found = _findings(output, lab)
                report.problems += [f"link {' + '.join(lab.values())}: {f}" for f in found]
            else:
                report.problems += _findings(output, labels)
    return report
