"""Scene files: TOML parsed into frozen dataclasses, every value validated.

Each problem is one :class:`~deformgl.errors.SceneError` line ``"<scene file>: <key.path>: <what>"``,
e.g. ``jelly.toml: physics.dt: must be > 0, got -1``. Absent keys take their defaults; unknown keys
are errors. Validation is table-driven: each TOML table has a schema mapping key to (checker,
default) and a builder that makes the dataclass. Positions are bounding-box fractions, the rest SI.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from deformgl.errors import SceneError
from deformgl.sim.integrators import INTEGRATORS
from deformgl.sim.model import MAX_PULLS

__all__ = ["BACKENDS", "Camera", "ClothSpec", "Converge", "DragSpec", "GridSpec", "Keyframes", "Light", "Safety", "UNSTABLE_POLICIES",
           "Material", "MeshSpec", "Output", "Physics", "Pull", "Region", "Render", "Scene", "SphereSpec",
           "SpringClass", "load_scene", "parse_size"]

Vec3 = tuple[float, float, float]
MAX_SIZE = 16384
MSAA_CHOICES = (0, 1, 2, 4, 8, 16)
AXES = ("x", "y", "z")
#: Where a scene's simulation runs: fragment passes, transform feedback, or the float64 NumPy reference.
BACKENDS = ("fragment", "feedback", "numpy")
MAX_SPHERES = 8
MAX_DRAGS = 8


@dataclass(frozen=True, slots=True)
class MeshSpec:
    """The detailed mesh to deform: an absolute path that existed at load time."""
    path: Path


@dataclass(frozen=True, slots=True)
class ClothSpec:
    """A cloth instead of a mesh: ``nodes`` (along x, along z) in a square-spaced sheet of
    ``size`` m along its longer side, centred on the origin in the plane y = 0 (Movania & Feng
    2012, section 5). Its bounding box for fractions is the cube of side ``size`` around it, so
    the sheet lies at y fraction 0.5."""
    nodes: tuple[int, int]
    size: float


@dataclass(frozen=True, slots=True)
class GridSpec:
    """Coarse node grid resolution; exactly one field is set."""
    nodes_along_longest: int | None
    spacing: float | None


@dataclass(frozen=True, slots=True)
class Region:
    """Space in bounding-box fractions: ``"below"``/``"above"`` ``at`` along ``axis`` (0, 1, 2), or
    an inclusive ``"box"`` from ``lo`` to ``hi``."""
    kind: str
    axis: int | None
    at: float | None
    lo: Vec3 | None
    hi: Vec3 | None

    def contains(self, points_fraction: np.ndarray) -> np.ndarray:
        """Returns the (N,) bool mask of (N, 3) bounding-box-fraction points inside, boundaries included.

        Raises:
            ValueError: If ``points_fraction`` is not of shape (N, 3).
        """
        p = np.asarray(points_fraction, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"points must have shape (N, 3), got {p.shape}")
        if self.kind == "box":
            assert self.lo is not None and self.hi is not None
            return np.all((p >= np.asarray(self.lo)) & (p <= np.asarray(self.hi)), axis=1)
        assert self.axis is not None and self.at is not None
        return p[:, self.axis] <= self.at if self.kind == "below" else p[:, self.axis] >= self.at


@dataclass(frozen=True, slots=True)
class Pull:
    """A scripted force (N per node) on the nodes in ``region``: zero before ``start``, rising
    linearly to full over ``ramp`` seconds, zero again from ``stop`` (may be ``inf``) on."""
    region: Region
    force: Vec3
    start: float
    ramp: float
    stop: float

    def force_at(self, t: float) -> np.ndarray:
        """Returns the (3,) float64 force per node at simulation time ``t`` seconds."""
        if t < self.start or t >= self.stop:
            scale = 0.0
        else:
            scale = min(1.0, (t - self.start) / self.ramp) if self.ramp > 0.0 else 1.0
        return np.asarray(self.force, dtype=np.float64) * scale


@dataclass(frozen=True, slots=True)
class Keyframes:
    """A piecewise-linear path: ``points`` (bounding-box fractions) at increasing ``times`` (s);
    before the first time it is at the first point, after the last at the last."""
    points: tuple[Vec3, ...]
    times: tuple[float, ...]

    def at(self, t: float) -> np.ndarray:
        """Returns the (3,) point (box fractions) at time ``t``."""
        p = np.asarray(self.points, dtype=np.float64)
        return np.array([np.interp(t, self.times, p[:, c]) for c in range(3)])


@dataclass(frozen=True, slots=True)
class SpringClass:
    """Stiffness (N/m; None: ``physics.stiffness``) and damping along the spring (N*s/m) of one
    spring class (Movania & Feng 2012, section 3)."""
    stiffness: float | None
    damping: float


@dataclass(frozen=True, slots=True)
class SphereSpec:
    """A sphere obstacle: fixed ``centre`` or moving along ``path`` (box fractions); ``radius``
    in units of the bounding box's longest side."""
    centre: Vec3 | None
    path: Keyframes | None
    radius: float


@dataclass(frozen=True, slots=True)
class DragSpec:
    """A scripted drag: the node nearest to the path's first point is pulled toward the moving
    point through a zero-rest-length spring of ``stiffness`` N/m."""
    path: Keyframes
    stiffness: float


@dataclass(frozen=True, slots=True)
class Converge:
    """Stop once no node moved more than ``threshold`` grid spacings in a step (checked every
    ``every`` steps, on the GPU); ``physics.steps`` is the limit."""
    threshold: float
    every: int


#: What to do with a dt above the integrator's stability limit (``physics.safety.unstable``).
UNSTABLE_POLICIES = ("refuse", "run", "subdivide")


@dataclass(frozen=True, slots=True)
class Safety:
    """Guards of a run: what a dt above the stability limit does (``refuse`` it, ``run`` anyway,
    or ``subdivide`` each step into enough substeps; ``subdivide`` also restarts a run that blew
    up with half the step, up to 16 substeps per step), and how often the GPU counts the
    non-finite or far-away nodes (every ``check_every`` steps; 0: only at the end); a node
    farther than ``bad_distance`` box lengths from the box centre counts as blown up."""
    unstable: str = "refuse"
    check_every: int = 100
    bad_distance: float = 1000.0


@dataclass(frozen=True, slots=True)
class Physics:
    """Time step (s), steps, spring stiffness (N/m), velocity damping (N*s/m), mass per node (kg),
    gravity (m/s^2), fixed regions and pulls; the integrator and backend; springs by class, wind
    (air velocity m/s and linear drag N*s/m), ground (box fraction along y), spheres, drags and
    the convergence stop."""
    dt: float
    steps: int
    stiffness: float
    damping: float
    mass: float
    gravity: Vec3
    fixed: tuple[Region, ...]
    pull: tuple[Pull, ...]
    integrator: str = "verlet"
    backend: str = "fragment"
    structural: SpringClass = SpringClass(None, 0.0)
    shear: SpringClass = SpringClass(None, 0.0)
    flexion: SpringClass = SpringClass(0.0, 0.0)
    wind: Vec3 = (0.0, 0.0, 0.0)
    wind_drag: float = 0.0
    ground: float | None = None
    sphere: tuple[SphereSpec, ...] = ()
    drag: tuple[DragSpec, ...] = ()
    converge: Converge | None = None
    safety: Safety = Safety()

    def class_stiffness(self) -> tuple[float, float, float]:
        """Stiffness of the structural, shear and flexion springs in N/m."""
        return tuple(self.stiffness if c.stiffness is None else c.stiffness
                     for c in (self.structural, self.shear, self.flexion))  # type: ignore[return-value]

    @property
    def extended(self) -> bool:
        """Uses anything the foundation's fragment Verlet pass does not model (springs by class,
        spring damping, flexion, wind, obstacles, drags, the convergence stop)."""
        k1, k2, k3 = self.class_stiffness()
        return bool(k1 != self.stiffness or k2 != self.stiffness or k3 > 0
                    or self.structural.damping or self.shear.damping or self.flexion.damping
                    or self.wind_drag > 0 or self.ground is not None or self.sphere or self.drag
                    or self.converge is not None)


@dataclass(frozen=True, slots=True)
class Camera:
    """Angles in degrees, ``distance`` in bounding-box diagonals, ``target`` in box fractions."""
    projection: str
    azimuth: float
    elevation: float
    fov: float
    distance: float
    target: Vec3


@dataclass(frozen=True, slots=True)
class Light:
    """Directional light; ``direction`` points towards the light and has unit length."""
    direction: Vec3
    colour: Vec3
    ambient: float


@dataclass(frozen=True, slots=True)
class Material:
    """Surface colour and specular parameters."""
    colour: Vec3
    specular: float
    shininess: float


@dataclass(frozen=True, slots=True)
class Render:
    """Image (width, height), multisampling, background and what to draw."""
    size: tuple[int, int]
    msaa: int
    background: Vec3
    show_grid: bool
    camera: Camera
    light: Light
    material: Material


@dataclass(frozen=True, slots=True)
class Mapping:
    """How the detailed mesh is drawn from the nodes (Mosegaard & Sørensen 3.2-3.3).

    ``mode``: "one-to-one" (the node-grid surface), "constant" (eq. 6), "curvature" (eq. 8) or
    "auto" (eq. 8 where the node normals are well defined, eq. 6 elsewhere). ``normal_map``:
    None, "procedural", or an absolute path to a tangent-space normal-map PNG.
    """
    mode: str
    normal_map: str | Path | None
    normal_map_strength: float
    normal_map_repeat: float
    cache: bool


@dataclass(frozen=True, slots=True)
class MotionSpec:
    """An analytic node motion (see :class:`deformgl.node_drivers.Motion`); axes as 0/1/2."""
    kind: str
    angle: float
    axis: int
    along: int
    towards: int
    translate: Vec3
    amount: float


@dataclass(frozen=True, slots=True)
class Nodes:
    """Where node positions come from: "simulate", "file" (``.npy``) or "motion"."""
    source: str
    file: Path | None
    frame: int
    motion: MotionSpec | None


@dataclass(frozen=True, slots=True)
class Attach:
    """A tube attached to the deforming detailed mesh (Knuth et al., section 5): anchors at the
    mesh vertices nearest to a path from ``start`` to ``end`` (bounding-box fractions);
    ``radius`` in bounding-box diagonals."""
    start: Vec3
    end: Vec3
    anchors: int
    radius: float
    colour: Vec3


@dataclass(frozen=True, slots=True)
class Output:
    """Where the PNG goes (absolute)."""
    path: Path


@dataclass(frozen=True, slots=True)
class Scene:
    """A validated scene; ``source`` is the absolute path of its scene file."""
    source: Path
    mesh: MeshSpec | None
    grid: GridSpec
    physics: Physics
    render: Render
    output: Output
    mapping: Mapping = None  # type: ignore[assignment]  # set by load_scene
    nodes: Nodes = None  # type: ignore[assignment]
    attach: tuple[Attach, ...] = ()
    cloth: ClothSpec | None = None

    @property
    def name(self) -> str:
        """What the scene deforms, for messages: the mesh file name or ``cloth NxM``."""
        if self.mesh is not None:
            return self.mesh.path.name
        return f"cloth {self.cloth.nodes[0]}x{self.cloth.nodes[1]}"  # type: ignore[union-attr]

    def with_overrides(
        self, *, mesh: Path | None = None, steps: int | None = None, size: tuple[int, int] | None = None,
        mapping: str | None = None, integrator: str | None = None, backend: str | None = None,
        unstable: str | None = None, check_every: int | None = None,
    ) -> Scene:
        """Returns a copy with command-line overrides, validated like the scene file.

        Args:
            mesh: Replacement mesh file (relative to the working directory); must exist.
            mapping: Replacement mapping mode.
            integrator: Replacement ``physics.integrator``.
            backend: Replacement ``physics.backend``.
            steps: Replacement step count, >= 0.
            unstable: Replacement ``physics.safety.unstable`` (refuse, run, subdivide).
            check_every: Replacement ``physics.safety.check_every``, >= 0.
            size: Replacement (width, height), each in 1..16384.

        Raises:
            SceneError: ``"<scene file>: --steps: <what>"`` and so on.
        """
        file, scene = str(self.source), self
        if mesh is not None:
            if scene.cloth is not None:
                _fail(file, "--mesh", "a cloth scene has no mesh to replace")
            scene = dataclasses.replace(scene, mesh=MeshSpec(_existing(file, "--mesh", Path(mesh).resolve())))
        for flag, key, value, check in (("--integrator", "integrator", integrator, _INTEGRATOR),
                                        ("--backend", "backend", backend, _BACKEND)):
            if value is not None:
                scene = dataclasses.replace(scene, physics=dataclasses.replace(
                    scene.physics, **{key: check(file, flag, value)}))
        if steps is not None:
            scene = dataclasses.replace(
                scene, physics=dataclasses.replace(scene.physics, steps=_STEPS(file, "--steps", steps)))
        for flag, key, value, check in (("--unstable", "unstable", unstable, _str(UNSTABLE_POLICIES)),
                                        ("--check-every", "check_every", check_every, _int(lo=0))):
            if value is not None:
                safety = dataclasses.replace(scene.physics.safety, **{key: check(file, flag, value)})
                scene = dataclasses.replace(scene, physics=dataclasses.replace(scene.physics, safety=safety))
        if size is not None:
            scene = dataclasses.replace(
                scene, render=dataclasses.replace(scene.render, size=_SIZE(file, "--size", size)))
        if mapping is not None:
            scene = dataclasses.replace(
                scene, mapping=dataclasses.replace(scene.mapping, mode=_MAPPING_MODE(file, "--mapping", mapping)))
            if scene.attach and mapping == "one-to-one":
                _fail(file, "--mapping", "one-to-one draws no detailed mesh, which the scene's attach entries need")
            if scene.cloth is not None and mapping != "one-to-one":
                _fail(file, "--mapping", "a cloth scene has no detailed mesh: only one-to-one")
        return scene


def parse_size(text: str) -> tuple[int, int]:
    """Parses ``"WIDTHxHEIGHT"``, e.g. ``"800x600"`` -> ``(800, 600)``.

    Raises:
        ValueError: If the text is not of that form or a side is outside 1..16384.
    """
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if m is None:
        raise ValueError(f"invalid size {text!r}: expected WIDTHxHEIGHT, e.g. 800x600")
    w, h = int(m[1]), int(m[2])
    if not (1 <= w <= MAX_SIZE and 1 <= h <= MAX_SIZE):
        raise ValueError(f"invalid size {text!r}: width and height must each be in 1..{MAX_SIZE}")
    return w, h


# --- checkers: (file, key path, raw TOML value) -> checked value, or SceneError -------------------

Check = Callable[[str, str, Any], Any]
Build = Callable[[str, str, dict[str, Any]], Any]
REQUIRED: Any = object()  # schema default: the key must be given
# Schema defaults are raw TOML values run through the key's checker; None stays None (absent).


def _fail(file: str, key: str, msg: str) -> NoReturn:
    raise SceneError(f"{file}: {key}: {msg}")


def _join(key: str, sub: str) -> str:
    return f"{key}.{sub}" if key else sub


def _describe(v: object) -> str:
    if isinstance(v, bool):
        return f"boolean {str(v).lower()}"
    for types, name in ((int, "integer"), (float, "float"), (str, "string")):
        if isinstance(v, types):
            return f"{name} {v!r}"
    if isinstance(v, (list, tuple)):
        return f"array of {len(v)} elements"
    return "table" if isinstance(v, dict) else f"{type(v).__name__} {v}"


def _num(*, integer: bool = False, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
         hi_open: bool = False, allow_inf: bool = False, choices: tuple[int, ...] | None = None) -> Check:
    """A checker for a number (ints accepted, bools not), or an int with ``integer``, within bounds."""
    def check(file: str, key: str, v: Any) -> Any:
        if isinstance(v, bool) or not isinstance(v, int if integer else (int, float)):
            _fail(file, key, f"must be {'an integer' if integer else 'a number'}, got {_describe(v)}")
        if math.isnan(v) or (math.isinf(v) and not allow_inf):
            _fail(file, key, f"must be finite, got {v!r}")
        if choices is not None and v not in choices:
            _fail(file, key, f"must be one of {', '.join(map(repr, choices))}, got {v!r}")
        if (lo is None or (v > lo if lo_open else v >= lo)) and (hi is None or (v < hi if hi_open else v <= hi)):
            return v if integer else float(v)
        if lo is not None and hi is not None:
            want = f"in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
        else:
            want = f"{'>' if lo_open else '>='} {lo:g}" if lo is not None else f"{'<' if hi_open else '<='} {hi:g}"
        _fail(file, key, f"must be {want}, got {v!r}")
    return check


def _of(kind: type, what: str, choices: tuple[str, ...] | None = None) -> Check:
    """A checker for a value of type ``kind`` (described as ``what``), optionally one of ``choices``."""
    def check(file: str, key: str, v: Any) -> Any:
        if not isinstance(v, kind):
            _fail(file, key, f"must be {what}, got {_describe(v)}")
        if choices is not None and v not in choices:
            _fail(file, key, f"must be one of {', '.join(map(repr, choices))}, got {v!r}")
        return v
    return check


def _int(**bounds: Any) -> Check:
    return _num(integer=True, **bounds)


def _str(choices: tuple[str, ...] | None = None) -> Check:
    return _of(str, "a string", choices)


def _vec(n: int, item: Check | None = None) -> Check:
    def check(file: str, key: str, v: Any) -> tuple[Any, ...]:
        if not isinstance(v, (list, tuple)):
            _fail(file, key, f"must be an array of {n} values, got {_describe(v)}")
        if len(v) != n:
            _fail(file, key, f"must have {n} elements, got {len(v)}")
        return tuple((item or _num())(file, f"{key}[{i}]", x) for i, x in enumerate(v))
    return check


def _array(item: Check, most: int | None = None) -> Check:
    def check(file: str, key: str, v: Any) -> tuple[Any, ...]:
        if not isinstance(v, list):
            _fail(file, key, f"must be an array of tables ([[{key}]]), got {_describe(v)}")
        if most is not None and len(v) > most:
            _fail(file, key, f"at most {most} entries are allowed, got {len(v)}")
        return tuple(item(file, f"{key}[{i}]", x) for i, x in enumerate(v))
    return check


def _table(schema: dict[str, tuple[Check, Any]], build: Build) -> Check:
    """A checker for a table: unknown keys first, then each key in schema order, then ``build``."""
    def check(file: str, key: str, v: Any) -> Any:
        if not isinstance(v, dict):
            _fail(file, key, f"must be a table, got {_describe(v)}")
        for k in v:
            if k not in schema:
                close = difflib.get_close_matches(k, list(schema), n=1)
                hint = f"did you mean {close[0]!r}?" if close else "expected one of " + ", ".join(map(repr, schema))
                _fail(file, _join(key, k), f"unknown key ({hint})")
        values = {}
        for k, (sub, default) in schema.items():
            if k not in v and default is REQUIRED:
                _fail(file, _join(key, k), "required key is missing")
            raw = v.get(k, default)
            values[k] = None if raw is None else sub(file, _join(key, k), raw)
        return build(file, key, values)
    return check


def _plain(cls: Callable[..., Any]) -> Build:
    return lambda file, key, d: cls(**d)


def _existing(file: str, key: str, path: Path) -> Path:
    if not path.is_file():
        _fail(file, key, f"{'not a file' if path.exists() else 'file not found'}: {path}")
    return path


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
_STEPS, _SIZE = _int(lo=0), _vec(2, _int(lo=1, hi=MAX_SIZE))
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


_INTEGRATOR, _BACKEND = _str(INTEGRATORS), _str(BACKENDS)
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


MAPPING_MODES = ("one-to-one", "constant", "curvature", "auto")
_MAPPING_MODE = _str(MAPPING_MODES)
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
