"""Animated results in the tools users open them in: ParaView (VTK XML through meshio, XDMF with
HDF5) and USD (usd-core), written from :class:`Series` of frames.

Formats (``--export-mesh PATH`` for the detailed mesh, ``--export-grid PATH`` for the node grid):

* ``.pvd``: a ParaView collection of one ``.vtu`` per frame (``NAME_0000.vtu`` ... beside it), each
  the *deformed* geometry of its frame with the point and cell data; ``timestep`` = simulated
  time in s. ParaView plays it as a time series.
* ``.vtu``: one frame (a still).
* ``.xdmf``: XDMF 3 with its heavy data in ``NAME.h5`` beside it (meshio's time-series writer):
  the *rest* geometry once, and per frame (``Time`` = simulated time in s) the point data
  (``displacement`` among it) and cell data. This is the finite-element convention (FEniCS,
  dolfinx): ParaView's "Warp By Vector" filter on ``displacement`` shows the deformed body.
* ``.usd``, ``.usda``, ``.usdc`` (``--export-mesh`` only): one ``UsdGeomMesh`` at
  ``/deformgl/mesh`` with its topology once and time-sampled ``points`` (float32, world, m),
  ``normals``, ``velocities`` and the primvars ``displacement`` (m) and ``velocity`` (m/s) per
  frame at time code k of frame k; ``timeCodesPerSecond`` = ``framesPerSecond`` = the
  animation's fps, ``metersPerUnit`` = 1, ``upAxis`` Y. USD's ``velocities`` are per second of
  time codes: the m/s times the simulated seconds per second of the animation
  (:attr:`Series.time_scale`), so that motion blur extrapolates at the simulated speed (to first
  order: the velocity is the backward difference over the last step). ``.usd`` is the binary
  crate format.

Every file is written complete into a scratch folder beside the outputs (named as deformgl's
temporary files, so the next run removes one a killed run left), then moved to its temporary
name and staged with :func:`~deformgl.files.adopt_file` (inside the run's
:class:`~deformgl.files.OutputSet`: all outputs or none). The libraries are optional extras: a
format whose extra is missing is refused before any work with one line naming the extra
(:func:`check_format`).
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from deformgl.errors import InputError, SimulationError
from deformgl.files import adopt_file, temporary_path

__all__ = ["MESH_FORMATS", "GRID_FORMATS", "Series", "check_format", "is_interchange", "series_paths",
           "write_series"]

#: suffix -> (the modules it needs, the extra that installs them)
_NEEDS = {".vtu": (("meshio",), "io"), ".pvd": (("meshio",), "io"), ".xdmf": (("meshio", "h5py"), "io"),
          ".usd": (("pxr",), "usd"), ".usda": (("pxr",), "usd"), ".usdc": (("pxr",), "usd")}
MESH_FORMATS = tuple(_NEEDS)
GRID_FORMATS = (".vtu", ".pvd", ".xdmf")


@dataclass(frozen=True)
class Series:
    """Frames of one body on fixed cells.

    Attributes:
        cell_type: "triangle" (the detailed mesh) or "hexahedron" (the node grid; corners in VTK order).
        cells: (C, 3) or (C, 8) int point numbers.
        rest: (P, 3) float64 rest points (m, world).
        times: simulated time of each frame (s).
        points: per frame (P, 3) float64 points (m, world).
        point_data: per frame, name -> (P,) or (P, 3) arrays.
        cell_data: per frame, name -> (C,), (C, 3) or (C, 9) arrays.
        normals: per frame (P, 3) unit normals (USD), or empty.
        fps: frames per second of the animation (USD's time codes).
        time_scale: simulated seconds per second of the animation (USD's ``velocities`` are per
            second of time codes: the m/s of ``velocity`` times this).
    """

    cell_type: str
    cells: np.ndarray
    rest: np.ndarray
    times: Sequence[float]
    points: Sequence[np.ndarray]
    point_data: Sequence[dict[str, np.ndarray]]
    cell_data: Sequence[dict[str, np.ndarray]] = field(default_factory=list)
    normals: Sequence[np.ndarray] = field(default_factory=list)
    fps: float = 24.0
    time_scale: float = 1.0


def is_interchange(path: Path | None) -> bool:
    """Whether ``path`` names one of the formats of this module."""
    return path is not None and path.suffix.lower() in _NEEDS


def check_format(path: Path, option: str, frames: int, *, grid: bool = False) -> None:
    """Refuse, with one line naming ``option`` and the extra to install, a format that cannot be
    written here: its library is missing, it holds one frame (``.vtu``) but ``frames`` > 1, or
    (``grid``) it cannot hold hexahedra (USD)."""
    suffix = path.suffix.lower()
    formats = GRID_FORMATS if grid else MESH_FORMATS
    if suffix not in formats:
        raise InputError(f"{path}: {option} must end in {', '.join(formats)}")
    if suffix == ".vtu" and frames > 1:
        stem = path.with_suffix("")
        raise InputError(f"{path}: a .vtu holds one frame; {frames} frames need a collection: {stem}.pvd "
                         f"(one .vtu per frame) or {stem}.xdmf")
    modules, extra = _NEEDS[suffix]
    for module in modules:
        if importlib.util.find_spec(module) is None:
            raise InputError(f"{path}: {option} {suffix} needs the optional extra '{extra}' ({module} is not "
                             f"installed): pip install 'deformgl[{extra}]'")


def series_paths(path: Path, frames: int) -> list[Path]:
    """Every file ``write_series(path, ...)`` writes for ``frames`` frames."""
    suffix = path.suffix.lower()
    if suffix == ".xdmf":
        return [path, path.with_suffix(".h5")]
    if suffix == ".pvd":
        return [path, *(path.parent / f"{path.stem}_{k:04d}.vtu" for k in range(frames))]
    return [path]


def write_series(path: Path, series: Series) -> None:
    """Write ``series`` to ``path`` (and the files beside it, :func:`series_paths`)."""
    suffix = path.suffix.lower()
    _check_finite(path, series)
    scratch = temporary_path(path)  # a folder beside the outputs, named as deformgl's temporaries
    os.mkdir(scratch)
    try:
        if suffix == ".xdmf":
            _write_xdmf(scratch / path.name, series)
        elif suffix == ".pvd":
            _write_pvd(scratch / path.name, series)
        elif suffix == ".vtu":
            _write_vtu(scratch / path.name, series, 0)
        elif suffix in (".usd", ".usda", ".usdc"):
            _write_usd(scratch / path.name, series)
        else:
            raise InputError(f"{path}: not a format of deformgl.scene.interchange ({', '.join(MESH_FORMATS)})")
        for target in reversed(series_paths(path, len(series.times))):  # the index (.pvd, .xdmf) last
            adopt_file(target, scratch / target.name)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _check_finite(path: Path, series: Series) -> None:
    """Refuse to write a non-finite value (a blown-up run the checks missed): NaN never leaves
    deformgl silently."""
    for k in range(len(series.times)):
        named = [("points", series.points[k]), *series.point_data[k].items(),
                 *(series.cell_data[k].items() if series.cell_data else ()),
                 *((("normals", series.normals[k]),) if series.normals else ())]
        for name, values in named:
            bad = ~np.isfinite(np.asarray(values, np.float64))
            if bad.any():
                row = int(np.argwhere(bad)[0][0])
                raise SimulationError(f"{path}: frame {k} (t = {series.times[k]:g} s): {name} of point or cell {row} "
                                      f"is not finite; nothing written")


def _cells(series: Series) -> list[tuple[str, np.ndarray]]:
    return [(series.cell_type, np.asarray(series.cells, np.int64))]


def _point_data(series: Series, k: int) -> dict[str, np.ndarray]:
    return {name: np.ascontiguousarray(value) for name, value in series.point_data[k].items()}


def _cell_data(series: Series, k: int) -> dict[str, list[np.ndarray]] | None:
    """Frame k's cell data as meshio takes it (one list entry per cell block: one block here)."""
    if not series.cell_data:
        return None
    return {name: [np.ascontiguousarray(value)] for name, value in series.cell_data[k].items()}


def _write_vtu(path: Path, series: Series, k: int) -> None:
    import meshio

    mesh = meshio.Mesh(np.asarray(series.points[k], np.float64), _cells(series), point_data=_point_data(series, k),
                       cell_data=_cell_data(series, k))
    meshio.write(path, mesh, file_format="vtu")


def _write_pvd(path: Path, series: Series) -> None:
    root = ET.Element("VTKFile", type="Collection", version="0.1", byte_order="LittleEndian")
    collection = ET.SubElement(root, "Collection")
    for k, t in enumerate(series.times):
        name = f"{path.stem}_{k:04d}.vtu"
        _write_vtu(path.parent / name, series, k)
        ET.SubElement(collection, "DataSet", timestep=repr(float(t)), group="", part="0", file=name)
    ET.indent(root)
    ET.ElementTree(root).write(path, encoding="utf-8", xml_declaration=True)


def _write_xdmf(path: Path, series: Series) -> None:
    import h5py
    import meshio

    class Writer(meshio.xdmf.TimeSeriesWriter):
        """meshio's writer with its HDF5 file beside the .xdmf (meshio 5.3 opens it in the
        working directory)."""

        def __enter__(self):
            self.h5_filename = str(Path(self.filename).with_suffix(".h5"))
            self.h5_file = h5py.File(self.h5_filename, "w")
            return self

    with Writer(path) as writer:
        writer.write_points_cells(np.asarray(series.rest, np.float64), _cells(series))
        for k, t in enumerate(series.times):
            writer.write_data(float(t), point_data=_point_data(series, k), cell_data=_cell_data(series, k))


def _write_usd(path: Path, series: Series) -> None:
    from pxr import Gf, Sdf, Usd, UsdGeom, Vt

    if series.cell_type != "triangle":
        raise InputError(f"{path}: USD holds the detailed mesh (triangles), not the node grid's hexahedra")
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    fps = float(series.fps)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(max(len(series.times) - 1, 0))
    root = UsdGeom.Xform.Define(stage, "/deformgl")
    stage.SetDefaultPrim(root.GetPrim())
    mesh = UsdGeom.Mesh.Define(stage, "/deformgl/mesh")
    faces = np.asarray(series.cells, np.int32)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(faces.reshape(-1))))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    points, normals, extent = mesh.CreatePointsAttr(), mesh.CreateNormalsAttr(), mesh.CreateExtentAttr()
    velocities = mesh.CreateVelocitiesAttr()
    primvars = UsdGeom.PrimvarsAPI(mesh.GetPrim())
    displacement = primvars.CreatePrimvar("displacement", Sdf.ValueTypeNames.Vector3fArray, UsdGeom.Tokens.vertex)
    speed = primvars.CreatePrimvar("velocity", Sdf.ValueTypeNames.Vector3fArray, UsdGeom.Tokens.vertex)
    for k in range(len(series.times)):
        code = Usd.TimeCode(k)
        p = np.ascontiguousarray(series.points[k], np.float32)
        points.Set(Vt.Vec3fArray.FromNumpy(p), code)
        if series.normals:
            normals.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(series.normals[k], np.float32)), code)
        extent.Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, p.min(axis=0))), Gf.Vec3f(*map(float, p.max(axis=0)))]), code)
        data = series.point_data[k]
        if "velocity" in data:  # per second of time codes: motion blur at the simulated speed
            v = np.asarray(data["velocity"], np.float64)
            velocities.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(v * series.time_scale, np.float32)), code)
            speed.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(v, np.float32)), code)
        if "displacement" in data:
            displacement.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(data["displacement"], np.float32)), code)
    stage.GetRootLayer().Save()
