"""The fields a frame exports for ParaView and USD (``--export-mesh out.xdmf|.pvd|.vtu|.usd``,
``--export-grid``): what the simulation's state means on the detailed mesh and on the node grid.

All in SI units, world coordinates (the scene's recentring undone):

* **Detailed mesh, per vertex** (:class:`MeshFrame`): the deformed positions as rendered (m), the
  normals, the grid's ``volume_ratio`` and ``green_strain`` of the cell the vertex lies in at rest
  (for a vertex outside every full cell, the full cell nearest by centre: an approximation; none
  for a cloth), ``displacement`` (m) from the mesh's rest vertices, and ``velocity`` (m/s): the
  backward difference of the mapped positions over the last step,
  ``(map(x_n) − map(x_n − dt v_n)) / dt``, the mapping (Mosegaard & Sørensen 2005, eq. 9) applied
  in float64 to the node positions read back. For position Verlet ``x_n − dt v_n`` is the
  previous step's state, so this is the backward difference of the vertex's own positions; for
  the integrators that carry a velocity it is the mapping's response to the nodes' velocity, to
  first order in dt.
* **Node grid, per node** (:class:`GridFrame`): positions, ``displacement`` from the rest grid and
  ``velocity`` (the simulation's own: for position Verlet the backward difference
  ``(x_n − x_{n−1}) / dt``, :meth:`~deformgl.sim.simulation.Simulation.velocities`); **per full
  cell** (8 corners present): ``volume_ratio`` J = det F (deformed volume over rest volume) and
  the Green–Lagrange strain ``E = (FᵀF − I) / 2`` (dimensionless), F the trilinear map's
  deformation gradient at the cell centre (as the volumetric term uses it,
  :func:`~deformgl.sim.terms.volume.energy.cell_state`), and ``fill``: the share of the cell inside the mesh
  (1 where the grid carries no fill).

Nodes that do not come from a simulation (a node-frames file, a motion) have no velocity: the
field is left out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deformgl.errors import InputError
from deformgl.mapping.bases import map_vertices
from deformgl.sim.normals import unit_sums
from deformgl.sim.terms.volume.energy import centre_deformation, grid_cells

__all__ = ["GridFrame", "MeshFrame", "NodeFields", "VTK_HEXAHEDRON", "check_grid_export", "green_strain",
           "grid_series", "mesh_series", "sheet_quads"]

#: corner order of a VTK / XDMF hexahedron in deformgl's corner numbering (c = dx + 2 dy + 4 dz):
#: VTK walks the bottom face (0,0,0) (1,0,0) (1,1,0) (0,1,0), then the top face the same way.
VTK_HEXAHEDRON = (0, 1, 3, 2, 4, 5, 7, 6)


@dataclass(frozen=True)
class MeshFrame:
    """One frame of the detailed mesh (V vertices), world coordinates in m.

    Attributes:
        time_s: simulated time of the frame (s).
        vertices, normals: (V, 3) float64 as rendered (normals of unit length).
        displacement: (V, 3) m from the rest vertices.
        velocity: (V, 3) m/s, or None where the nodes were not simulated.
    """

    time_s: float
    vertices: np.ndarray
    normals: np.ndarray
    displacement: np.ndarray
    velocity: np.ndarray | None


@dataclass(frozen=True)
class GridFrame:
    """One frame of the node grid (N nodes, C full cells).

    Attributes:
        time_s: simulated time (s).
        positions, displacement: (N, 3) m.
        velocity: (N, 3) m/s, or None where the nodes were not simulated.
        volume_ratio: (C,) J = det F at each cell centre.
        green_strain: (C, 3, 3) E = (FᵀF − I)/2 at each cell centre.
    """

    time_s: float
    positions: np.ndarray
    displacement: np.ndarray
    velocity: np.ndarray | None
    volume_ratio: np.ndarray
    green_strain: np.ndarray


def _unit(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` scaled to unit length in float64 (zero rows stay zero)."""
    v = np.asarray(v, np.float64)
    length = np.linalg.norm(v, axis=1, keepdims=True)
    return v / np.where(length > 0, length, 1.0)


def green_strain(f: np.ndarray) -> np.ndarray:
    """(C, 3, 3) Green–Lagrange strain ``(FᵀF − I) / 2`` of deformation gradients (C, 3, 3)."""
    return 0.5 * (np.einsum("cki,ckj->cij", f, f) - np.eye(3))


class NodeFields:
    """Turns node states into :class:`MeshFrame` and :class:`GridFrame` records (immutable inputs:
    the grid, the recentring offset, and for the mesh the per-vertex data of its mapping).

    Args:
        grid: the node grid (recentred coordinates).
        centre: (3,) the offset the scene removed (added back to every position).
        mapped: the mapping's per-vertex data (:class:`~deformgl.render.mapped_setup.MappedVertices`),
            or None when only the grid is exported.
        rest_vertices: (V, 3) the detailed mesh at rest (recentred), with ``mapped``.
    """

    def __init__(self, grid, centre: np.ndarray, *, mapped=None, rest_vertices: np.ndarray | None = None) -> None:
        self.grid = grid
        self.centre = np.asarray(centre, np.float64)
        self.mapped = mapped
        self.rest_vertices = None if rest_vertices is None else np.asarray(rest_vertices, np.float64)
        self.cells = grid_cells(grid.occupied, grid.index)

    @property
    def fill(self) -> np.ndarray:
        """(C,) the share of each full cell inside the mesh (1 without a fill)."""
        if self.grid.fill is None:
            return np.ones(len(self.cells))
        lower = self.grid.ijk[self.cells[:, 0]]
        return np.asarray(self.grid.fill.fraction, np.float64)[lower[:, 0], lower[:, 1], lower[:, 2]]

    def cell_of(self, points: np.ndarray) -> np.ndarray | None:
        """(P,) the full cell each rest point (recentred) lies in, or the nearest one by centre
        where it lies in none; None for a grid without full cells."""
        if not len(self.cells):
            return None
        from scipy.spatial import cKDTree

        centres = self.grid.rest_positions[self.cells].mean(axis=1)
        return np.asarray(cKDTree(centres).query(np.asarray(points, np.float64))[1], np.int64)

    def _map(self, x: np.ndarray) -> np.ndarray:
        m = self.mapped
        normals = _unit(unit_sums(self.grid, x))  # (zero where the sum is)
        out, _ = map_vertices(x, normals, m.tri_nodes, m.weights, m.offset, m.offset_world, m.use_curvature)
        return out

    def mesh_frame(self, time_s: float, vertices: np.ndarray, normals: np.ndarray, x: np.ndarray | None,
                   v: np.ndarray | None, dt: float) -> MeshFrame:
        """The mesh's frame from the rendered vertices and normals (world, m), the node
        positions ``x`` and velocities ``v`` (recentred, float64; None: not simulated) and the
        simulation's step ``dt`` (s) of the backward difference."""
        if self.mapped is None or self.rest_vertices is None:
            raise ValueError("NodeFields: mesh frames need the mapping's per-vertex data")
        vertices = np.asarray(vertices, np.float64)
        velocity = None
        if x is not None and v is not None and dt > 0:
            x = np.asarray(x, np.float64)
            velocity = (self._map(x) - self._map(x - dt * np.asarray(v, np.float64))) / dt
        return MeshFrame(float(time_s), vertices, _unit(normals), vertices - (self.rest_vertices + self.centre),
                         velocity)

    def grid_frame(self, time_s: float, x: np.ndarray, v: np.ndarray | None) -> GridFrame:
        """The grid's frame from node positions (recentred) and velocities."""
        x = np.asarray(x, np.float64)
        f = centre_deformation(self.cells, self.grid.spacing, x)
        return GridFrame(float(time_s), x + self.centre, x - self.grid.rest_positions,
                         None if v is None else np.asarray(v, np.float64), np.linalg.det(f), green_strain(f))


def time_scale(frames, fps: float) -> float:
    """Simulated seconds per second of the animation: the simulated time between two frames
    times ``fps`` (1 for a single frame)."""
    times = [sample.time_s for sample in frames.nodes]
    return (times[1] - times[0]) * fps if len(times) > 1 and times[1] > times[0] else 1.0


def mesh_series(frames, fps: float):
    """The :class:`~deformgl.scene.interchange.Series` of the detailed mesh of
    :class:`~deformgl.scene.animation.Frames` rendered with ``nodes=True`` and ``mesh=True``
    (mapped as its meshes were captured: :attr:`~deformgl.scene.animation.Frames.mapped`)."""
    from deformgl.scene.interchange import Series

    built = frames.model
    fields = NodeFields(built.grid, built.centre, mapped=frames.mapped, rest_vertices=built.mesh.vertices)
    made = [fields.mesh_frame(s.time_s, v, n, s.x, s.v, s.dt) for (v, n, _), s in zip(frames.meshes, frames.nodes)]
    data = [{"displacement": f.displacement, **({"velocity": f.velocity} if f.velocity is not None else {})}
            for f in made]
    cell = fields.cell_of(built.mesh.vertices)
    if cell is not None:  # the node grid's strain, where its cells carry it
        for s, d in zip(frames.nodes, data):
            g = fields.grid_frame(s.time_s, s.x, None)
            d["volume_ratio"], d["green_strain"] = g.volume_ratio[cell], g.green_strain[cell].reshape(-1, 9)
    return Series("triangle", np.asarray(built.mesh.faces), np.asarray(built.mesh.vertices, np.float64) + built.centre,
                  [f.time_s for f in made], [f.vertices for f in made], data, normals=[f.normals for f in made],
                  fps=fps, time_scale=time_scale(frames, fps))


def sheet_quads(grid) -> np.ndarray:
    """(Q, 4) node numbers of the quads of a grid one node thick along one axis (a cloth), counter-
    clockwise about that axis; (0, 4) for any other grid."""
    shape = grid.shape
    if sorted(shape)[0] != 1 or sorted(shape)[1] < 2:
        return np.zeros((0, 4), np.int64)
    axis = shape.index(1)
    index = np.moveaxis(np.asarray(grid.index, np.int64), axis, 0)[0]
    if axis == 1:  # (x, z) about y: keep x-z right-handed about +y
        index = index.T
    a, b, c, d = index[:-1, :-1], index[1:, :-1], index[1:, 1:], index[:-1, 1:]
    quads = np.stack([a, b, c, d], axis=-1).reshape(-1, 4)
    return quads[(quads >= 0).all(axis=1)]


def _quad_areas(x: np.ndarray, quads: np.ndarray) -> np.ndarray:
    p = x[quads]
    return 0.5 * np.linalg.norm(np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1]), axis=1)


def check_grid_export(scene, built) -> None:
    """Refuse ``--export-grid`` of a grid with neither a full cell nor the quads of a sheet (a
    rod one node across), before the run."""
    if getattr(built, "spline", None) is not None:  # (its knot spans are written: the body itself)
        return
    if not len(grid_cells(built.grid.occupied, built.grid.index)) and not len(sheet_quads(built.grid)):
        raise InputError(f"{scene.source}: --export-grid: the node grid of {built.grid.shape} positions has "
                         f"neither a full cell nor the quads of a sheet to write")


def grid_series(frames, fps: float):
    """The :class:`~deformgl.scene.interchange.Series` of the node grid of
    :class:`~deformgl.scene.animation.Frames` rendered with ``nodes=True``: hexahedra of its full
    cells (corners in VTK order) with their volume ratio, strain and fill; a sheet one node thick
    (a cloth, no full cells) as quads with their ``area_ratio`` (deformed over rest area)."""
    from deformgl.scene.interchange import Series

    built = frames.model
    fields = NodeFields(built.grid, built.centre)
    if not len(fields.cells):
        quads = sheet_quads(built.grid)
        if not len(quads):
            raise ValueError(f"grid_series: a grid of {built.grid.shape} positions with nothing to write "
                             f"(check_grid_export refuses it before the run)")
        rest = built.grid.rest_positions
        area = _quad_areas(rest, quads)
        samples = frames.nodes
        return Series("quad", quads, rest + built.centre, [s.time_s for s in samples],
                      [s.x + built.centre for s in samples],
                      [{"displacement": s.x - rest, **({"velocity": s.v} if s.v is not None else {})} for s in samples],
                      [{"area_ratio": _quad_areas(s.x, quads) / area} for s in samples], fps=fps)
    made = [fields.grid_frame(s.time_s, s.x, s.v) for s in frames.nodes]
    fill = fields.fill
    points = [{"displacement": f.displacement, **({"velocity": f.velocity} if f.velocity is not None else {})}
              for f in made]
    cells = [{"volume_ratio": f.volume_ratio, "green_strain": f.green_strain.reshape(-1, 9), "fill": fill}
             for f in made]
    return Series("hexahedron", fields.cells[:, list(VTK_HEXAHEDRON)], built.grid.rest_positions + built.centre,
                  [f.time_s for f in made], [f.positions for f in made], points, cells, fps=fps)
