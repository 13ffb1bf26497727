"""Scene files: TOML parsed into frozen dataclasses, every value validated.

Each problem is one :class:`~deformgl.errors.SceneError` line ``"<scene file>: <key.path>: <what>"``,
e.g. ``jelly.toml: physics.dt: must be > 0, got -1``. Absent keys take their defaults; unknown keys
are errors. Validation is table-driven: each TOML table has a schema mapping key to (checker,
default) and a builder that makes the dataclass. Positions are bounding-box fractions, the rest SI.

This module is the loader: the tables' schemas, their builders and :func:`load_scene`. The
dataclasses are in :mod:`deformgl.scene.spec` and the value checkers in
:mod:`deformgl.scene.checks`; both are re-exported here, so every name is importable from
``deformgl.scene.schema`` as before.
"""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path
from typing import Any

from deformgl.errors import SceneError
from deformgl.scene.checks import (REQUIRED, Build, Check, _array, _describe, _existing, _fail, _int, _join,  # noqa: F401
                                   _num, _of, _plain, _str, _table, _vec)
from deformgl.scene.spec import (AXES, BACKENDS, MAPPING_MODES, MAX_DRAGS, MAX_SIZE, MAX_SPHERES,  # noqa: F401
                                 MSAA_CHOICES, UNSTABLE_POLICIES, _BACKEND, _INTEGRATOR, _MAPPING_MODE,
                                 _SIZE, _STEPS, Attach, Camera, ClothSpec, Converge, DragSpec, GridSpec,
                                 Keyframes, Light, Mapping, Material, MeshSpec, MotionSpec, Nodes, Output,
                                 Physics, Pull, Region, Render, Safety, Scene, SphereSpec, SpringClass, Vec3,
                                 parse_size)
from deformgl.sim.springs import MAX_LOADS as MAX_PULLS

__all__ = ["BACKENDS", "Camera", "ClothSpec", "Converge", "DragSpec", "GridSpec", "Keyframes", "Light", "Safety", "UNSTABLE_POLICIES",
           "Material", "MeshSpec", "Output", "Physics", "Pull", "Region", "Render", "Scene", "SphereSpec",
           "SpringClass", "load_scene", "parse_size"]

# --- schemas and builders ------------------------------------------------------------------------


def _build_region(file: str, key: str, d: dict[str, Any]) -> Region:
    kind = d["region"]
    need, foreign = (("min", "max"), ("axis", "at")) if kind == "box" else (("axis", "at"), ("min", "max"))
    for k in need:
        if d[k] is None:
            _fail(file, _join(key, k), f"required for region {kind!r}")
    for k in foreign:
        if d[k] is not None:
            _fail(file, _join(key, k), f"not used by region {kind!r}")
    if kind != "box":
        return Region(kind, AXES.index(d["axis"]), d["at"], None, None)
    for i, (lo, hi) in enumerate(zip(d["min"], d["max"])):
        if lo > hi:
            _fail(file, _join(key, "max"), f"must be >= min componentwise, got max[{i}] {hi:g} < min[{i}] {lo:g}")
    return Region(kind, None, None, d["min"], d["max"])


def _build_pull(file: str, key: str, d: dict[str, Any]) -> Pull:
    if d["stop"] <= d["start"]:
        _fail(file, _join(key, "stop"), f"must be > start ({d['start']:g}), got {d['stop']:g}")
    return Pull(_build_region(file, key, d), d["force"], d["start"], d["ramp"], d["stop"])


def _build_grid(file: str, key: str, d: dict[str, Any]) -> GridSpec:
    n, spacing = d["nodes_along_longest"], d["spacing"]
    if (n is None) == (spacing is None):
        both = ", not both" if n is not None else ""
        _fail(file, key, f"set exactly one of 'nodes_along_longest' or 'spacing'{both}")
    return GridSpec(n, spacing)


def _build_light(file: str, key: str, d: dict[str, Any]) -> Light:
    x, y, z = d["direction"]
    norm = math.sqrt(x * x + y * y + z * z)
    if norm == 0.0:
        _fail(file, _join(key, "direction"), "must be nonzero, got [0, 0, 0]")
    return Light((x / norm, y / norm, z / norm), d["colour"], d["ambient"])


_POS, _NONNEG, _UNIT = _num(lo=0.0, lo_open=True), _num(lo=0.0), _num(lo=0.0, hi=1.0)
_REGION: dict[str, tuple[Check, Any]] = {
    "region": (_str(("below", "above", "box")), REQUIRED),
    "axis": (_str(AXES), None), "at": (_num(), None), "min": (_vec(3), None), "max": (_vec(3), None),
}
_PULL = _REGION | {
    "force": (_vec(3), REQUIRED), "start": (_NONNEG, 0.0), "ramp": (_NONNEG, 0.0),
    "stop": (_num(allow_inf=True), math.inf),
}
def _build_keyframes(file: str, key: str, points: tuple[Vec3, ...], times: tuple[float, ...] | None) -> Keyframes:
    if times is None:
        if len(points) != 1:
            _fail(file, _join(key, "times"), f"required for a path of {len(points)} points")
        times = (0.0,)
    if len(times) != len(points):
        _fail(file, _join(key, "times"), f"must have one time per point ({len(points)}), got {len(times)}")
    for i in range(1, len(times)):
        if times[i] <= times[i - 1]:
            _fail(file, _join(key, "times"), f"must increase, got {times[i]:g} after {times[i - 1]:g}")
    return Keyframes(points, times)


def _points(file: str, key: str, v: Any) -> tuple[Vec3, ...]:
    if not isinstance(v, list) or not v:
        _fail(file, key, f"must be a non-empty array of [x, y, z] points, got {_describe(v)}")
    return tuple(_vec(3)(file, f"{key}[{i}]", p) for i, p in enumerate(v))


def _numbers(file: str, key: str, v: Any) -> tuple[float, ...]:
    if not isinstance(v, list):
        _fail(file, key, f"must be an array of numbers, got {_describe(v)}")
    return tuple(_NONNEG(file, f"{key}[{i}]", t) for i, t in enumerate(v))


def _build_sphere(file: str, key: str, d: dict[str, Any]) -> SphereSpec:
    if (d["centre"] is None) == (d["path"] is None):
        _fail(file, key, "set exactly one of 'centre' (a fixed sphere) or 'path' (a moving one)")
    if d["path"] is None and d["times"] is not None:
        _fail(file, _join(key, "times"), "only used with 'path'")
    path = None if d["path"] is None else _build_keyframes(file, key, d["path"], d["times"])
    return SphereSpec(d["centre"], path, d["radius"])


def _build_physics(file: str, key: str, d: dict[str, Any]) -> Physics:
    springs = d.pop("springs")
    return Physics(**d, **springs)


def _spring_class(flexion: bool) -> Check:
    return _table({"stiffness": (_NONNEG, 0.0 if flexion else None), "damping": (_NONNEG, 0.0)},
                  lambda file, key, d: SpringClass(d["stiffness"], d["damping"]))


_PHYSICS = _table({
    "dt": (_POS, 0.002), "steps": (_STEPS, 400), "stiffness": (_POS, 500.0),
    "damping": (_NONNEG, 0.5), "mass": (_POS, 0.01), "gravity": (_vec(3), [0.0, -9.81, 0.0]),
    "fixed": (_array(_table(_REGION, _build_region)), []),
    "pull": (_array(_table(_PULL, _build_pull), MAX_PULLS), []),
    "integrator": (_INTEGRATOR, "verlet"), "backend": (_BACKEND, "fragment"),
    "springs": (_table({"structural": (_spring_class(False), {}), "shear": (_spring_class(False), {}),
                        "flexion": (_spring_class(True), {})}, lambda file, key, d: d), {}),
    "wind": (_vec(3), [0.0, 0.0, 0.0]), "wind_drag": (_NONNEG, 0.0),
    "ground": (_table({"at": (_num(), REQUIRED)}, lambda file, key, d: d["at"]), None),
    "sphere": (_array(_table({
        "centre": (_vec(3), None), "path": (_points, None), "times": (_numbers, None),
        "radius": (_POS, REQUIRED)}, _build_sphere), MAX_SPHERES), []),
    "drag": (_array(_table({
        "path": (_points, REQUIRED), "times": (_numbers, None), "stiffness": (_POS, REQUIRED)},
        lambda file, key, d: DragSpec(_build_keyframes(file, key, d["path"], d["times"]), d["stiffness"])),
        MAX_DRAGS), []),
    "converge": (_table({"threshold": (_POS, 0.001), "every": (_int(lo=1), 10)}, _plain(Converge)), None),
    "safety": (_table({"unstable": (_str(UNSTABLE_POLICIES), "refuse"), "check_every": (_int(lo=0), 100),
                       "bad_distance": (_POS, 1000.0)}, _plain(Safety)), {}),
}, _build_physics)


_GRID = _table({"nodes_along_longest": (_int(lo=2), None), "spacing": (_POS, None)}, _build_grid)
_CAMERA = _table({
    "projection": (_str(("perspective", "orthographic")), "perspective"),
    "azimuth": (_num(), 30.0), "elevation": (_num(lo=-89.0, hi=89.0), 20.0),
    "fov": (_num(lo=0.0, hi=179.0, lo_open=True, hi_open=True), 35.0),
    "distance": (_POS, 1.6), "target": (_vec(3), [0.5, 0.5, 0.5]),
}, _plain(Camera))
_LIGHT = _table({
    "direction": (_vec(3), [0.4, 1.0, 0.6]), "colour": (_vec(3, _NONNEG), [1.0, 1.0, 1.0]),
    "ambient": (_UNIT, 0.2),
}, _build_light)
_MATERIAL = _table({
    "colour": (_vec(3, _UNIT), [0.85, 0.6, 0.35]), "specular": (_UNIT, 0.3), "shininess": (_POS, 32.0),
}, _plain(Material))
_RENDER = _table({
    "size": (_SIZE, [800, 600]), "msaa": (_int(choices=MSAA_CHOICES), 4),
    "background": (_vec(3, _UNIT), [1.0, 1.0, 1.0]), "show_grid": (_of(bool, "a boolean (true or false)"), False),
    "camera": (_CAMERA, {}), "light": (_LIGHT, {}), "material": (_MATERIAL, {}),
}, _plain(Render))


_MOTION = _table({
    "kind": (_str(("rigid", "bend", "twist")), REQUIRED), "angle": (_num(), 0.0),
    "axis": (_str(AXES), "y"), "along": (_str(AXES), "x"), "towards": (_str(AXES), "y"),
    "translate": (_vec(3), [0.0, 0.0, 0.0]), "amount": (_num(), 1.0),
}, lambda file, key, d: _build_motion(file, key, d))


def _build_motion(file: str, key: str, d: dict[str, Any]) -> MotionSpec:
    if d["kind"] == "bend" and d["along"] == d["towards"]:
        _fail(file, _join(key, "towards"), f"must differ from along ({d['along']!r})")
    return MotionSpec(d["kind"], d["angle"], AXES.index(d["axis"]), AXES.index(d["along"]),
                      AXES.index(d["towards"]), d["translate"], d["amount"])


def load_scene(path: str | Path) -> Scene:
    """Reads and validates a scene file (named as given in ``path`` in error messages).

    Relative paths in it are relative to its directory; the returned scene's paths are absolute.

    Raises:
        SceneError: For an unreadable file, invalid TOML, or any invalid, missing or unknown key.
    """
    file, source = str(path), Path(path).resolve()
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise SceneError(f"{file}: cannot read scene file: file not found") from None
    except OSError as e:
        raise SceneError(f"{file}: cannot read scene file: {e.strerror or e}") from None
    except UnicodeDecodeError as e:
        raise SceneError(f"{file}: invalid TOML: not UTF-8 ({e.reason} at byte {e.start})") from None
    except tomllib.TOMLDecodeError as e:
        m = re.fullmatch(r"(.*) \(at (line (\d+), column (\d+)|end of document)\)", str(e))
        where = f"{m[2]}: invalid TOML: {m[1]}" if m else f"invalid TOML: {e}"
        raise SceneError(f"{file}: {where}") from None

    def build_mesh(file: str, key: str, d: dict[str, Any]) -> MeshSpec:
        return MeshSpec(_existing(file, _join(key, "path"), (source.parent / d["path"]).resolve()))

    def build_output(file: str, key: str, d: dict[str, Any]) -> Output:
        out = d["path"] if d["path"] is not None else f"{source.stem}.png"
        if not out.lower().endswith(".png") or Path(out).name.lower() == ".png":
            _fail(file, _join(key, "path"), f"must end in .png, got {out!r}")
        return Output((source.parent / out).resolve())

    def build_mapping(file: str, key: str, d: dict[str, Any]) -> Mapping:
        nm = d["normal_map"]
        if nm not in ("none", "procedural"):
            nm = _existing(file, _join(key, "normal_map"), (source.parent / nm).resolve())
        return Mapping(d["mode"], None if nm == "none" else nm, d["normal_map_strength"],
                       d["normal_map_repeat"], d["cache"])

    def build_nodes(file: str, key: str, d: dict[str, Any]) -> Nodes:
        src = d["source"]
        if src == "file" and d["file"] is None:
            _fail(file, _join(key, "file"), "required for source 'file'")
        if src == "motion" and d["motion"] is None:
            _fail(file, _join(key, "motion"), "required for source 'motion'")
        for k, needed_by in (("file", "file"), ("motion", "motion")):
            if d[k] is not None and src != needed_by:
                _fail(file, _join(key, k), f"not used by source {src!r}")
        path = _existing(file, _join(key, "file"), (source.parent / d["file"]).resolve()) if d["file"] else None
        return Nodes(src, path, d["frame"], d["motion"])

    def build_scene(file: str, key: str, d: dict[str, Any]) -> Scene:
        if (d["mesh"] is None) == (d["cloth"] is None):
            _fail(file, "mesh", "set exactly one of [mesh] (a mesh to deform) or [cloth] (a cloth sheet)")
        if d["cloth"] is not None:
            if "grid" in data:
                _fail(file, "grid", "a cloth scene sets its nodes in cloth.nodes")
            if d["mapping"].mode != "one-to-one":
                _fail(file, "mapping.mode", "a cloth scene has no detailed mesh: only one-to-one")
            if d["nodes"].source != "simulate":
                _fail(file, "nodes.source", "a cloth scene is simulated")
        if d["attach"] and d["mapping"].mode == "one-to-one":
            _fail(file, "attach", "needs a detailed mesh: set mapping.mode to constant, curvature or auto")
        return Scene(source, **d)

    scene = _table({
        "attach": (_array(_table({
            "from": (_vec(3), REQUIRED), "to": (_vec(3), REQUIRED), "anchors": (_int(lo=2, hi=4096), 16),
            "radius": (_num(lo=0.0, lo_open=True, hi=0.5), 0.01), "colour": (_vec(3, _UNIT), [0.2, 0.45, 0.85]),
        }, lambda file, key, d: Attach(d["from"], d["to"], d["anchors"], d["radius"], d["colour"])), 8), []),
        "mapping": (_table({
            "mode": (_MAPPING_MODE, "one-to-one"), "normal_map": (_str(), "none"),
            "normal_map_strength": (_UNIT, 1.0), "normal_map_repeat": (_POS, 4.0),
            "cache": (_of(bool, "a boolean (true or false)"), True),
        }, build_mapping), {}),
        "nodes": (_table({
            "source": (_str(("simulate", "file", "motion")), "simulate"), "file": (_str(), None),
            "frame": (_int(), -1), "motion": (_MOTION, None),
        }, build_nodes), {}),
        "mesh": (_table({"path": (_str(), REQUIRED)}, build_mesh), None),
        "cloth": (_table({"nodes": (_vec(2, _int(lo=2, hi=MAX_SIZE)), REQUIRED), "size": (_POS, 1.0)},
                         lambda file, key, d: ClothSpec(d["nodes"], d["size"])), None),
        "grid": (_GRID, {"nodes_along_longest": 8}),
        "physics": (_PHYSICS, {}),
        "render": (_RENDER, {}),
        "output": (_table({"path": (_str(), None)}, build_output), {}),
    }, build_scene)
    return scene(file, "", data)
