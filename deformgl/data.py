"""The scenes and meshes shipped with deformgl (package ``deformgl.scenes``, the repository's
``scenes/`` folder), found through :mod:`importlib.resources` so they work from an installed
wheel in any working directory as well as from the checkout.

Scene files name their meshes relative to themselves, so a packaged scene loads its packaged
mesh. A scene given on the command line that does not exist in the working directory is looked
up among the packaged ones by file name (``deformgl render dragon.toml``).
"""

from __future__ import annotations

import os
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path

from deformgl.errors import DeformglError

__all__ = ["asset", "default_output", "find_mesh", "find_scene", "is_packaged", "package_folder", "packaged_scene",
           "scene_file", "scene_names", "scenes_dir"]


def package_folder(name: str) -> Traversable:
    """The package data folder ``deformgl.<name>`` (``"shaders"`` or ``"scenes"``).

    An installed deformgl (wheel or editable) has them as packages; a deformgl imported from a
    source checkout without being installed there (the repository root first on ``sys.path``, as
    ``python -m studies.NAME`` from the root does beside a non-editable install) finds them as the
    repository's own ``shaders/`` and ``scenes/`` folders, which is what the wheel packages
    (pyproject.toml's ``package-dir``).
    """
    try:
        return resources.files(f"deformgl.{name}")
    except ModuleNotFoundError:
        root = Path(__file__).resolve().parents[1]
        checkout = root / name
        # only a source checkout's own folder (its pyproject.toml beside the package), never a
        # folder of that name that another distribution put beside an installed deformgl
        if (root / "pyproject.toml").is_file() and checkout.is_dir():
            return checkout
        raise DeformglError(f"deformgl.{name}: the package data is missing (neither installed nor "
                            f"a source checkout's {name}/ folder); reinstall deformgl") from None


def scenes_dir() -> Path:
    """The folder of the packaged scenes (its ``assets/`` holds the meshes).

    Raises:
        DeformglError: If the package data is not on the file system (a zipped install).
    """
    root = package_folder("scenes")
    if not isinstance(root, Path) or not root.is_dir():
        raise DeformglError(f"the packaged scenes are not a folder on disk ({root}); install "
                            "deformgl unzipped (pip install)")
    return root


def scene_names() -> list[str]:
    """File names of the packaged scenes, sorted (``cloth_64.toml``, ``dragon.toml``, ...)."""
    return sorted(p.name for p in scenes_dir().glob("*.toml"))


def packaged_scene(name: str) -> Path:
    """The packaged scene ``name`` (``dragon`` or ``dragon.toml``).

    Raises:
        DeformglError: If there is none of that name, listing the ones there are.
    """
    file = name if name.endswith(".toml") else f"{name}.toml"
    path = scenes_dir() / file
    if not path.is_file():
        raise DeformglError(f"{name}: no packaged scene of that name (there are: "
                            f"{', '.join(scene_names())})")
    return path


def asset(name: str) -> Path:
    """The packaged mesh ``scenes/assets/<name>``, e.g. ``dragon_vrip_res3.ply.gz``."""
    path = scenes_dir() / "assets" / name
    if not path.is_file():
        raise DeformglError(f"{name}: no packaged asset of that name in {path.parent}")
    return path


def is_packaged(path: Path) -> bool:
    """Whether ``path`` lies in the packaged scenes folder."""
    try:
        path.resolve().relative_to(scenes_dir().resolve())
    except (ValueError, DeformglError):
        return False
    return True


def _exists(path: Path) -> bool:
    """``path.exists()``, False for a path the system cannot take (a NUL byte, a name too long):
    opening it then reports it by the name given."""
    try:
        return path.exists()
    except (OSError, ValueError):
        return False


def find_scene(path: str | os.PathLike[str]) -> Path:
    """A scene file as given if it exists, else the packaged scene of that file name.

    ``scenes/dragon.toml`` outside the checkout and plain ``dragon.toml`` both find the packaged
    dragon. A path that is neither is returned unchanged, so that loading it reports the missing
    file by the name the user gave.
    """
    path = Path(path)
    if _exists(path):
        return path
    if len(path.parts) == 1 or (len(path.parts) == 2 and path.parts[0] == "scenes"):
        try:
            return packaged_scene(path.name)
        except DeformglError:
            pass
    return path


def find_mesh(path: str | os.PathLike[str]) -> Path:
    """A mesh file as given if it exists, else the shipped mesh of that file name
    (``scenes/assets/<name>``: ``dragon_vrip_res3.ply.gz``, ``scenes/assets/dragon_vrip_res3.ply.gz``).
    A path that is neither is returned unchanged, so that loading it reports the missing file by
    the name the user gave."""
    path = Path(path)
    if _exists(path):
        return path
    parts = path.parts
    if len(parts) == 1 or (len(parts) == 3 and parts[:2] == ("scenes", "assets")) or (
            len(parts) == 2 and parts[0] == "assets"):
        try:
            return asset(path.name)
        except DeformglError:
            pass
    return path


def default_output(source: Path, output: Path) -> Path:
    """Where a scene's image goes by default: its ``output.path``, but for a shipped scene its
    file name in the working directory (never into the installed package)."""
    return Path(output.name) if is_packaged(source) else output


def scene_file(path: str | Path, flag: str = "") -> Path:
    """A scene file as given, else the shipped scene of that name.

    Raises:
        InputError: neither exists (one line naming the folder searched and the shipped scenes).
    """
    from deformgl.errors import InputError

    found = find_scene(path)
    if not found.exists():
        raise InputError(f"{path}: {flag + ': ' if flag else ''}scene file not found (not in "
                         f"{Path.cwd()} nor among the shipped scenes: {', '.join(scene_names())})")
    return found
