"""What a scene file describes: frozen dataclasses of validated values (positions as bounding-box
fractions, the rest SI), made by :func:`deformgl.scene.schema.load_scene`, and
:func:`parse_size` for ``WIDTHxHEIGHT`` strings.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from deformgl.grid.blocks import BLOCK_SHAPES
from deformgl.scene.checks import Check, _existing, _fail, _int, _str, _vec
from deformgl.sim.equilibrium import ConvergeRule
from deformgl.sim.guards import UNSTABLE_POLICIES
from deformgl.sim.implicit import DEFAULT_PRECONDITIONER
from deformgl.sim.integrators import INTEGRATORS
from deformgl.sim.materials import ElasticMaterial, SheetMaterial
from deformgl.sim.simulation import BACKENDS  # where a scene's simulation runs

Vec3 = tuple[float, float, float]
MAX_SIZE = 16384
#: The smallest image side (pixels): below it a render can miss the body altogether, a blank image
#: written as a success (found by tests/test_fuzz_render.py: a 64x1 render.size).
MIN_SIZE = 16
#: The smallest mesh (its longest bounding-box side, mesh units times scale) a grid is built for:
#: below it the voxelizer's arithmetic overflows and float32 positions draw nothing (found by
#: tests/test_fuzz_render.py: a box scaled by 1e-38 rendered blank, by 5e-324 crashed).
MIN_EXTENT = 1e-30
MSAA_CHOICES = (0, 1, 2, 4, 8, 16)
AXES = ("x", "y", "z")
MAX_SPHERES = 8
MAX_DRAGS = 8
MAPPING_MODES = ("one-to-one", "constant", "curvature", "auto")
#: Sanity limits of scene sizes (docs/SCENE_LIMITS.md): steps of a run, nodes along a grid's
#: longest side, points of a keyframed path.
MAX_STEPS = 100_000_000
MAX_GRID_NODES = 1024
MAX_KEYFRAMES = 10_000
# the checkers the command-line overrides share with the scene file's tables
_STEPS, _SIZE = _int(lo=0, sane=(0, MAX_STEPS)), _vec(2, _int(lo=MIN_SIZE, hi=MAX_SIZE))
_CHECK_EVERY = _int(lo=0, sane=(0, MAX_STEPS))
_INTEGRATOR, _BACKEND, _MAPPING_MODE = _str(INTEGRATORS), _str(BACKENDS), _str(MAPPING_MODES)
#: ``[physics] layout``, the node layout of the fragment backend's Verlet pass: "auto" (several
#: nodes per fragment where measured faster, :func:`deformgl.sim.backends.blocked.default_block`),
#: "compact" (one node per fragment), or a block of nodes per fragment "XxYxZ".
NODE_LAYOUTS = ("auto", "compact") + tuple("x".join(map(str, s)) for s in BLOCK_SHAPES)
_LAYOUT = _str(NODE_LAYOUTS)


@dataclass(frozen=True, slots=True)
class MeshSpec:
    """The detailed mesh to deform: an absolute path that existed at load time, and ``scale``:
    metres per mesh unit (the mesh, and ``grid.spacing``, are scaled by it before anything else,
    so a material scene means the same body whatever unit the mesh file uses)."""
    path: Path
    scale: float = 1.0


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
    """A scripted force (N per node; with a ``[material]`` N in all, spread over the region's
    node masses: :func:`deformgl.scene.physics.scene_loads`) on the nodes in ``region``: zero before ``start``, rising
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
class Xpbd:
    """``[physics.xpbd]``: Jacobi sweeps per substep and substeps per step of the XPBD integrator
    (:mod:`deformgl.sim.xpbd`; used with ``integrator = "xpbd"``)."""
    iterations: int = 10
    substeps: int = 1


#: ``[physics.converge]``: stop at equilibrium (the default criterion) or when no node moved more
#: than ``threshold`` grid spacings in a step ("displacement"); ``physics.steps`` is the limit
#: (:class:`deformgl.sim.equilibrium.ConvergeRule`).
Converge = ConvergeRule


#: What to do with a dt above the integrator's stability limit (``physics.safety.unstable``).


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
class Implicit:
    """The solver of ``integrator = "implicit-euler"`` (``[physics.implicit]``): at most
    ``iterations`` conjugate-gradient iterations per step, stopping early at the relative
    residual ``tolerance`` (``|b - A dv| / |b|``, or below the positions' rounding-noise floor; 0: always
    ``iterations``, nothing read back while stepping), with the ``preconditioner`` "jacobi" (the
    diagonal), "block-jacobi" (the 3x3 block per node) or "multigrid" (a V-cycle over the node
    grid, :mod:`deformgl.sim.multigrid`)."""
    iterations: int = 20
    tolerance: float = 0.0
    preconditioner: str = DEFAULT_PRECONDITIONER

    def options(self) -> dict[str, object]:
        """The :func:`~deformgl.sim.simulation.make_simulation` options."""
        return {"cg_iterations": self.iterations, "cg_tolerance": self.tolerance,
                "cg_preconditioner": self.preconditioner}


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
    #: the Verlet pass's node layout (:data:`NODE_LAYOUTS`; fragment backend, Verlet only)
    layout: str = "auto"
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
    implicit: Implicit = Implicit()
    #: ``[physics.xpbd]`` (None: the defaults; only with ``integrator = "xpbd"``)
    xpbd: Xpbd | None = None
    #: the body's material (a top-level ``[material]`` table): the springs, masses and damping
    #: come from it (:mod:`deformgl.sim.materials`) instead of ``stiffness``, ``mass``,
    #: ``damping`` and ``springs``; each pull's ``force`` is then the total force in N on its
    #: region, split equally over the region's nodes.
    material: ElasticMaterial | SheetMaterial | None = None

    def class_stiffness(self) -> tuple[float, float, float]:
        """Stiffness of the structural, shear and flexion springs in N/m."""
        return tuple(self.stiffness if c.stiffness is None else c.stiffness
                     for c in (self.structural, self.shear, self.flexion))  # type: ignore[return-value]


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


#: ``[render] aa``: "msaa" (``msaa`` samples, the default), "fxaa" (the post-process pass of
#: ``shaders/render/fxaa.frag`` on a single-sampled image; ``msaa`` is then unused) or "none".
AA_CHOICES = ("msaa", "fxaa", "none")


@dataclass(frozen=True, slots=True)
class Render:
    """Image (width, height), anti-aliasing, background and what to draw."""
    size: tuple[int, int]
    msaa: int
    background: Vec3
    show_grid: bool
    camera: Camera
    light: Light
    material: Material
    aa: str = "msaa"
    #: cull the detailed mesh's back faces where it is closed (render.mapped.closed_front_face):
    #: a cheaper draw, the same image where the surface neither folds nor intersects itself
    cull: bool = False

    @property
    def samples(self) -> int:
        """MSAA samples of the render target (0: single-sampled, as with aa = "fxaa" or "none")."""
        return int(self.msaa) if self.aa == "msaa" and self.msaa > 1 else 0

    @property
    def fxaa(self) -> bool:
        """Whether the image goes through the FXAA pass."""
        return self.aa == "fxaa"


@dataclass(frozen=True, slots=True)
class Mapping:
    """How the detailed mesh is drawn from the nodes (Mosegaard & Sørensen 3.2-3.3).

    ``mode``: "one-to-one" (the node-grid surface), "constant" (eq. 6), "curvature" (eq. 8) or
    "auto" (Mosegaard & Sørensen 2005, eq. 8 where the node normals are well defined, eq. 6 elsewhere). ``normal_map``:
    None, "procedural", or an absolute path to a tangent-space normal-map PNG.
    """
    mode: str
    normal_map: str | Path | None
    normal_map_strength: float
    normal_map_repeat: float
    cache: bool


@dataclass(frozen=True, slots=True)
class MotionSpec:
    """An analytic node motion (see :class:`deformgl.mapping.node_drivers.Motion`); axes as 0/1/2."""
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
class CameraKey:
    """A camera keyframe of an animation: at ``at`` (fraction 0..1 of the animation) the camera's
    azimuth and elevation (degrees) and distance (box diagonals); None keeps ``render.camera``'s."""
    at: float
    azimuth: float | None
    elevation: float | None
    distance: float | None


@dataclass(frozen=True, slots=True)
class Animation:
    """``[animation]``: ``frames`` images at ``fps`` from one simulation run, frame k at step
    ``k * steps_per_frame`` (frame 0 is the start state; 0 steps per frame: ``physics.steps``,
    then every frame of that one state, e.g. a turntable); ``seconds_per_frame`` (s of simulated
    time) is the other way to say it (rounded to whole steps of ``physics.dt``). The camera adds
    ``turntable`` degrees of azimuth over the animation and follows the ``camera`` keyframes
    (linear between them)."""
    frames: int
    fps: float
    steps_per_frame: int | None
    seconds_per_frame: float | None
    turntable: float
    camera: tuple[CameraKey, ...]


@dataclass(frozen=True, slots=True)
class Output:
    """Where the image goes (absolute): a .png, or for an animation .gif, .webp, .mp4 or a
    frame pattern such as ``frames/%04d.png``."""
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
    animation: Animation | None = None

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
            scale = scene.mesh.scale if scene.mesh is not None else 1.0  # the mesh.scale stays
            scene = dataclasses.replace(scene, mesh=MeshSpec(_existing(file, "--mesh", Path(mesh).resolve()), scale))
        for flag, key, value, check in (("--integrator", "integrator", integrator, _INTEGRATOR),
                                        ("--backend", "backend", backend, _BACKEND)):
            if value is not None:
                scene = dataclasses.replace(scene, physics=dataclasses.replace(
                    scene.physics, **{key: check(file, flag, value)}))
        material = scene.physics.material
        for needs in material.term_needs if material is not None else ():
            if integrator is not None and (why := needs.refusal(integrator)) is not None:
                _fail(file, "--integrator", f"{integrator}: the scene's {needs.key} {why}")
        if steps is not None:
            scene = dataclasses.replace(
                scene, physics=dataclasses.replace(scene.physics, steps=_STEPS(file, "--steps", steps)))
        safety_overrides: tuple[tuple[str, str, object, Check], ...] = (
            ("--unstable", "unstable", unstable, _str(UNSTABLE_POLICIES)),
            ("--check-every", "check_every", check_every, _CHECK_EVERY))
        for flag, key, given, check in safety_overrides:
            if given is not None:
                safety = dataclasses.replace(scene.physics.safety, **{key: check(file, flag, given)})
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
        if getattr(material, "model", None) == "spline":  # (what load_scene refused, the overrides may give)
            from deformgl.scene.spline_model import spline_refusal

            refused = spline_refusal(scene.physics)
            if refused is not None:
                flag = {"physics.backend": "--backend", "physics.layout": "--layout"}.get(refused[0], refused[0])
                _fail(file, flag, refused[1])
            if mapping is not None and mapping != "auto":
                _fail(file, "--mapping", f'{mapping!r} is a mapping to the lattice\'s nodes; model = "spline" draws '
                      "the mesh through its field")
        return scene


def parse_size(text: str) -> tuple[int, int]:
    """Parses ``"WIDTHxHEIGHT"``, e.g. ``"800x600"`` -> ``(800, 600)``.

    Raises:
        ValueError: If the text is not of that form or a side is outside 16..16384.
    """
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if m is None:
        raise ValueError(f"invalid size {text!r}: expected WIDTHxHEIGHT, e.g. 800x600")
    w, h = int(m[1]), int(m[2])
    if not (MIN_SIZE <= w <= MAX_SIZE and MIN_SIZE <= h <= MAX_SIZE):
        raise ValueError(f"invalid size {text!r}: width and height must each be in {MIN_SIZE}..{MAX_SIZE}")
    return w, h
