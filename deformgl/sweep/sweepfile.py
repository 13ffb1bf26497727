"""Sweep files (TOML): a scene, overrides common to every variant, and the variants.

::

    scene = "jelly.toml"              # relative to the sweep file, or a shipped scene by name
    outputs = ["png", "record"]       # per variant: "png", "mesh" (.ply; a mapped scene), "record" (.json)
    [set]                             # every variant
    "render.size" = [160, 120]
    [product]                         # every combination of these values (a product)
    "physics.integrator" = ["verlet", "euler"]
    "grid.nodes_along_longest" = [6, 8]
    [[variant]]                       # and these variants (a set), after the product's
    name = "stiff"
    "material.youngs_modulus" = 20000.0

Keys are any scene keys, dotted (:func:`deformgl.scene.schema.apply_overrides`); a variant's
values are checked when it runs, and a bad one is that variant's error in the table, not the
sweep's.
"""

from __future__ import annotations

import itertools
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from deformgl.errors import InputError

__all__ = ["OUTPUT_KINDS", "SweepSpec", "Variant", "load_sweep"]

OUTPUT_KINDS = ("png", "mesh", "record")
MAX_VARIANTS = 10_000


@dataclass(frozen=True)
class Variant:
    """One run: its name (files are ``NAME.png`` ...), a label, and the scene keys it sets."""

    name: str
    label: str
    overrides: dict[str, Any]


@dataclass(frozen=True)
class SweepSpec:
    """A sweep: the scene file, the variants, what each writes."""

    source: Path
    scene: Path
    variants: tuple[Variant, ...]
    outputs: tuple[str, ...]


def _fail(file: str, key: str, what: str) -> InputError:
    return InputError(f"{file}: {key}: {what}")


def _label(overrides: dict[str, Any]) -> str:
    return ", ".join(f"{k.rsplit('.', 1)[-1]}={v}" for k, v in overrides.items()) or "base"


def load_sweep(path: str | Path) -> SweepSpec:
    """Read and check a sweep file (every problem one line naming the file and key).

    Raises:
        InputError: unreadable, invalid TOML, an unknown key, no variants, a bad scene path.
    """
    from deformgl.data import find_scene

    file = str(path)
    try:
        data = tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise InputError(f"{file}: sweep file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{file}: cannot read sweep file: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{file}: invalid TOML: {exc}") from None
    for key in data:
        if key not in ("scene", "outputs", "set", "product", "variant"):
            raise _fail(file, key, "unknown key (expected scene, outputs, set, product, variant)")
    scene = data.get("scene")
    if not isinstance(scene, str) or not scene:
        raise _fail(file, "scene", "required: the scene file to sweep (a path or a shipped scene's name)")
    scene_path = (Path(path).resolve().parent / scene)
    if not scene_path.is_file():
        scene_path = find_scene(Path(scene))
        if not scene_path.is_file():
            raise _fail(file, "scene", f"scene file not found: {scene}")
    outputs = data.get("outputs", ["png", "record"])
    if not isinstance(outputs, list) or not all(o in OUTPUT_KINDS for o in outputs):
        raise _fail(file, "outputs", f"must be an array of {', '.join(map(repr, OUTPUT_KINDS))}, got {outputs!r}")
    common = data.get("set", {})
    if not isinstance(common, dict):
        raise _fail(file, "set", "must be a table of scene keys")
    product = data.get("product", {})
    if not isinstance(product, dict) or not all(isinstance(v, list) and v for v in product.values()):
        raise _fail(file, "product", "must be a table of scene keys, each an array of values")
    explicit = data.get("variant", [])
    if not isinstance(explicit, list) or not all(isinstance(v, dict) for v in explicit):
        raise _fail(file, "variant", "must be an array of tables ([[variant]])")
    found: list[tuple[str | None, dict[str, Any]]] = []
    if product:
        keys = list(product)
        for values in itertools.product(*(product[k] for k in keys)):
            found.append((None, dict(zip(keys, values))))
    for i, v in enumerate(explicit):
        v = dict(v)
        name = v.pop("name", None)
        if name is not None and (not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_-][A-Za-z0-9_.-]{0,63}", name)):
            raise _fail(file, f"variant[{i}].name", "must be 1-64 letters, digits, '_', '-' or '.', not starting with '.'")
        if name == "sweep":
            raise _fail(file, f"variant[{i}].name", "'sweep' is reserved (sweep.csv, sweep.json and sweep.png are the tables)")
        found.append((name, v))
    if not found:
        raise _fail(file, "product", "no variants: give [product] values or [[variant]] tables")
    if len(found) > MAX_VARIANTS:
        raise _fail(file, "product", f"{len(found)} variants, more than {MAX_VARIANTS}")
    width = max(2, len(str(len(found) - 1)))
    variants, names = [], set()
    for i, (name, own) in enumerate(found):
        name = name or f"v{i:0{width}d}"
        if name in names:
            raise _fail(file, "variant", f"two variants are named {name!r}")
        names.add(name)
        variants.append(Variant(name, _label(own), {**common, **own}))
    return SweepSpec(Path(path).resolve(), scene_path, tuple(variants), tuple(outputs))
