"""The wheel works installed: built from the checkout, installed into a fresh virtual environment
and run from a folder outside the checkout, its shipped scenes and meshes are found.

The fresh environment reuses this one's dependencies (a ``.pth`` line naming this environment's
site-packages, which does not run its editable-install hook; the wheel is installed with
``--ignore-installed`` and comes first on the path, so a deformgl installed there is not used),
so the test needs no network beyond what building the wheel needs (setuptools and wheel, from
the package index).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: What building the wheel reads from the checkout.
SOURCES = ("pyproject.toml", "README.md", "deformgl", "shaders", "scenes")


def _run(cmd: list[str], cwd: Path, env: dict[str, str], timeout: float = 120) -> subprocess.CompletedProcess:
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{' '.join(map(str, cmd))} failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict[str, str]]:
    """(bin folder of the fresh venv, a working folder outside the checkout, environment)."""
    base = tmp_path_factory.mktemp("installed")
    src = base / "src"
    src.mkdir()
    for name in SOURCES:  # a copy, so the build writes nothing into the checkout
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy2(ROOT / name, src / name)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
    env["DEFORMGL_CACHE_DIR"] = str(base / "cache")
    wheels = base / "wheels"
    _run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", str(wheels), str(src)], base, env,
         timeout=300)
    wheel = next(wheels.glob("deformgl-*.whl"))
    venv = base / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], base, env)
    bindir = venv / "bin"
    purelib = Path(_run([str(bindir / "python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                        base, env).stdout.strip())
    (purelib / "_deformgl_test_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    _run([sys.executable, "-m", "pip", "--python", str(bindir / "python"), "install", "--quiet", "--no-deps", "--ignore-installed",
          "--no-index", str(wheel)], base, env, timeout=300)
    work = base / "work"
    work.mkdir()
    env["PATH"] = f"{bindir}{os.pathsep}{env.get('PATH', '')}"
    return bindir, work, env


def test_the_installed_package_is_the_wheel(installed):
    bindir, work, env = installed
    where = _run([str(bindir / "python"), "-c", "import deformgl.data as d; print(d.__file__); print(d.scenes_dir())"],
                 work, env).stdout.split()
    assert all(str(bindir.parent) in line for line in where), where
    assert not any(str(ROOT) in line for line in where), where


def test_bench_binding_runs_installed_outside_the_checkout(installed, tmp_path):
    """The binding study (the repository's studies/, not in the wheel) on the installed package
    finds the shipped mesh; the wheel's ``deformgl bench binding`` names that command."""
    bindir, work, env = installed
    shutil.copytree(ROOT / "studies", tmp_path / "studies", ignore=shutil.ignore_patterns("__pycache__"))
    out = _run([str(bindir / "python"), "-m", "studies.binding_speed", "--quick"], work,
               {**env, "PYTHONPATH": str(tmp_path)}).stdout
    assert "bind dragon_vrip_res3.ply.gz to" in out and "vertices" in out, out
    moved = subprocess.run([str(bindir / "deformgl"), "bench", "binding", "--quick"], cwd=work, env=env,
                           capture_output=True, text=True, timeout=60)
    assert moved.returncode == 2 and "python -m studies.binding_speed" in moved.stderr, moved.stderr
    missing = subprocess.run([str(bindir / "python"), "-c", "import studies"], cwd=work, env=env,
                             capture_output=True, text=True, timeout=60)
    assert missing.returncode != 0 and "No module named 'studies'" in missing.stderr  # not in the wheel


@pytest.mark.parametrize("scene", ["dragon.toml", "scenes/dragon.toml"])
def test_render_a_shipped_scene_installed_outside_the_checkout(installed, scene):
    from deformgl.files import read_png

    bindir, work, env = installed
    out = work / f"x{len(scene)}.png"
    _run([str(bindir / "deformgl"), "render", scene, "-o", str(out), "--steps", "3", "--size", "64x48", "--quiet"],
         work, env)
    assert read_png(out).shape == (48, 64, 3)


def test_a_shipped_scene_without_output_writes_into_the_working_folder(installed):
    bindir, work, env = installed
    _run([str(bindir / "deformgl"), "render", "jelly", "--steps", "2", "--size", "32x24", "--quiet"], work, env)
    assert (work / "jelly.png").stat().st_size > 0
    missing = subprocess.run([str(bindir / "deformgl"), "render", "no_such.toml"], cwd=work, env=env,
                             capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2  # an input error
    lines = missing.stderr.strip().splitlines()
    assert len(lines) == 1 and "no_such.toml: scene file not found" in lines[0] and "dragon.toml" in lines[0]


def test_a_shipped_scene_graph_renders_installed_outside_the_checkout(installed):
    """The demo scene-graph files ship in the wheel: ``deformgl render`` finds one by name and
    ``deformgl trilinear`` renders from it."""
    from deformgl.files import read_png

    bindir, work, env = installed
    _run([str(bindir / "deformgl"), "render", "trilinear_helix.toml", "--size", "64x48"], work, env)
    assert read_png(work / "trilinear_helix.png").shape == (48, 64, 3)
    _run([str(bindir / "deformgl"), "trilinear", "tile", "-o", str(work / "tile.png"), "--size", "64x48"], work, env)
    assert read_png(work / "tile.png").shape == (48, 64, 3)
