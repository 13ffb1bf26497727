"""The record of a run: what ``deformgl render`` did, as one summary line (stderr) and as a
machine-readable dict (``--json``; the rows of a sweep's table).

Keys (SI, the unit in the name): ``mesh``, ``nodes``, ``springs``, ``integrator``, ``backend``,
``steps`` (scene steps taken), ``frames``, ``fps``, ``dt_s`` (the scene step), ``substeps`` (per
scene step), ``simulated_time_s``, ``wall_time_s``, ``converged`` (the convergence stop's verdict: at
equilibrium, by default), ``convergence`` (its last check's measures), ``inverted_cells`` (the
inversion census at the end: cells with a corner Jacobian <= 0; None without cells), ``solver``
(implicit Euler's linear solves, apart from ``converged``: preconditioner, tolerance, residual
floor in N s, iterations mean and most per step, the last and worst relative residual
``|b - A dv| / |b|``, steps that missed the tolerance; None for the other integrators), ``mapping``, ``size``,
``renderer``, ``deformgl`` (the version), and ``outputs`` once written.
"""

from __future__ import annotations

import dataclasses

import json
import os
from typing import Any

from deformgl.files import write_atomic

__all__ = ["run_record", "summary_line", "version", "write_record"]


def version() -> str:
    """deformgl's version (of the installed distribution; ``deformgl.__version__``)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed

    try:
        return installed("deformgl")
    except PackageNotFoundError:  # run from a checkout that is not installed
        return "unknown"


def material_fields(scene) -> dict[str, Any]:
    """The body's material and mesh scale for the record (None in the per-spring form)."""
    material = getattr(scene.physics, "material", None)
    fields: dict[str, Any] = {"material": None, "mesh_scale_m": None if scene.mesh is None else float(scene.mesh.scale)}
    if material is not None:
        fields["material"] = {k: (float(v) if isinstance(v, (int, float)) else v)
                              for k, v in dataclasses.asdict(material).items() if k != "source"}
    return fields


def model_of(scene) -> str | None:
    """The body model that ran: "lattice" or "spline" for a solid material, None otherwise."""
    material = getattr(scene.physics, "material", None)
    return getattr(material, "model", None)


def run_record(scene, built, run, *, frames: int = 1, fps: float | None = None, wall: float = 0.0,
               ctx=None) -> dict[str, Any]:
    """The record of one render of ``scene`` (its :class:`~deformgl.scene.pipeline.SceneModel`
    ``built`` and :class:`~deformgl.scene.physics.SceneRun` ``run``, None when nothing was simulated)."""
    physics = scene.physics
    simulated = run is not None
    return {
        "scene": str(scene.source),
        "mesh": scene.name,
        "nodes": int(built.grid.count),
        "springs": int(len(built.system.i)),
        "integrator": physics.integrator if simulated else None,
        "backend": physics.backend if simulated else None,
        "nodes_source": scene.nodes.source,
        "steps": int(run.steps) if simulated else 0,
        "frames": int(frames),
        "fps": fps if frames > 1 else None,
        "dt_s": float(physics.dt),
        "substeps": int(run.substeps) if simulated else 1,
        "simulated_time_s": float(run.time) if simulated else 0.0,
        "converged": run.converged if simulated else None,
        "convergence": getattr(run, "convergence", None) if simulated else None,
        "inverted_cells": getattr(run, "inverted_cells", None) if simulated else None,
        "solver": getattr(run, "solver", None) if simulated else None,
        "mapping": scene.mapping.mode if getattr(built, "spline", None) is None else "field",
        "model": model_of(scene),
        **material_fields(scene),
        "size": list(scene.render.size),
        "wall_time_s": round(float(wall), 4),
        "renderer": None if ctx is None else str(ctx.info.get("GL_RENDERER", "?")),
        "deformgl": version(),
    }


def summary_line(record: dict[str, Any]) -> str:
    """One line: ``dragon.ply: 5411 nodes, 61234 springs, verlet on fragment, 1600 steps of dt
    0.00025 s (1 substep), 0.4 s simulated, 12.3 s wall``."""
    parts = [f"{record['mesh']}: {record['nodes']} nodes, {record['springs']} springs"]
    if record.get("integrator"):
        sub = record["substeps"]
        parts.append(f"{record['integrator']} on {record['backend']}")
        parts.append(f"{record['steps']} steps of dt {record['dt_s']:g} s ({sub} substep{'s' if sub != 1 else ''})")
        parts.append(f"{record['simulated_time_s']:.4g} s simulated")
    else:
        parts.append(f"nodes from {record['nodes_source']}")
    if record.get("frames", 1) > 1:
        parts.append(f"{record['frames']} frames at {record['fps']:g} fps")
    parts.append(f"{record['wall_time_s']:.2f} s wall")
    if record.get("renderer"):
        parts.append(str(record["renderer"]))
    return ", ".join(parts)


def write_record(path: str | os.PathLike[str], record: dict[str, Any]) -> None:
    """The record as indented JSON, atomically."""
    text = json.dumps(record, indent=2, default=str) + "\n"
    write_atomic(path, lambda stream: stream.write(text.encode()))
