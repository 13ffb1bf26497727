"""Where the package data comes from: the installed packages ``deformgl.shaders`` and
``deformgl.scenes``, or, where deformgl is imported from a source checkout that is not what is
installed (``python -m studies.NAME`` from the repository root beside a non-editable install),
the checkout's own ``shaders/`` and ``scenes/`` folders."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from deformgl import data
from deformgl.errors import DeformglError
from deformgl.gl.preprocessor import read_shader_file

ROOT = Path(__file__).resolve().parents[1]


def test_a_checkout_imported_without_its_install_finds_its_own_shaders_and_scenes():
    """``python -S`` (no site-packages: no installed deformgl, no editable finder) with the
    checkout on the path: the data packages do not exist, the checkout's folders stand in."""
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import deformgl.data as d; "
            "from deformgl.gl.preprocessor import read_shader_file; "
            "print(d.package_folder('shaders')); print(d.scenes_dir()); "
            "print(len(read_shader_file('lib/node_texel.glsl')) > 0)")
    done = subprocess.run([sys.executable, "-S", "-c", code, str(ROOT)], capture_output=True, text=True,
                          timeout=60, cwd=ROOT / "tests")
    assert done.returncode == 0, done.stderr
    shaders, scenes, read = done.stdout.split()
    assert Path(shaders) == ROOT / "shaders" and Path(scenes) == ROOT / "scenes" and read == "True"


def test_the_data_folders_hold_what_the_wheel_ships():
    assert (Path(str(data.package_folder("shaders"))) / "lib" / "node_texel.glsl").is_file()
    assert "dragon.toml" in data.scene_names()
    assert read_shader_file("lib/node_texel.glsl").strip()


def test_the_wheel_lists_every_package_and_shader():
    """The wheel is built from pyproject.toml's explicit package list and data globs (an editable
    install would hide a missing one): every folder of deformgl/ with an __init__.py is listed, and
    every shader file matches a glob of the shaders' package data."""
    import fnmatch
    import tomllib

    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]
    packages = set(config["packages"])
    found = {".".join(f.parent.relative_to(ROOT).parts) for f in (ROOT / "deformgl").rglob("__init__.py")}
    assert found - packages == set(), "packages missing from pyproject.toml [tool.setuptools] packages"
    globs = config["package-data"]["deformgl.shaders"]
    for f in (ROOT / "shaders").rglob("*"):
        if f.is_file() and f.name != "__init__.py" and "__pycache__" not in f.parts:
            rel = f.relative_to(ROOT / "shaders").as_posix()
            assert any(fnmatch.fnmatch(rel, g) and rel.count("/") == g.count("/") for g in globs), rel


def test_missing_package_data_is_one_line_naming_it(monkeypatch):
    def no_package(name):
        raise ModuleNotFoundError(name)

    monkeypatch.setattr(data.resources, "files", no_package)
    with pytest.raises(DeformglError, match=r"deformgl\.nothing: the package data is missing"):
        data.package_folder("nothing")
