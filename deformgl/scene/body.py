"""A soft body from Python: a detailed mesh (a file or NumPy ``(V, F)`` arrays) voxelized into a
node grid, its spring system, simulations of it, its mapped detailed mesh and images of it.

This is the code path of a scene (:mod:`deformgl.scene.pipeline`) without the scene file: the
mesh is recentred on its bounding-box centre, voxelized at ``resolution`` nodes along its longest
side (or at ``spacing``), the spring system is built from the physics
(:func:`~deformgl.scene.run.scene_system`), the binding to the node surface is the scene's (cached the same way), and
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

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import moderngl
import numpy as np
import trimesh

from deformgl.errors import InputError
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
from deformgl.scene.pipeline import mesh_grid, recentred
from deformgl.sim.materials import PRESETS, ElasticMaterial, LatticeReport
from deformgl.scene.run import scene_system
from deformgl.scene.schema import load_scene
from deformgl.scene.spec import AXES, Physics, Region, Scene
from deformgl.scene.stepping import GuardedSimulation, make_simulation
from deformgl.sim.backends.foundation import NodeTextures
from deformgl.sim.normals import rest_normals
from deformgl.sim.springs import SpringSystem

__all__ = ["Body", "above", "below", "inside", "render_scene", "render_to_png", "write_png"]

#: The mapping modes :meth:`Body.mapped_mesh` and :meth:`Body.render` accept.
MAPPINGS = ("one-to-one", "constant", "curvature", "auto")


def _axis(axis: int | str) -> int:
    if isinstance(axis, str):
        if axis not in AXES:
            raise ValueError(f"axis must be one of {AXES} or 0..2, got {axis!r}")
        return AXES.index(axis)
    if axis not in (0, 1, 2):
        raise ValueError(f"axis must be one of {AXES} or 0..2, got {axis!r}")
    return int(axis)


def below(axis: int | str, at: float) -> Region:
    """The region at or below bounding-box fraction ``at`` along ``axis`` ("x", "y", "z" or 0..2),
    as a scene's ``[[physics.fixed]] below = ...``."""
    return Region("below", _axis(axis), float(at), None, None)


def above(axis: int | str, at: float) -> Region:
    """The region at or above bounding-box fraction ``at`` along ``axis``."""
    return Region("above", _axis(axis), float(at), None, None)


def inside(lo: Sequence[float], hi: Sequence[float]) -> Region:
    """The box of bounding-box fractions from ``lo`` to ``hi`` (3 each, inclusive)."""
    lo3 = tuple(float(v) for v in lo)
    hi3 = tuple(float(v) for v in hi)
    if len(lo3) != 3 or len(hi3) != 3:  # checked before the tuples are built
        raise ValueError("inside: lo and hi must have 3 components each")
    return Region("box", None, None, (lo3[0], lo3[1], lo3[2]), (hi3[0], hi3[1], hi3[2]))


def write_png(path: str | os.PathLike[str], image: np.ndarray) -> None:
    """Write a (height, width, 3 or 4) uint8 image as a PNG, atomically (temporary file, then
    rename)."""
    write_png_atomic(Path(path), np.asarray(image))


def _regions(fixed: Region | Sequence[Region] | None) -> tuple[Region, ...]:
    if fixed is None:
        return ()
    if isinstance(fixed, Region):
        return (fixed,)
    return tuple(fixed)


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
    per mesh unit. ``gravity`` m/s^2, ``fixed`` regions.
    """

    def __init__(self, mesh: trimesh.Trimesh, *, resolution: int | None = 8, spacing: float | None = None,
                 stiffness: float | None = None, damping: float | None = None, mass: float | None = None,
                 gravity: Sequence[float] = (0.0, -9.81, 0.0), fixed: Region | Sequence[Region] | None = None,
                 material: ElasticMaterial | str | None = None, scale: float = 1.0,
                 ctx: moderngl.Context | None = None, source: str = "<arrays>") -> None:
        if spacing is not None:
            resolution = None
        elif resolution is None or int(resolution) < 2:
            raise InputError(f"{source}: resolution must be at least 2 nodes along the longest side, got {resolution}")
        given = [name for name, value in (("stiffness", stiffness), ("damping", damping), ("mass", mass))
                 if value is not None]
        if material is not None and given:
            raise InputError(f"{source}: {given[0]}: not used with material= (the springs, masses and damping "
                             f"come from its Young's modulus, density and Rayleigh damping)")
        stiffness = 500.0 if stiffness is None else stiffness
        damping = 0.5 if damping is None else damping
        mass = 0.01 if mass is None else mass
        if isinstance(material, str):
            if material not in PRESETS:
                raise InputError(f"{source}: material must be an ElasticMaterial or one of {', '.join(PRESETS)}, "
                                 f"got {material!r}")
            material = PRESETS[material]
        if not (np.isfinite(scale) and scale > 0):
            raise InputError(f"{source}: scale must be > 0 (metres per mesh unit), got {scale}")
        if scale != 1.0:
            mesh = trimesh.Trimesh(np.asarray(mesh.vertices, np.float64) * scale, mesh.faces, process=False)
            spacing = None if spacing is None else spacing * scale
        recentred_mesh, centre = recentred(mesh)
        self.mesh: trimesh.Trimesh = recentred_mesh
        self.centre: np.ndarray = centre
        self.source = source
        self.grid = mesh_grid(self.mesh, nodes_along_longest=resolution, spacing=spacing, source=source,
                              finer="a larger resolution or a smaller spacing", solid=material is not None)
        self.bbox = np.array(self.mesh.bounds, dtype=np.float64)
        g = tuple(float(v) for v in gravity)
        self.physics = Physics(dt=1e-3, steps=0, stiffness=float(stiffness), damping=0.0 if material else float(damping),
                               mass=float(mass), gravity=(g[0], g[1], g[2]), fixed=_regions(fixed), pull=(),
                               material=material)
        reports: list[LatticeReport] = []
        self.system: SpringSystem = scene_system(self.grid, self.physics, self.bbox, source=source, report=reports)
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
        if isinstance(mesh, trimesh.Trimesh):
            return cls(mesh, **options)
        options.setdefault("source", os.fspath(mesh))
        return cls(load_mesh(mesh), **options)

    @classmethod
    def from_arrays(cls, vertices: Any, faces: Any, **options: Any) -> Body:
        """A body from (V, 3) float vertices and (F, 3) integer triangles; ``options`` as
        :class:`Body`.

        Raises:
            InputError: the arrays are not of those shapes or have a non-finite vertex.
        """
        source = options.setdefault("source", "<arrays>")
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
            raise InputError(f"{source}: vertices must have shape (V, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or not np.issubdtype(f.dtype, np.integer):
            raise InputError(f"{source}: faces must be integers of shape (F, 3), got {f.dtype} {f.shape}")
        if not np.isfinite(v).all():
            raise InputError(f"{source}: vertex {int(np.argmax(~np.isfinite(v).all(axis=1)))} is non-finite")
        if f.min() < 0 or f.max() >= len(v):
            raise InputError(f"{source}: a face index is outside 0..{len(v) - 1}")
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
        """A simulation of the body's spring system (:func:`deformgl.make_simulation`), owned by
        the body; step it with :func:`deformgl.run` (guards on) or ``sim.step(n)``.

        Args:
            integrator: "euler", "semi-implicit", "midpoint", "rk4" or "verlet".
            backend: "fragment", "feedback" or "numpy".
            dt: the step (s).
            ctx: the GL context (default: the body's).
            options: passed on (constraints, drags, loads, ...).
        """
        gl_ctx = None if backend == "numpy" else (ctx or self.ctx)
        sim = make_simulation(self.system, integrator, backend, dt=dt, ctx=gl_ctx, grid=self.grid, **options)
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
            raise InputError(f"{self.source}: mapping must be one of {', '.join(MAPPINGS)}, got {mapping!r}")
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
        draw = self._pass(mapping)
        positions = self._upload(sim)
        key = ((int(size[0]), int(size[1])), int(msaa))
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
    loaded = scene if isinstance(scene, Scene) else load_scene(Path(scene))
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
    loaded = scene if isinstance(scene, Scene) else load_scene(Path(scene))
    path = Path(out) if out is not None else loaded.output.path
    if ctx is not None:
        return pipeline.render_to_png(ctx, loaded, path, progress=progress)
    own = create_context()
    try:
        return pipeline.render_to_png(own, loaded, path, progress=progress)
    finally:
        own.release()
