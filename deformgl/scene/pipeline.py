"""From a scene to a PNG: load the mesh, build the grid and spring system, simulate, render, write.

Positions are recentred on the mesh's bounding-box centre before anything reaches float32 GPU
memory, so a mesh far from the origin keeps its precision; the offset is kept in
:attr:`SceneModel.centre`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import moderngl
import numpy as np
import trimesh

from deformgl.trilinear.attachments import TubeAttachment
from deformgl.render.camera import View, frame_box
from deformgl.scene.budget import check_scene
from deformgl.scene.obstacles import draw_obstacles
from deformgl.errors import InputError, SimulationError
from deformgl.grid.nodes import CompactLayout, NodeGrid, layout_uniforms
from deformgl.files import OutputSet, write_png_atomic
from deformgl.render.mapped import MappedMeshPass, closed_front_face
from deformgl.render.mapped_setup import export_mesh, get_binding, mapped_vertices, mesh_uv, normal_map_image
from deformgl.grid.meshio import load_mesh
from deformgl.sim.normals import rest_normals
from deformgl.sim.springs import SpringSystem
from deformgl.sim.scripted import Load
from deformgl.render.passes import GridSurfacePass, Lighting, RenderTarget
from deformgl.scene.spec import Scene
from deformgl.scene.spec import MIN_EXTENT, ClothSpec, MeshSpec, Vec3
from deformgl.scene.node_state import NodeState
from deformgl.scene.physics import SceneBox, scene_constraints, scene_loads, scene_system
from deformgl.trilinear.renderer import TrilinearRenderer
from deformgl.render.shader_pack import pack_inputs, write_pack_inputs
from deformgl.grid.surface import grid_surface
from deformgl.grid.fill import fill_cells
from deformgl.grid.voxelize import voxelize
from deformgl.sim.materials import ElasticMaterial, LatticeReport, SheetMaterial
from deformgl.render.bspline_premap import FieldMeshPass
from deformgl.scene.spline_model import spline_scene
from deformgl.sim.terms.spline.body import SplineBody


@dataclass(frozen=True, eq=False)
class SceneModel:
    """Everything a scene builds on the CPU, once: recentred mesh, grid, spring system, loads.

    Attributes:
        mesh: the detailed mesh, recentred.
        centre: (3,) the world offset removed from every position.
        grid: node grid (recentred coordinates).
        system: the spring system (:func:`~deformgl.scene.physics.scene_system`).
        loads: the ``[[physics.pull]]`` loads (:func:`~deformgl.scene.physics.scene_loads`).
        bbox: (2, 3) recentred bounding box of the mesh, for regions and the camera.
        lattice: what the cell assembly of a ``[material]`` scene found, or None.
        spline: the spline body of a ``model = "spline"`` scene (its control points are the
            grid's nodes), or None.
    """

    mesh: trimesh.Trimesh
    centre: np.ndarray
    grid: NodeGrid
    system: SpringSystem
    loads: tuple[Load, ...]
    bbox: np.ndarray
    lattice: LatticeReport | None = None
    spline: SplineBody | None = None

    @classmethod
    def build(cls, scene: Scene, mesh: trimesh.Trimesh, centre: np.ndarray, grid: NodeGrid,
              bbox: np.ndarray) -> SceneModel:
        """The model of ``scene``'s physics on ``grid`` (regions are fractions of ``bbox``)."""
        source = scene.source.name
        material = scene.physics.material
        if isinstance(material, ElasticMaterial) and material.model == "spline":
            system, body = spline_scene(grid, scene.physics, bbox, mesh=mesh, source=source)
            return cls(mesh=mesh, centre=centre, grid=body.grid, system=system,
                       loads=scene_loads(body.grid, scene.physics, bbox, source=source, mass=system.mass), bbox=bbox,
                       spline=body)
        report: list[LatticeReport] = []
        system = scene_system(grid, scene.physics, bbox, source=source, report=report)
        return cls(mesh=mesh, centre=centre, grid=grid, system=system,
                   loads=scene_loads(grid, scene.physics, bbox, source=source, mass=system.mass), bbox=bbox,
                   lattice=report[0] if report else None)


def _vec3(v: Vec3) -> Vec3:
    """``tuple(v)`` of a 3-vector of the scene (a list or tuple of 3: the schema checks it)."""
    x, y, z = v
    return (x, y, z)


def _cloth(scene: Scene) -> ClothSpec:
    """The scene's cloth; only called on a cloth scene."""
    if scene.cloth is None:
        raise ValueError(f"{scene.source}: not a cloth scene")
    return scene.cloth


def _mesh(scene: Scene) -> MeshSpec:
    """The scene's detailed mesh; the schema sets it on every scene that is not a cloth."""
    if scene.mesh is None:
        raise ValueError(f"{scene.source}: a cloth scene has no detailed mesh")
    return scene.mesh


def build_cloth_model(scene: Scene) -> SceneModel:
    """A cloth scene: a one-node-thin sheet of nodes centred on the origin in the plane y = 0; its
    box is the cube of side ``cloth.size`` around it (Movania & Feng 2012, section 5)."""
    cloth = _cloth(scene)
    nx, nz = cloth.nodes
    size = cloth.size
    spacing = size / (max(nx, nz) - 1)
    origin = np.array([-(nx - 1) * spacing / 2.0, 0.0, -(nz - 1) * spacing / 2.0])
    grid = NodeGrid(origin=origin, spacing=spacing, occupied=np.ones((nx, 1, nz), dtype=bool))
    surface = grid_surface(grid)
    mesh = trimesh.Trimesh(grid.rest_positions[surface.nodes], surface.triangles, process=False)
    bbox = np.array([[origin[0], -size / 2.0, origin[2]], [-origin[0], size / 2.0, -origin[2]]])
    return SceneModel.build(scene, mesh, np.zeros(3), grid, bbox)


def material_line(material: object, spacing: float) -> str:
    """``material E = ... Pa, rho = ... kg/m^3 at spacing h = ... m`` for the render log."""
    if not isinstance(material, (ElasticMaterial, SheetMaterial)):
        return "per-spring constants"
    what = material.summary
    name = getattr(material, "name", "")
    return f"material {name + ' ' if name else ''}{what} at grid spacing h = {spacing:.4g} m"


def recentred(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The mesh moved so its bounding-box centre is the origin, and that centre (3,) float64."""
    lo, hi = mesh.bounds
    centre = (np.asarray(lo, np.float64) + np.asarray(hi, np.float64)) / 2.0
    return trimesh.Trimesh(np.asarray(mesh.vertices, np.float64) - centre, mesh.faces, visual=mesh.visual,
                           process=False), centre


#: the last fills built in this process, by mesh bytes and resolution (both results are immutable)
_FILLS: dict[tuple, tuple] = {}
_FILLS_KEPT = 8


def _filled(mesh: trimesh.Trimesh, nodes_along_longest: int | None, spacing: float | None, source: str):
    """:func:`~deformgl.grid.fill.fill_cells` of the mesh, reused when the same mesh at the same
    resolution was filled before in this process (a scene rebuilt, a study's repeated runs)."""
    import hashlib

    digest = hashlib.sha256(np.ascontiguousarray(mesh.vertices, np.float64).tobytes()
                            + np.ascontiguousarray(mesh.faces, np.int64).tobytes()).hexdigest()
    key = (digest, nodes_along_longest, spacing)
    if key not in _FILLS:
        if len(_FILLS) >= _FILLS_KEPT:
            _FILLS.pop(next(iter(_FILLS)))
        _FILLS[key] = fill_cells(mesh, nodes_along_longest=nodes_along_longest, spacing=spacing, source=source)
    return _FILLS[key]


def mesh_grid(mesh: trimesh.Trimesh, *, nodes_along_longest: int | None, spacing: float | None, source: str,
              finer: str, solid: bool = False) -> NodeGrid:
    """The node grid of a (recentred) mesh; a mesh too thin for any cell or 2x2 sheet is an
    InputError naming ``source`` and what to change (``finer``).

    ``solid``: a body of an elastic material: the grid is the cells that hold the mesh's
    material, each carrying its fill (:mod:`deformgl.grid.fill`); otherwise the nodes whose
    cubes meet the mesh (:mod:`deformgl.grid.voxelize`, the per-spring-constant model of
    Mosegaard & Sørensen 2005)."""
    longest = float(np.max(np.ptp(np.asarray(mesh.vertices, np.float64), axis=0), initial=0.0))
    if not longest >= MIN_EXTENT:  # (the grid's arithmetic and the float32 draw lose a smaller mesh)
        raise InputError(f"{source}: the mesh is {longest:.3g} across: below {MIN_EXTENT:g}, too small to "
                         f"voxelize and draw; scale it up")
    fill = None
    if solid:
        vox, fill = _filled(mesh, nodes_along_longest, spacing, source)
    else:
        vox = voxelize(mesh, nodes_along_longest=nodes_along_longest, spacing=spacing, source=source)
    grid = NodeGrid(origin=np.asarray(vox.origin, dtype=np.float64), spacing=float(vox.spacing),
                    occupied=np.asarray(vox.occupied, dtype=bool), fill=fill)
    if len(grid_surface(grid).triangles) == 0:
        raise InputError(f"{source}: too thin for a node grid at spacing {grid.spacing:.4g}: its "
                         f"{grid.count} node(s) form no cell and no sheet of 2x2 nodes; use a finer grid "
                         f"({finer})")
    return grid


def build_scene_model(scene: Scene) -> SceneModel:
    """Load and recentre the mesh, voxelize it into the node grid, build the spring system (or
    build the cloth sheet of a cloth scene)."""
    if scene.cloth is not None:
        return build_cloth_model(scene)
    mesh_spec = _mesh(scene)
    loaded = load_mesh(mesh_spec.path)
    if mesh_spec.scale != 1.0:  # metres per mesh unit: the mesh and grid.spacing in metres
        loaded = trimesh.Trimesh(np.asarray(loaded.vertices, np.float64) * mesh_spec.scale, loaded.faces,
                                 visual=loaded.visual, process=False)
    mesh, centre = recentred(loaded)
    spacing = None if scene.grid.spacing is None else scene.grid.spacing * mesh_spec.scale
    grid = mesh_grid(mesh, nodes_along_longest=scene.grid.nodes_along_longest, spacing=spacing,
                     source=str(mesh_spec.path),
                     finer=f"grid.nodes_along_longest or grid.spacing in {scene.source.name}",
                     solid=isinstance(scene.physics.material, ElasticMaterial))
    return SceneModel.build(scene, mesh, centre, grid, np.array(mesh.bounds, dtype=np.float64))


def scene_view(scene: Scene, bbox: np.ndarray) -> View:
    """The scene's camera framing the rest bounding box.

    Raises:
        InputError: the rest bounding box lies wholly outside the camera's view (a target far
            off the body, say): the image would be blank (found by tests/test_fuzz_render.py).
    """
    cam = scene.render.camera
    w, h = scene.render.size
    view = frame_box(bbox[0], bbox[1], projection=cam.projection, azimuth=cam.azimuth,
                     elevation=cam.elevation, fov=cam.fov, distance=cam.distance,
                     target=np.asarray(cam.target), aspect=w / h)
    corners = np.array([[x, y, z, 1.0] for x in bbox[:, 0] for y in bbox[:, 1] for z in bbox[:, 2]])
    cx, cy, cz, cw = (corners @ np.asarray(view.view_projection, np.float64).T).T
    if any(out.all() for out in (cx < -cw, cx > cw, cy < -cw, cy > cw, cz < -cw, cz > cw)):
        raise InputError(f"{scene.source}: render.camera: the body lies wholly outside the view (target "
                         f"{list(cam.target)}, distance {cam.distance:g}, azimuth {cam.azimuth:g}, elevation "
                         f"{cam.elevation:g}): the image would be blank")
    return view


def scene_lighting(scene: Scene) -> Lighting:
    """Light and material uniforms of a scene."""
    r = scene.render
    return Lighting(direction=_vec3(r.light.direction), colour=_vec3(r.light.colour),
                    ambient=r.light.ambient, material=_vec3(r.material.colour),
                    specular=r.material.specular, shininess=r.material.shininess)


def check_texture_limit(scene: Scene, grid: NodeGrid, max_size: int) -> None:
    """The node grid must fit the GL texture limit; the error names the scene key to change."""
    try:
        CompactLayout.for_grid(grid, max_size)  # the layout NodeTextures uses by default
    except ValueError as exc:
        key = "grid.spacing" if scene.grid.spacing is not None else "grid.nodes_along_longest"
        raise InputError(f"{scene.source}: {key}: {exc}; use a coarser grid") from None


def make_draw_pass(ctx: moderngl.Context, scene: Scene, built: SceneModel, layout, *,
                   log: Callable[[str], None] | None = None):
    """The pass that draws the scene: the grid surface (one-to-one) or the mapped detailed mesh.

    Args:
        log: receives the binding's report lines (what it could not do well), if given.
    """
    mode = scene.mapping.mode
    if built.spline is not None:  # (drawn through the field it was solved with; the schema refused the rest)
        mesh = built.mesh
        return FieldMeshPass(ctx, built.spline, layout_uniforms(layout.width), mesh.vertices, mesh.vertex_normals,
                             mesh.faces, front_face=closed_front_face(mesh.vertices, mesh.faces) if scene.render.cull
                             else None)
    if mode == "one-to-one":
        return GridSurfacePass(ctx, built.grid, layout, overlay=scene.render.show_grid)
    surface = grid_surface(built.grid)
    normal_map = normal_map_image(scene.mapping.normal_map, scene.source)
    own_uv = mesh_uv(built.mesh)
    binding = get_binding(built.mesh, built.grid, surface, use_cache=scene.mapping.cache, uv=own_uv)
    if log is not None:
        for line in binding.report.lines():
            log(f"{_mesh(scene).path.name}: {line}")
    data = mapped_vertices(binding, mode, built.grid.rest_positions, rest_normals(built.grid))
    if normal_map is not None:
        # the mesh's own UVs as they are; procedural ones (what the tangents were built from)
        # repeated over the surface
        uv = binding.uv if own_uv is not None else binding.uv * scene.mapping.normal_map_repeat
        data = dataclasses.replace(data, uv=uv)
    front_face = closed_front_face(built.mesh.vertices, built.mesh.faces) if scene.render.cull else None
    return MappedMeshPass(ctx, built.grid, layout, built.mesh.faces, data, normal_map=normal_map,
                          normal_map_strength=scene.mapping.normal_map_strength, front_face=front_face,
                          mapping_pass=RENDER_MAPPING_PASS)


#: Where the renderer maps the detailed mesh (``MappedMeshPass``'s ``mapping_pass``): once per
#: vertex in a fragment pass, the same function as the paper's mapping in the drawing vertex
#: shader (``python -m studies.render_speed`` compares all three).
RENDER_MAPPING_PASS = "fragment"


def draw_attachments(ctx: moderngl.Context, scene: Scene, built: SceneModel, deformed: np.ndarray,
                     view: View, lighting: Lighting) -> None:
    """Draw the scene's attached tubes on the deformed detailed mesh (Knuth et al., section 5).

    Args:
        deformed: (V, 3) the detailed mesh's vertices as the mapping shader computed them (the
            anchors' frames need them on the CPU; the paper composes on the CPU too).
    """
    lo, hi = built.bbox
    diag = float(np.linalg.norm(hi - lo))
    renderer = TrilinearRenderer(ctx)
    try:
        for spec in scene.attach:
            tube = TubeAttachment.along(built.mesh.vertices, built.mesh.faces, lo + (hi - lo) * np.asarray(spec.start),
                                        lo + (hi - lo) * np.asarray(spec.end), count=spec.anchors,
                                        radius=spec.radius * diag, colour=spec.colour)
            renderer.draw(tube.compose(deformed, built.mesh.faces), view, lighting)
    finally:
        renderer.release()


@dataclass
class Rendered:
    """What one render produced: the image, and on request the deformed mesh and the shader-pack
    inputs (kept in memory so that files are written only after the PNG)."""

    image: np.ndarray
    mesh: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # vertices (world), normals, faces
    pack: dict[str, np.ndarray | np.float32] | None = None
    record: dict[str, Any] = dataclasses.field(default_factory=dict)  # deformgl.scene.record.run_record


def check_gl_limits(ctx: moderngl.Context, scene: Scene) -> None:
    """Limits a scene can exceed, checked before any work: MSAA samples, a normal map wider than
    a texture may be (read from the PNG header, not decoded)."""
    max_samples = int(ctx.info.get("GL_MAX_SAMPLES", 1))
    if scene.render.samples > max(max_samples, 1):
        raise InputError(f"{scene.source}: render.msaa: {scene.render.samples}x is more than this renderer's "
                         f"{max_samples}x")
    spec = scene.mapping.normal_map
    if spec is not None and spec != "procedural" and scene.mapping.mode != "one-to-one":
        from PIL import Image, UnidentifiedImageError

        limit = int(ctx.info["GL_MAX_TEXTURE_SIZE"])
        try:
            with Image.open(Path(spec)) as image:
                width, height = image.size
        except (OSError, UnidentifiedImageError, Image.DecompressionBombError) as exc:
            raise InputError(f"{scene.source}: mapping.normal_map: cannot read {spec}: {exc}") from None
        if max(width, height) > limit:
            raise InputError(f"{scene.source}: mapping.normal_map: {spec} is {width}x{height}, more than this "
                             f"renderer's {limit}x{limit} texture limit")


def render(ctx: moderngl.Context, scene: Scene, *, progress: bool = False, mesh: bool = False,
           pack: bool = False, log: Callable[[str], None] | None = None,
           overlay: Callable[[SceneModel, np.ndarray, View, Lighting], None] | None = None) -> Rendered:
    """Simulate (or drive) a scene's nodes and render it.

    Args:
        mesh: also capture the deformed detailed mesh from the mapping vertex shader.
        overlay: also draws into the image, after the body and its attachments, given the
            model, the deformed detailed mesh's (V, 3) vertices, the view and the lighting
            (a scene graph's attachments, :mod:`deformgl.scene.graphs`).
        pack: also collect the inputs of the shader pack's example program.
        log: receives human-readable notes (the binding report), if given.
    """
    if (mesh or pack) and scene.mapping.mode == "one-to-one":
        flag = "--export-mesh" if mesh else "--pack-inputs"
        raise InputError(f"{scene.source}: {flag} needs a mapping of the detailed mesh "
                         f"(--mapping constant, curvature or auto), not one-to-one")
    import time

    from deformgl.scene.record import run_record

    started = time.perf_counter()
    check_gl_limits(ctx, scene)
    check_scene(ctx, scene)  # host and GPU memory, render-target limits: before anything is built
    built = build_scene_model(scene)
    check_texture_limit(scene, built.grid, int(ctx.info["GL_MAX_TEXTURE_SIZE"]))
    scene_view(scene, built.bbox)  # (a camera that cannot see the body: refused before the run)
    state = NodeState(ctx, scene, built, progress=progress)
    draw_pass = None
    target = None
    try:
        draw_pass = make_draw_pass(ctx, scene, built, state.layout, log=log)
        target = RenderTarget(ctx, scene.render.size, scene.render.samples, fxaa=scene.render.fxaa)
        target.begin(_vec3(scene.render.background))
        view, lighting = scene_view(scene, built.bbox), scene_lighting(scene)
        draw_pass.draw(state.position_texture, view, lighting)
        if log is not None:
            for note in state.notes:
                log(f"{scene.name}: {note}")
            if built.lattice is not None:
                log(f"{scene.name}: {material_line(scene.physics.material, built.grid.spacing)}: "
                    f"{built.lattice.summary()}")
            if built.spline is not None:
                body = built.spline
                log(f"{scene.name}: model spline: {material_line(scene.physics.material, built.grid.spacing)}: "
                    f"{len(body.span_nodes)} knot spans, {body.count} control points, volume {body.volume:.4g} m^3, "
                    f"drawn through the field")
        if state.run is not None:
            if log is not None:
                log(f"{scene.name}: {state.run.summary(scene.physics)}")
            constraints = scene_constraints(scene.physics, SceneBox(*built.bbox))
            if constraints is not None:
                target.fbo.use()
                draw_obstacles(ctx, constraints, state.run.time, built.bbox[0], built.bbox[1],
                               built.grid.spacing, view, lighting)
        captured: tuple[np.ndarray, np.ndarray] | None = None
        if scene.attach or mesh or overlay is not None:
            captured = draw_pass.capture(state.position_texture)
            if not np.isfinite(captured[0]).all():
                bad = int(np.argmax(~np.isfinite(captured[0]).all(axis=1)))
                raise SimulationError(f"{scene.source}: mapped vertex {bad} is non-finite")
        if scene.attach and captured is not None:  # (captured whenever scene.attach)
            target.fbo.use()
            draw_attachments(ctx, scene, built, captured[0].astype(np.float64), view, lighting)
        if overlay is not None and captured is not None:  # (captured whenever overlay)
            target.fbo.use()
            overlay(built, captured[0].astype(np.float64), view, lighting)
        result = Rendered(target.read_rgb())
        if mesh and captured is not None:  # (captured whenever mesh)
            result.mesh = (captured[0].astype(np.float64) + built.centre, captured[1], built.mesh.faces)
        if pack:
            result.pack = pack_inputs(state.position_texture, built.grid, state.layout, draw_pass.data,
                                      built.mesh.faces, view, lighting, scene.render.size,
                                      _vec3(scene.render.background))
        result.record = run_record(scene, built, state.run, wall=time.perf_counter() - started, ctx=ctx)
        return result
    finally:
        for obj in (target, draw_pass):
            if obj is not None:
                obj.release()
        state.release()


def render_scene(ctx: moderngl.Context, scene: Scene, *, progress: bool = False) -> np.ndarray:
    """Simulate (or drive) a scene's nodes and render it: (height, width, 3) uint8 image."""
    return render(ctx, scene, progress=progress).image


def render_to_png(ctx: moderngl.Context, scene: Scene, out: Path, *, progress: bool = False,
                  export: Path | None = None, pack: Path | None = None,
                  log: Callable[[str], None] | None = None) -> np.ndarray:
    """Render a scene and write the PNG, the optional mesh and shader-pack inputs as one
    :class:`~deformgl.files.OutputSet`: every path is checked before any work, and the files
    appear together when all are written, or none of them (a failed render or write, SIGTERM)."""
    return render_still(ctx, scene, out, progress=progress, export=export, pack=pack, log=log).image


def render_still(ctx: moderngl.Context, scene: Scene, out: Path, *, progress: bool = False,
                 export: Path | None = None, pack: Path | None = None, record: Path | None = None,
                 log: Callable[[str], None] | None = None) -> Rendered:
    """:func:`render_to_png`, also writing the run record as JSON to ``record`` (in the same
    output set); returns what :func:`render` produced, its record with ``outputs``."""
    from deformgl.scene.record import write_record

    outputs = OutputSet([out, export, pack, record])
    result = render(ctx, scene, progress=progress, mesh=export is not None, pack=pack is not None, log=log)
    result.record["outputs"] = [str(p) for p in (out, export, pack) if p is not None]
    with outputs:
        write_png_atomic(out, result.image)
        if export is not None:
            if result.mesh is None:
                raise RuntimeError("render() returned no mesh for --export-mesh")  # it always does
            export_mesh(export, *result.mesh)
        if pack is not None:
            if result.pack is None:
                raise RuntimeError("render() returned no inputs for --pack-inputs")  # it always does
            write_pack_inputs(pack, result.pack)
        if record is not None:
            write_record(record, result.record)
    return result
