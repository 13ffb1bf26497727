"""A soft body from Python: a detailed mesh (a file or NumPy ``(V, F)`` arrays) voxelized into a
node grid, its spring system, simulations of it, its mapped detailed mesh and images of it.

This is the code path of a scene (:mod:`deformgl.scene.pipeline`) without the scene file: the
mesh is recentred on its bounding-box centre, voxelized at ``resolution`` nodes along its longest
side (or at ``spacing``), the spring system is built from the physics
(:func:`~deformgl.scene.physics.scene_system`), the binding to the node surface is the scene's (cached the same way), and
node positions reach the draw passes through the same :class:`DrivenNodes` upload. Everything GL
the body makes (its context if it made one, simulations, node textures, draw passes, targets)
is owned by one :class:`~deformgl.gl.resources.GLOwner` and freed by :meth:`Body.release` or
``with``::

    with Body.from_arrays(V, F, resolution=8, fixed=below("y", 0.1)) as body:
        sim = body.simulate(dt=1e-3)
        run(sim, 200)
        image = body.render(sim)
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import moderngl
import numpy as np
import trimesh

from deformgl.data import default_output, find_mesh
from deformgl.errors import ArgumentError, InputError
from deformgl.files import check_writable
from deformgl.files import write_png_atomic
from deformgl.gl.context import create_context
from deformgl.gl.resources import GLOwner
from deformgl.grid.meshio import load_mesh
from deformgl.grid.nodes import CompactLayout
from deformgl.grid.surface import grid_surface
from deformgl.mapping.node_drivers import DrivenNodes
from deformgl.render.camera import View, frame_box
from deformgl.render.mapped import MappedMeshPass
from deformgl.render.mapped_setup import get_binding, mapped_vertices
from deformgl.render.passes import GridSurfacePass, Lighting, RenderTarget
from deformgl.scene import pipeline
from deformgl.scene.checks import _one_line
from deformgl.scene.pipeline import mesh_grid, recentred
from deformgl.sim.materials import PRESETS, ElasticMaterial, LatticeReport, SheetMaterial
from deformgl.scene.physics import scene_system
from deformgl.scene.schema import load_scene
from deformgl.scene.spec import AXES, MAX_SIZE, MIN_SIZE, Physics, Region, Scene
from deformgl.sim.restartable import GuardedSimulation
from deformgl.sim.backends.verlet_data import NodeTextures
from deformgl.sim.normals import rest_normals
from deformgl.sim.springs import SpringSystem

__all__ = ["Body", "above", "below", "inside", "render_scene", "render_to_png", "write_png"]

#: The mapping modes :meth:`Body.mapped_mesh` and :meth:`Body.render` accept.
MAPPINGS = ("one-to-one", "constant", "curvature", "auto")


def _real(caller: str, name: str, value: Any, *, above: float | None = None, at_least: float | None = None) -> float:
    """``value`` as a finite float (> ``above``, >= ``at_least`` when given), else
    :class:`ArgumentError` naming ``caller`` and the argument ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ArgumentError(f"{caller}: {name} must be a real number, got {value!r}")
    x = float(value)
    bound = "" if above is None else f" > {above:g}"
    bound += "" if at_least is None else f" >= {at_least:g}"
    if not math.isfinite(x) or (above is not None and not x > above) or (at_least is not None and not x >= at_least):
        raise ArgumentError(f"{caller}: {name} must be a finite number{bound}, got {value!r}")
    return x


def _vec3(caller: str, name: str, value: Any) -> tuple[float, float, float]:
    """Three finite numbers (``gravity``, a box corner), else :class:`ArgumentError`."""
    try:
        items = list(value)
    except TypeError:
        raise ArgumentError(f"{caller}: {name} must be 3 numbers, got {value!r}") from None
    if len(items) != 3:
        raise ArgumentError(f"{caller}: {name} must be 3 numbers, got {len(items)}")
    x, y, z = (_real(caller, f"{name}[{i}]", v) for i, v in enumerate(items))
    return x, y, z


def _is_file(path: Path) -> bool:
    try:
        return path.is_file()
    except (OSError, ValueError):  # (a NUL byte, a name too long)
        return False


def _size(caller: str, size: Any) -> tuple[int, int]:
    """(width, height) in pixels, each :data:`MIN_SIZE` to :data:`MAX_SIZE` as a scene's
    ``render.size``, else :class:`ArgumentError`."""
    try:
        w, h = size
    except (TypeError, ValueError):
        raise ArgumentError(f"{caller}: size must be (width, height) in pixels, got {size!r}") from None
    for name, v in (("size[0]", w), ("size[1]", h)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not MIN_SIZE <= v <= MAX_SIZE:
            raise ArgumentError(f"{caller}: {name} must be an integer of {MIN_SIZE} to {MAX_SIZE} pixels, got {v!r}")
    return int(w), int(h)


def _axis(caller: str, axis: int | str) -> int:
    if isinstance(axis, str) and axis in AXES:
        return AXES.index(axis)
    if not isinstance(axis, (str, bool)) and isinstance(axis, (int, np.integer)) and axis in (0, 1, 2):
        return int(axis)
    raise ArgumentError(f"{caller}: axis must be one of {', '.join(AXES)} or 0..2, got {axis!r}")


def below(axis: int | str, at: float) -> Region:
    """The region at or below bounding-box fraction ``at`` along ``axis`` ("x", "y", "z" or 0..2),
    as a scene's ``[[physics.fixed]] below = ...``."""
    return Region("below", _axis("below", axis), _real("below", "at", at), None, None)


def above(axis: int | str, at: float) -> Region:
    """The region at or above bounding-box fraction ``at`` along ``axis``."""
    return Region("above", _axis("above", axis), _real("above", "at", at), None, None)


def inside(lo: Sequence[float], hi: Sequence[float]) -> Region:
    """The box of bounding-box fractions from ``lo`` to ``hi`` (3 each, inclusive)."""
    return Region("box", None, None, _vec3("inside", "lo", lo), _vec3("inside", "hi", hi))


def write_png(path: str | os.PathLike[str], image: np.ndarray) -> None:
    """Write a (height, width, 3 or 4) uint8 image as a PNG, atomically (temporary file, then
    rename).

    Raises:
        ArgumentError: ``image`` is not such an array; InputError: ``path`` cannot be written.
    """
    array = np.asarray(image)
    if array.dtype != np.uint8 or array.ndim != 3 or array.shape[2] not in (3, 4) or 0 in array.shape:
        raise ArgumentError(f"write_png: image must be a (height, width, 3 or 4) uint8 array, got "
                            f"{array.dtype} {array.shape}")
    check_writable(path, "png")
    write_png_atomic(Path(path), array)


def _regions(caller: str, fixed: Region | Sequence[Region] | None) -> tuple[Region, ...]:
    if fixed is None:
        return ()
    regions = (fixed,) if isinstance(fixed, Region) else tuple(fixed) if isinstance(fixed, (list, tuple)) else None
    if regions is None or not all(isinstance(r, Region) for r in regions):
        raise ArgumentError(f"{caller}: fixed must be a region (below, above, inside) or a list of them, "
                            f"got {fixed!r}")
    return regions


class Body:
    """A detailed mesh, its node grid and spring system: build with :meth:`from_mesh` or
    :meth:`from_arrays`.

    Attributes:
        mesh: the detailed mesh, recentred on its bounding-box centre.
        centre: (3,) the world offset removed (added back to everything returned).
        grid: the node grid (recentred coordinates).
        physics: the physics the system was built from (dt and steps unused).
        system: the spring system every integrator and backend steps.
        bbox: (2, 3) recentred bounding box of the mesh.
        source: the name errors start with (the mesh file, or ``"<arrays>"``).
        lattice: with a ``material``, what the cell assembly found
            (:class:`~deformgl.sim.materials.LatticeReport`), else None.

    Options: ``resolution`` (nodes along the longest side) or ``spacing`` (mesh units);
    ``material``: an :class:`~deformgl.sim.materials.ElasticMaterial` or a preset name
    (``"liver"``, ``"gelatin"``, ...): the calibrated lattice of
    :mod:`deformgl.sim.materials`, the same body at any resolution; without one, the per-spring
    form: ``stiffness`` N/m per spring, ``mass`` kg per node, ``damping`` N*s/m. ``scale``: metres
    per mesh unit. ``gravity`` m/s^2, ``fixed`` regions. ``caller``: the name argument errors
    start with (``Body.from_arrays``, ...): they name the argument as passed (``fixed[0]``),
    where a scene names its key (``physics.fixed[0]``).
    """

    def __init__(self, mesh: trimesh.Trimesh, *, resolution: int | None = 8, spacing: float | None = None,
                 stiffness: float | None = None, damping: float | None = None, mass: float | None = None,
                 gravity: Sequence[float] = (0.0, -9.81, 0.0), fixed: Region | Sequence[Region] | None = None,
                 material: ElasticMaterial | SheetMaterial | str | None = None, scale: float = 1.0,
                 ctx: moderngl.Context | None = None, source: str = "<arrays>", caller: str = "Body") -> None:
        if spacing is not None:
            resolution = None
            spacing = _real(caller, "spacing", spacing, above=0.0)
        elif isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or resolution < 2:
            raise ArgumentError(f"{caller}: resolution must be an integer of at least 2 nodes along the longest side, "
                                f"got {resolution!r}")
        given = [name for name, value in (("stiffness", stiffness), ("damping", damping), ("mass", mass))
                 if value is not None]
        if material is not None and given:
            raise ArgumentError(f"{caller}: {given[0]}: not used with material= (the springs, masses and damping "
                                f"come from its Young's modulus, density and Rayleigh damping)")
        stiffness = 500.0 if stiffness is None else _real(caller, "stiffness", stiffness, above=0.0)
        damping = 0.5 if damping is None else _real(caller, "damping", damping, at_least=0.0)
        mass = 0.01 if mass is None else _real(caller, "mass", mass, above=0.0)
        if isinstance(material, str):
            if material not in PRESETS:
                raise ArgumentError(f"{caller}: material must be an ElasticMaterial or one of {', '.join(PRESETS)}, "
                                    f"got {material!r}")
            material = PRESETS[material]
        elif material is not None and not isinstance(material, (ElasticMaterial, SheetMaterial)):
            raise ArgumentError(f"{caller}: material must be an ElasticMaterial, a SheetMaterial or one of "
                                f"{', '.join(PRESETS)}, got {material!r}")
        if isinstance(material, ElasticMaterial) and material.model == "spline":
            raise ArgumentError(f'{caller}: material: model = "spline" runs from a scene for now (dg.load_scene and '
                                f"dg.render_scene, or deformgl render); Body builds the lattice")
        scale = _real(caller, "scale", scale, above=0.0)
        g = _vec3(caller, "gravity", gravity)
        regions = _regions(caller, fixed)
        extent = np.ptp(np.asarray(mesh.vertices, np.float64), axis=0) * scale if len(mesh.vertices) else np.zeros(3)
        if not (np.isfinite(extent).all() and 0.0 < extent.max() < 1e30):  # (a larger box overflows the springs)
            raise ArgumentError(f"{caller}: the mesh's bounding box {extent.tolist()} (times scale) must be finite, "
                                f"not a point and under 1e30")
        if scale != 1.0:
            mesh = trimesh.Trimesh(np.asarray(mesh.vertices, np.float64) * scale, mesh.faces, process=False)
            spacing = None if spacing is None else spacing * scale
        recentred_mesh, centre = recentred(mesh)
        self.mesh: trimesh.Trimesh = recentred_mesh
        self.centre: np.ndarray = centre
        self.source = source
        self.grid = mesh_grid(self.mesh, nodes_along_longest=resolution, spacing=spacing, source=source,
                              finer="a larger resolution or a smaller spacing", solid=material is not None)
        if isinstance(material, SheetMaterial) and 1 not in self.grid.shape:
            raise ArgumentError(f"{caller}: material: a SheetMaterial needs a grid one node thick (a cloth), this "
                                f"one is {'x'.join(map(str, self.grid.shape))} nodes; use an ElasticMaterial")
        self.bbox = np.array(self.mesh.bounds, dtype=np.float64)
        self.physics = Physics(dt=1e-3, steps=0, stiffness=stiffness, damping=0.0 if material else damping,
                               mass=mass, gravity=g, fixed=regions, pull=(), material=material)
        reports: list[LatticeReport] = []
        self.system: SpringSystem = scene_system(self.grid, self.physics, self.bbox, source=caller, keys="",
                                                 report=reports)
        #: what the cell assembly found (a material body), else None
        self.lattice: LatticeReport | None = reports[0] if reports else None
        self._ctx = ctx
        self._owner: GLOwner | None = None
        self._nodes: tuple[NodeTextures, DrivenNodes] | None = None
        self._passes: dict[str, Any] = {}
        self._targets: dict[tuple[tuple[int, int], int], RenderTarget] = {}

    @classmethod
    def from_mesh(cls, mesh: str | os.PathLike[str] | trimesh.Trimesh, **options: Any) -> Body:
        """A body from a mesh file (PLY, OBJ, STL, GLB, glTF, OFF, optionally ``.gz``; vertices kept
        as stored) or a ``trimesh.Trimesh``; ``options`` as :class:`Body` (``resolution``,
        ``spacing``, ``stiffness``, ``damping``, ``mass``, ``gravity``, ``fixed``, ``material``,
        ``scale``, ``ctx``)."""
        options.setdefault("caller", "Body.from_mesh")
        if isinstance(mesh, trimesh.Trimesh):
            return cls(mesh, **options)
        if not isinstance(mesh, (str, os.PathLike)):
            raise ArgumentError(f"Body.from_mesh: mesh must be a file path or a trimesh.Trimesh, got {type(mesh).__name__}")
        name = _one_line(os.fspath(mesh))  # (how messages show it: a name may hold a line break)
        options.setdefault("source", name)
        path = find_mesh(mesh)
        if not _is_file(path):
            raise InputError(f"{name}: file not found (not in {Path.cwd()} nor among the shipped meshes)")
        return cls(load_mesh(path), **options)

    @classmethod
    def from_arrays(cls, vertices: Any, faces: Any, **options: Any) -> Body:
        """A body from (V, 3) float vertices and (F, 3) integer triangles; ``options`` as
        :class:`Body`.

        Raises:
            InputError: the arrays are not of those shapes or have a non-finite vertex.
        """
        caller = options.setdefault("caller", "Body.from_arrays")
        options.setdefault("source", "<arrays>")
        try:
            if np.iscomplexobj(vertices):  # (the cast would drop the imaginary parts, silently)
                raise TypeError("complex")
            v = np.asarray(vertices, dtype=np.float64)
        except (TypeError, ValueError):
            raise ArgumentError(f"{caller}: vertices must be numbers of shape (V, 3)") from None
        f = np.asarray(faces)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
            raise ArgumentError(f"{caller}: vertices must have shape (V, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or not np.issubdtype(f.dtype, np.integer):
            raise ArgumentError(f"{caller}: faces must be integers of shape (F, 3), got {f.dtype} {f.shape}")
        if not np.isfinite(v).all():
            raise ArgumentError(f"{caller}: vertices[{int(np.argmax(~np.isfinite(v).all(axis=1)))}] is non-finite")
        if f.min() < 0 or f.max() >= len(v):
            bad = int(np.argmax(((f < 0) | (f >= len(v))).any(axis=1)))
            raise ArgumentError(f"{caller}: faces[{bad}] {f[bad].tolist()} has a vertex index outside 0..{len(v) - 1}")
        return cls(trimesh.Trimesh(v, f.astype(np.int64), process=False), **options)

    # -- GL ownership ----------------------------------------------------------------------

    @property
    def ctx(self) -> moderngl.Context:
        """The GL context: the one given, else one created (and released with the body)."""
        return self._gl().ctx

    def _gl(self) -> GLOwner:
        if self._owner is None:
            if self._ctx is None:
                ctx = create_context()
                self._owner = GLOwner(ctx)
                self._owner.own(ctx)  # released last
            else:
                self._owner = GLOwner(self._ctx)
        elif self._owner.released:
            raise RuntimeError("the body is released")
        return self._owner

    def own(self, obj: Any) -> Any:
        """Register a GL object (anything with ``release()``) to be released with the body."""
        return self._gl().own(obj)

    def release(self) -> None:
        """Release every GL object the body made (its simulations included) and its context if it
        created one; calling it again does nothing."""
        if self._owner is not None:
            self._owner.release()
        self._nodes = None
        self._passes.clear()
        self._targets.clear()

    @property
    def released(self) -> bool:
        """Whether :meth:`release` has run (False while the body has made no GL object)."""
        return self._owner is not None and self._owner.released

    def __enter__(self) -> Body:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    # -- simulation ------------------------------------------------------------------------

    def simulate(self, integrator: str = "verlet", backend: str = "fragment", *, dt: float,
                 ctx: moderngl.Context | None = None, **options: Any) -> GuardedSimulation:
        """A restartable simulation of the body's spring system (:class:`deformgl.GuardedSimulation`
        on :func:`deformgl.make_simulation`'s backend), owned by the body; step it with
        :func:`deformgl.run` (guards on) or ``sim.step(n)``.

        Args:
            integrator: "euler", "semi-implicit", "midpoint", "rk4" or "verlet".
            backend: "fragment", "feedback" or "numpy".
            dt: the step (s).
            ctx: the GL context (default: the body's).
            options: passed on (constraints, drags, loads, ...).
        """
        gl_ctx = None if backend == "numpy" else (ctx or self.ctx)
        sim = GuardedSimulation(self.system, integrator, backend, dt=dt, ctx=gl_ctx, grid=self.grid, **options)
        sim.source = self.source
        if backend != "numpy":
            self.own(sim)
        return sim

    def node_positions(self, sim: Any = None) -> np.ndarray:
        """(N, 3) float64 world node positions of ``sim`` (its ``positions()``), or the rest ones."""
        world: np.ndarray = self._local_positions(sim) + self.centre
        return world

    def _local_positions(self, sim: Any) -> np.ndarray:
        if sim is None:
            return self.grid.rest_positions.astype(np.float64)
        x = np.asarray(sim.positions() if hasattr(sim, "positions") else sim, dtype=np.float64)
        if x.ndim != 2 or x.shape[0] != self.grid.count or x.shape[1] < 3:
            raise InputError(f"{self.source}: node positions must have shape ({self.grid.count}, 3), got {x.shape}")
        if hasattr(sim, "positions"):
            return x[:, :3]
        local: np.ndarray = x[:, :3] - self.centre  # world positions given as an array
        return local

    # -- drawing ---------------------------------------------------------------------------

    def _upload(self, sim: Any) -> moderngl.Texture:
        """The node state texture with ``sim``'s positions (or the rest ones) and their normals."""
        if self._nodes is None:
            owner = self._gl()
            max_size = int(owner.ctx.info["GL_MAX_TEXTURE_SIZE"])
            try:
                CompactLayout.for_grid(self.grid, max_size)
            except ValueError as exc:
                raise InputError(f"{self.source}: {exc}; use a coarser grid") from None
            textures = owner.own(NodeTextures(owner.ctx, self.grid))
            driven = owner.own(DrivenNodes(owner.ctx, textures, self.grid))
            self._nodes = (textures, driven)
        self._nodes[1].set_positions(self._local_positions(sim))
        return self._nodes[1].position_texture

    def _pass(self, mapping: str) -> Any:
        if mapping not in MAPPINGS:
            raise ArgumentError(f"Body: mapping must be one of {', '.join(MAPPINGS)}, got {mapping!r}")
        if mapping not in self._passes:
            owner = self._gl()
            if self._nodes is None:
                self._upload(None)
            assert self._nodes is not None
            layout = self._nodes[0].layout
            if mapping == "one-to-one":
                draw: Any = GridSurfacePass(owner.ctx, self.grid, layout)
            else:
                binding = get_binding(self.mesh, self.grid, grid_surface(self.grid), use_cache=True, uv=None)
                data = mapped_vertices(binding, mapping, self.grid.rest_positions, rest_normals(self.grid))
                draw = MappedMeshPass(owner.ctx, self.grid, layout, self.mesh.faces, data)
            self._passes[mapping] = owner.own(draw)
        return self._passes[mapping]

    def mapped_mesh(self, sim: Any = None, mapping: str = "auto") -> tuple[np.ndarray, np.ndarray]:
        """The detailed mesh deformed by ``sim``'s nodes (or by node positions (N, 3) in world
        coordinates; None: the rest nodes), exactly as the mapping vertex shader computes it.

        Returns:
            (V, 3) float64 world vertices and (F, 3) int64 faces (the input's).
        """
        if mapping == "one-to-one":
            raise InputError(f"{self.source}: mapped_mesh needs a mapping of the detailed mesh "
                             f"(constant, curvature or auto), not one-to-one")
        draw = self._pass(mapping)
        vertices, _ = draw.capture(self._upload(sim))
        return vertices.astype(np.float64) + self.centre, np.asarray(self.mesh.faces, dtype=np.int64)

    def view(self, *, size: tuple[int, int] = (640, 480), azimuth: float = 30.0, elevation: float = 20.0,
             fov: float = 35.0, distance: float = 1.6, projection: str = "perspective",
             target: Sequence[float] = (0.5, 0.5, 0.5)) -> View:
        """The camera framing the rest bounding box (a scene's ``[render.camera]`` defaults)."""
        return frame_box(self.bbox[0], self.bbox[1], projection=projection, azimuth=azimuth,
                         elevation=elevation, fov=fov, distance=distance, target=np.asarray(target, np.float64),
                         aspect=size[0] / size[1])

    def render(self, sim: Any = None, *, mapping: str = "auto", size: tuple[int, int] = (640, 480),
               msaa: int = 4, background: tuple[float, float, float] = (1.0, 1.0, 1.0),
               view: View | None = None, lighting: Lighting | None = None) -> np.ndarray:
        """An image of the body with ``sim``'s nodes (or node positions (N, 3), world; None: at rest).

        Args:
            mapping: "auto", "constant", "curvature" (the detailed mesh) or "one-to-one" (the
                node-grid surface).
            size: (width, height) pixels; msaa: samples; background: RGB in [0, 1].
            view: the camera (default: :meth:`view`); lighting: default as a scene's.

        Returns:
            (height, width, 3) uint8, top row first.
        """
        key = (_size("Body.render", size), int(_real("Body.render", "msaa", msaa, at_least=0)))
        if key[1] not in (0, 1, 2, 4, 8):
            raise ArgumentError(f"Body.render: msaa must be 0, 1, 2, 4 or 8 samples, got {msaa!r}")
        draw = self._pass(mapping)
        positions = self._upload(sim)
        if key not in self._targets:
            self._targets[key] = self.own(RenderTarget(self.ctx, key[0], key[1]))
        target = self._targets[key]
        target.begin(background)
        draw.draw(positions, view or self.view(size=key[0]),
                  lighting or Lighting(direction=(0.4, 1.0, 0.6)))
        return target.read_rgb()


def render_scene(scene: Scene | str | os.PathLike[str], *, ctx: moderngl.Context | None = None,
                 progress: bool = False) -> np.ndarray:
    """Simulate (or drive) a scene and render it as the CLI does: (height, width, 3) uint8.

    Args:
        scene: a :class:`~deformgl.scene.spec.Scene` or the path of a scene file.
        ctx: the GL context (default: one created for the call and released after it).
    """
    loaded = scene if isinstance(scene, Scene) else load_scene(scene)
    if ctx is not None:
        return pipeline.render_scene(ctx, loaded, progress=progress)
    own = create_context()
    try:
        return pipeline.render_scene(own, loaded, progress=progress)
    finally:
        own.release()


def render_to_png(scene: Scene | str | os.PathLike[str], out: str | os.PathLike[str] | None = None, *,
                  ctx: moderngl.Context | None = None, progress: bool = False) -> np.ndarray:
    """Render a scene and write the PNG (default: the scene's ``output.path``) atomically; returns
    the image."""
    loaded = scene if isinstance(scene, Scene) else load_scene(scene)
    path = Path(out) if out is not None else default_output(loaded.source, loaded.output.path)
    check_writable(path)
    if ctx is not None:
        return pipeline.render_to_png(ctx, loaded, path, progress=progress)
    own = create_context()
    try:
        return pipeline.render_to_png(own, loaded, path, progress=progress)
    finally:
        own.release()
