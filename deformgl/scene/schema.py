"""Scene files: TOML parsed into frozen dataclasses, every value validated.

Each problem is one :class:`~deformgl.errors.SceneError` line ``"<scene file>: <key.path>: <what>"``,
e.g. ``jelly.toml: physics.dt: must be > 0, got -1``. Absent keys take their defaults; unknown keys
are errors. Validation is table-driven: each TOML table has a schema mapping key to (checker,
default) and a builder that makes the dataclass. Positions are bounding-box fractions, the rest SI.

This module is the loader: the tables' schemas, their builders and :func:`load_scene`. The
dataclasses are in :mod:`deformgl.scene.spec` and the value checkers in
:mod:`deformgl.scene.checks`; import them from there.
"""

from __future__ import annotations

import dataclasses
import math
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from deformgl.data import find_scene
from deformgl.errors import SceneError
from deformgl.scene.tomltext import check_depth, read_toml
from deformgl.scene.checks import (REQUIRED, Check, _array, _describe, _existing, _fail, _int, _join, _num, _of,
                                   _one_line, _plain, _resolve, _short, _str, _table, _vec)
from deformgl.scene.spec import (AA_CHOICES, AXES, MAX_DRAGS, MAX_GRID_NODES, MAX_KEYFRAMES, MAX_SIZE, MAX_SPHERES,
                                 MAX_STEPS, MSAA_CHOICES, UNSTABLE_POLICIES, _BACKEND, _CHECK_EVERY, _INTEGRATOR,
                                 _LAYOUT, _MAPPING_MODE, _SIZE, _STEPS, Animation, Attach, Implicit, Camera, CameraKey,
                                 ClothSpec, Converge, DragSpec, GridSpec, Keyframes, Light, Mapping, Material, MeshSpec,
                                 MotionSpec, Nodes, Output, Physics, Pull, Region, Render, Safety, Scene, SphereSpec,
                                 SpringClass, Vec3, Xpbd)
from deformgl.sim.equilibrium import CRITERIA as CONVERGE_CRITERIA
from deformgl.sim.implicit import DEFAULT_PRECONDITIONER, PRECONDITIONERS
from deformgl.scene.material_table import _BODY_MATERIAL
from deformgl.sim.materials import ElasticMaterial, SheetMaterial
from deformgl.scene.spline_model import spline_refusal
from deformgl.sim.scripted import MAX_LOADS as MAX_PULLS

__all__ = ["apply_overrides", "load_scene"]

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
    norm = math.hypot(x, y, z)  # no overflow or underflow of the squares
    if norm == 0.0:
        _fail(file, _join(key, "direction"), "must be nonzero, got [0, 0, 0]")
    if not LIGHT_NORM[0] < norm < LIGHT_NORM[1]:
        _fail(file, _join(key, "direction"),
              f"length must be in ({LIGHT_NORM[0]:g}, {LIGHT_NORM[1]:g}), got {norm:.3g}")
    unit = (x / norm, y / norm, z / norm)
    if not 0.5 < math.hypot(*(float(np.float32(c)) for c in unit)) < 2.0:  # pragma: no cover - by the bounds
        _fail(file, _join(key, "direction"), "cannot be normalised in float32")
    return Light(unit, d["colour"], d["ambient"])


#: The open range of the light direction's length (its components are finite and within 1e6).
LIGHT_NORM = (1e-6, 1e6)


_POS, _NONNEG, _UNIT = _num(lo=0.0, lo_open=True), _num(lo=0.0), _num(lo=0.0, hi=1.0)
# The ranges a scene may use (docs/SCENE_LIMITS.md): wide around every shipped scene, narrow enough
# that the float64 arithmetic of the dt check and the float32 arithmetic on the GPU stay finite.
_FRAC = _num(sane=(-10.0, 10.0), unit="box fractions")
_TIME = _num(lo=0.0, sane=(0.0, 1e9), unit="s")
_K = _num(lo=0.0, lo_open=True, sane=(1e-9, 1e9), unit="N/m")  # spring stiffness
_C = _num(lo=0.0, sane=(0.0, 1e6), unit="N*s/m")  # damping and drag
_ANGLE = _num(sane=(-3600.0, 3600.0), unit="degrees")
_COLOUR = _vec(3, _UNIT)
_REGION: dict[str, tuple[Check, Any]] = {
    "region": (_str(("below", "above", "box")), REQUIRED),
    "axis": (_str(AXES), None), "at": (_FRAC, None), "min": (_vec(3, _FRAC), None),
    "max": (_vec(3, _FRAC), None),
}
_PULL = _REGION | {
    "force": (_vec(3, _num(sane=(-1e6, 1e6), unit="N")), REQUIRED), "start": (_TIME, 0.0),
    "ramp": (_TIME, 0.0), "stop": (_num(allow_inf=True, sane=(0.0, 1e9), unit="s (or inf)"), math.inf),
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
    if len(v) > MAX_KEYFRAMES:
        _fail(file, key, f"at most {MAX_KEYFRAMES} points are allowed, got {len(v)}")
    return tuple(_vec(3, _FRAC)(file, f"{key}[{i}]", p) for i, p in enumerate(v))


def _numbers(file: str, key: str, v: Any) -> tuple[float, ...]:
    if not isinstance(v, list):
        _fail(file, key, f"must be an array of numbers, got {_describe(v)}")
    if len(v) > MAX_KEYFRAMES:
        _fail(file, key, f"at most {MAX_KEYFRAMES} times are allowed, got {len(v)}")
    return tuple(_TIME(file, f"{key}[{i}]", t) for i, t in enumerate(v))


def _build_sphere(file: str, key: str, d: dict[str, Any]) -> SphereSpec:
    if (d["centre"] is None) == (d["path"] is None):
        _fail(file, key, "set exactly one of 'centre' (a fixed sphere) or 'path' (a moving one)")
    if d["path"] is None and d["times"] is not None:
        _fail(file, _join(key, "times"), "only used with 'path'")
    path = None if d["path"] is None else _build_keyframes(file, key, d["path"], d["times"])
    return SphereSpec(d["centre"], path, d["radius"])


#: the keys of each convergence criterion (``every`` serves both)
_CONVERGE_KEYS = {"equilibrium": ("tolerance", "interval", "checks"), "displacement": ("threshold",)}


def _build_converge(file: str, key: str, d: dict[str, Any]) -> Converge:
    criterion = d.pop("criterion")
    if criterion is None:  # a table written for the paper's criterion (a threshold) keeps it
        criterion = "displacement" if d["threshold"] is not None else "equilibrium"
    for other, keys in _CONVERGE_KEYS.items():
        for name in keys:
            if other != criterion and d[name] is not None:
                _fail(file, _join(key, name), f"only used with criterion = \"{other}\" (the criterion is {criterion!r})")
    if d["interval"] is not None and d["every"] is not None:
        _fail(file, _join(key, "every"), "give either 'every' (steps) or 'interval' (simulated seconds), not both")
    return Converge(criterion, **{name: value for name, value in d.items() if value is not None})


def _build_physics(file: str, key: str, d: dict[str, Any]) -> Physics:
    springs = d.pop("springs")
    if d["layout"] != "auto" and (d["integrator"], d["backend"]) != ("verlet", "fragment"):
        _fail(file, _join(key, "layout"), f"is the node layout of the fragment backend's Verlet pass (the integrator is "
                                          f"{d['integrator']!r} on {d['backend']!r})")
    if d["xpbd"] is not None and d["integrator"] != "xpbd":
        _fail(file, _join(key, "xpbd"), f"only used with integrator = \"xpbd\" (the integrator is {d['integrator']!r})")
    return Physics(**d, **springs)


def _spring_class(flexion: bool) -> Check:
    stiffness = _num(lo=0.0, sane=(0.0, 1e9), unit="N/m")
    return _table({"stiffness": (stiffness, 0.0 if flexion else None), "damping": (_C, 0.0)},
                  lambda file, key, d: SpringClass(d["stiffness"], d["damping"]))


_PHYSICS = _table({
    "dt": (_num(lo=0.0, lo_open=True, sane=(1e-9, 1.0), unit="s"), 0.002), "steps": (_STEPS, 400),
    "stiffness": (_K, 500.0), "damping": (_C, 0.5),
    "mass": (_num(lo=0.0, lo_open=True, sane=(1e-12, 1e6), unit="kg"), 0.01),
    "gravity": (_vec(3, _num(sane=(-1e4, 1e4), unit="m/s^2")), [0.0, -9.81, 0.0]),
    "fixed": (_array(_table(_REGION, _build_region)), []),
    "pull": (_array(_table(_PULL, _build_pull), MAX_PULLS), []),
    "integrator": (_INTEGRATOR, "verlet"), "backend": (_BACKEND, "fragment"), "layout": (_LAYOUT, "auto"),
    "springs": (_table({"structural": (_spring_class(False), {}), "shear": (_spring_class(False), {}),
                        "flexion": (_spring_class(True), {})}, lambda file, key, d: d), {}),
    "wind": (_vec(3, _num(sane=(-1e4, 1e4), unit="m/s")), [0.0, 0.0, 0.0]), "wind_drag": (_C, 0.0),
    "ground": (_table({"at": (_FRAC, REQUIRED)}, lambda file, key, d: d["at"]), None),
    "sphere": (_array(_table({
        "centre": (_vec(3, _FRAC), None), "path": (_points, None), "times": (_numbers, None),
        "radius": (_num(lo=0.0, lo_open=True, sane=(0.0, 100.0), unit="box lengths"), REQUIRED)},
        _build_sphere), MAX_SPHERES), []),
    "drag": (_array(_table({
        "path": (_points, REQUIRED), "times": (_numbers, None), "stiffness": (_K, REQUIRED)},
        lambda file, key, d: DragSpec(_build_keyframes(file, key, d["path"], d["times"]), d["stiffness"])),
        MAX_DRAGS), []),
    "converge": (_table({
        "criterion": (_str(CONVERGE_CRITERIA), None),
        "tolerance": (_num(lo=0.0, lo_open=True, sane=(1e-9, 1.0), unit="(a ratio)"), None),
        "interval": (_num(lo=0.0, lo_open=True, sane=(1e-9, 1e3), unit="s"), None),
        "checks": (_int(lo=1, sane=(1, 1000)), None),
        "threshold": (_num(lo=0.0, lo_open=True, sane=(0.0, 1e3), unit="grid spacings"), None),
        "every": (_int(lo=1, sane=(1, MAX_STEPS)), None)}, _build_converge), None),
    "xpbd": (_table({"iterations": (_int(lo=1, sane=(1, 100_000)), 10),
                     "substeps": (_int(lo=1, sane=(1, 1000)), 1)}, _plain(Xpbd)), None),
    "safety": (_table({"unstable": (_str(UNSTABLE_POLICIES), "refuse"), "check_every": (_CHECK_EVERY, 100),
                       "bad_distance": (_num(lo=0.0, lo_open=True, sane=(0.0, 1e6), unit="box lengths"), 1000.0)},
                      _plain(Safety)), {}),
    "implicit": (_table({"iterations": (_int(lo=1, sane=(1, 10000)), 20),
                         "tolerance": (_num(lo=0.0, sane=(0.0, 1.0)), 0.0),
                         "preconditioner": (_str(PRECONDITIONERS), DEFAULT_PRECONDITIONER)},
                        _plain(Implicit)), {}),
}, _build_physics)


#: ``physics`` keys the material replaces.
_PER_SPRING_KEYS = ("stiffness", "mass", "damping", "springs")


_GRID = _table({"nodes_along_longest": (_int(lo=2, sane=(2, MAX_GRID_NODES)), None),
                "spacing": (_num(lo=0.0, lo_open=True, sane=(1e-9, 1e9), unit="mesh units"), None)}, _build_grid)
_CAMERA = _table({
    "projection": (_str(("perspective", "orthographic")), "perspective"),
    "azimuth": (_num(sane=(-360.0, 360.0), unit="degrees"), 30.0), "elevation": (_num(lo=-89.0, hi=89.0), 20.0),
    "fov": (_num(lo=0.0, hi=179.0, lo_open=True, hi_open=True), 35.0),
    "distance": (_num(lo=0.0, lo_open=True, sane=(1e-3, 1e3), unit="box diagonals"), 1.6),
    "target": (_vec(3, _FRAC), [0.5, 0.5, 0.5]),
}, _plain(Camera))
_LIGHT = _table({
    "direction": (_vec(3, _num(sane=(-1e6, 1e6))), [0.4, 1.0, 0.6]),
    "colour": (_vec(3, _num(lo=0.0, sane=(0.0, 100.0))), [1.0, 1.0, 1.0]),
    "ambient": (_UNIT, 0.2),
}, _build_light)
_MATERIAL = _table({
    "colour": (_COLOUR, [0.85, 0.6, 0.35]), "specular": (_UNIT, 0.3),
    "shininess": (_num(lo=0.0, lo_open=True, sane=(0.0, 1e4)), 32.0),
}, _plain(Material))
_RENDER = _table({
    "size": (_SIZE, [800, 600]), "msaa": (_int(choices=MSAA_CHOICES), 4), "aa": (_str(AA_CHOICES), "msaa"),
    "background": (_COLOUR, [1.0, 1.0, 1.0]), "show_grid": (_of(bool, "a boolean (true or false)"), False),
    "cull": (_of(bool, "a boolean (true or false)"), False),
    "camera": (_CAMERA, {}), "light": (_LIGHT, {}), "material": (_MATERIAL, {}),
}, _plain(Render))

#: Most frames of an animation (docs/SCENE_LIMITS.md).
MAX_FRAMES = 100_000
_ANIMATION = _table({
    "frames": (_int(lo=1, sane=(1, MAX_FRAMES)), REQUIRED), "fps": (_num(lo=0.0, lo_open=True, sane=(0.0, 1000.0), unit="frames/s"), 24.0),
    "steps_per_frame": (_int(lo=0, sane=(0, MAX_STEPS)), None),
    "seconds_per_frame": (_num(lo=0.0, sane=(0.0, 1e6), unit="s"), None),
    "turntable": (_ANGLE, 0.0),
    "camera": (_array(_table({
        "at": (_UNIT, REQUIRED), "azimuth": (_num(sane=(-3600.0, 3600.0), unit="degrees"), None),
        "elevation": (_num(lo=-89.0, hi=89.0), None),
        "distance": (_num(lo=0.0, lo_open=True, sane=(1e-3, 1e3), unit="box diagonals"), None),
    }, _plain(CameraKey)), MAX_KEYFRAMES), []),
}, lambda file, key, d: _build_animation(file, key, d))


def _build_animation(file: str, key: str, d: dict[str, Any]) -> Animation:
    if d["steps_per_frame"] is not None and d["seconds_per_frame"] is not None:
        _fail(file, _join(key, "seconds_per_frame"), "set at most one of 'steps_per_frame' or 'seconds_per_frame'")
    keys = d["camera"]
    for i in range(1, len(keys)):
        if keys[i].at <= keys[i - 1].at:
            _fail(file, _join(key, f"camera[{i}].at"), f"must increase, got {keys[i].at:g} after {keys[i - 1].at:g}")
    return Animation(**d)


#: The file suffixes of an animation output (and a .png with a %d frame pattern).
ANIMATION_SUFFIXES = (".gif", ".webp", ".mp4")


_MOTION = _table({
    "kind": (_str(("rigid", "bend", "twist")), REQUIRED), "angle": (_ANGLE, 0.0),
    "axis": (_str(AXES), "y"), "along": (_str(AXES), "x"), "towards": (_str(AXES), "y"),
    "translate": (_vec(3, _num(sane=(-1e6, 1e6), unit="mesh units")), [0.0, 0.0, 0.0]),
    "amount": (_num(sane=(-10.0, 10.0)), 1.0),
}, lambda file, key, d: _build_motion(file, key, d))


def _build_motion(file: str, key: str, d: dict[str, Any]) -> MotionSpec:
    if d["kind"] == "bend" and d["along"] == d["towards"]:
        _fail(file, _join(key, "towards"), f"must differ from along ({d['along']!r})")
    return MotionSpec(d["kind"], d["angle"], AXES.index(d["axis"]), AXES.index(d["along"]),
                      AXES.index(d["towards"]), d["translate"], d["amount"])


def apply_overrides(file: str, data: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """``data`` (a parsed scene file) with dotted keys set: ``{"physics.dt": 1e-3,
    "render.camera.azimuth": 90, "physics.pull.0.force": [0, 1, 0]}`` (a number indexes an array
    of tables). The values are checked afterwards by the scene's schema like the file's own, so a
    bad one is the usual one-line error naming the key. Returns a new dict; ``data`` is untouched.

    Raises:
        SceneError: a key that does not name a place in the scene (``<file>: --set KEY: ...``).
    """
    import copy

    out = copy.deepcopy(data)
    for dotted, value in overrides.items():

        def _bad(reason: str, dotted: str = str(dotted)) -> SceneError:  # key, reason: the CLI blames its flag
            return SceneError(_one_line(f"{file}: --set {dotted}: {reason}"), key=dotted, reason=_one_line(reason))

        parts = str(dotted).split(".")
        if not all(parts):
            raise _bad("not a dotted scene key (e.g. physics.dt)")
        node: Any = out
        for i, part in enumerate(parts[:-1]):
            where = ".".join(parts[: i + 1])
            if isinstance(node, list):
                if not part.isdigit() or int(part) >= len(node):
                    raise _bad(f"{where}: no entry {part} (the array has {len(node)})")
                node = node[int(part)]
            elif isinstance(node, dict):
                node = node.setdefault(part, {})
            else:
                raise _bad(f"{'.'.join(parts[:i])} is a value, not a table")
        last = parts[-1]
        if isinstance(node, list):
            if not last.isdigit() or int(last) >= len(node):
                raise _bad(f"no entry {last} (the array has {len(node)})")
            node[int(last)] = value
        elif isinstance(node, dict):
            node[last] = value
        else:
            raise _bad(f"{'.'.join(parts[:-1])} is a value, not a table")
    return out


def load_scene(path: str | PathLike[str], overrides: dict[str, Any] | None = None) -> Scene:
    """Reads and validates a scene file (named as given in ``path`` in error messages).

    Relative paths in it are relative to its directory; the returned scene's paths are absolute.

    Args:
        overrides: dotted scene keys to set before validation (:func:`apply_overrides`), e.g.
            ``{"physics.integrator": "rk4", "grid.nodes_along_longest": 12}``.

    A path that does not exist is looked up among the shipped scenes by file name, as the CLI
    does (:func:`deformgl.data.find_scene`): ``load_scene("jelly.toml")`` in any folder.

    Raises:
        SceneError: For an unreadable file, invalid TOML, or any invalid, missing or unknown key.
    """
    if not isinstance(path, (str, PathLike)):
        raise SceneError(f"load_scene: path must be a file path (str or os.PathLike), got {type(path).__name__}")
    path = find_scene(path)
    file = str(path)
    data = read_toml(path, file)  # (first: it refuses a name the system cannot take)
    source = Path(path).resolve()
    if overrides:
        data = apply_overrides(file, data, overrides)
        check_depth(file, data)

    def given_file(key: str, rel: str, suffixes: tuple[str, ...] | None = None) -> Path:
        if not rel:
            _fail(file, key, "must be a file path, got ''")
        return _existing(file, key, _resolve(file, key, source.parent, rel), suffixes)

    def build_mesh(file: str, key: str, d: dict[str, Any]) -> MeshSpec:
        return MeshSpec(given_file(_join(key, "path"), d["path"]), d["scale"])

    def build_output(file: str, key: str, d: dict[str, Any]) -> Output:
        out = d["path"] if d["path"] is not None else f"{source.stem}.png"
        if (not out.lower().endswith((".png",) + ANIMATION_SUFFIXES)
                or Path(out).stem == "" or Path(out).name.startswith(".")):
            _fail(file, _join(key, "path"), f"must end in .png (.gif, .webp or .mp4: an animation), "
                                            f"got {_short(out)}")
        return Output(_resolve(file, _join(key, "path"), source.parent, out))

    def build_mapping(file: str, key: str, d: dict[str, Any]) -> Mapping:
        nm = d["normal_map"]
        if nm not in ("none", "procedural"):
            nm = given_file(_join(key, "normal_map"), nm)
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
        path = None if d["file"] is None else given_file(_join(key, "file"), d["file"], (".npy",))
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
        material = d.pop("material")
        if material is not None:
            raw_physics = data.get("physics", {})
            for k in _PER_SPRING_KEYS:
                if isinstance(raw_physics, dict) and k in raw_physics:
                    _fail(file, _join("physics", k), "not used with [material]: the springs, masses and "
                          "damping come from material.youngs_modulus, density and the Rayleigh damping")
            if isinstance(material, SheetMaterial) != (d["cloth"] is not None):
                _fail(file, "material", "a cloth needs a sheet material (stretch_modulus, areal_density)"
                      if d["cloth"] is not None else
                      "stretch_modulus and areal_density are for a cloth; a mesh needs youngs_modulus and density")
            for needs in material.term_needs:  # a term the integrator has no form of, before the build
                if (why := needs.refusal(d["physics"].integrator)) is not None:
                    _fail(file, needs.key, why)
            if isinstance(material, ElasticMaterial) and material.model == "spline":
                refused = spline_refusal(dataclasses.replace(d["physics"], material=material))
                raw_mapping = data.get("mapping", {})
                mode = raw_mapping.get("mode") if isinstance(raw_mapping, dict) else None
                if refused is None and mode not in (None, "auto"):
                    refused = ("mapping.mode", f'{mode!r} is a mapping to the lattice\'s nodes; model = "spline" draws '
                               'the mesh through its field (leave mapping.mode out, or "auto")')
                if refused is None and d["mapping"].normal_map is not None:
                    refused = ("mapping.normal_map", 'not drawn with model = "spline" yet')
                if refused is not None:
                    _fail(file, refused[0], refused[1])
            d["physics"] = dataclasses.replace(d["physics"], material=material, damping=0.0)
        return Scene(source, **d)

    scene = _table({
        "attach": (_array(_table({
            "from": (_vec(3, _FRAC), REQUIRED), "to": (_vec(3, _FRAC), REQUIRED), "anchors": (_int(lo=2, hi=4096), 16),
            "radius": (_num(lo=0.0, lo_open=True, hi=0.5), 0.01), "colour": (_COLOUR, [0.2, 0.45, 0.85]),
        }, lambda file, key, d: Attach(d["from"], d["to"], d["anchors"], d["radius"], d["colour"])), 8), []),
        "mapping": (_table({
            "mode": (_MAPPING_MODE, "one-to-one"), "normal_map": (_str(), "none"),
            "normal_map_strength": (_UNIT, 1.0),
            "normal_map_repeat": (_num(lo=0.0, lo_open=True, sane=(1e-6, 1e4), unit="per box side"), 4.0),
            "cache": (_of(bool, "a boolean (true or false)"), True),
        }, build_mapping), {}),
        "nodes": (_table({
            "source": (_str(("simulate", "file", "motion")), "simulate"), "file": (_str(), None),
            "frame": (_int(sane=(-1e9, 1e9)), -1), "motion": (_MOTION, None),
        }, build_nodes), {}),
        "mesh": (_table({"path": (_str(), REQUIRED),
                         "scale": (_num(lo=0.0, lo_open=True, sane=(1e-9, 1e9), unit="m per mesh unit"), 1.0)},
                        build_mesh), None),
        "material": (_BODY_MATERIAL, None),
        "cloth": (_table({"nodes": (_vec(2, _int(lo=2, hi=MAX_SIZE)), REQUIRED),
                          "size": (_num(lo=0.0, lo_open=True, sane=(1e-6, 1e6), unit="m"), 1.0)},
                         lambda file, key, d: ClothSpec(d["nodes"], d["size"])), None),
        "grid": (_GRID, {"nodes_along_longest": 8}),
        "physics": (_PHYSICS, {}),
        "render": (_RENDER, {}),
        "output": (_table({"path": (_str(), None)}, build_output), {}),
        "animation": (_ANIMATION, None),
    }, build_scene)
    return scene(file, "", data)
