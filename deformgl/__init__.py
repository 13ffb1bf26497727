"""deformgl: GPU soft bodies on a coarse grid, detailed meshes deformed by them, rendered headless.

The public API (see docs/API.md; ``deformgl.render`` etc. stay the subpackages); every name is imported on first use, so ``import deformgl``
starts no GL context and loads neither moderngl nor trimesh::

    import numpy as np
    import deformgl as dg

    with dg.Body.from_arrays(V, F, resolution=8, fixed=dg.below("y", 0.1)) as body:
        sim = body.simulate("verlet", "fragment", dt=1e-3)
        dg.run(sim, 200)                      # the CLI's dt check, blow-up census, subdivision
        V2, F2 = body.mapped_mesh(sim)        # the deformed detailed mesh, NumPy
        dg.write_png("out.png", body.render(sim))

Scenes: :func:`load_scene`, :func:`render_scene`, :func:`render_to_png`. Lower levels: the spring
system builders, :func:`make_simulation` (the one constructor of a backend's :class:`Simulation`),
:class:`GuardedSimulation` (one that :func:`run` restarts at a smaller step, with a context of its
own), :func:`run` (the one run: dt check, blow-up census, convergence stop, subdivision), the
trilinear scene graph, the error types.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

# name -> module that defines it; imported on first attribute access (PEP 562)
_EXPORTS: dict[str, str] = {
    # bodies, running, images
    "Body": "deformgl.scene.body",
    "below": "deformgl.scene.body",
    "above": "deformgl.scene.body",
    "inside": "deformgl.scene.body",
    "write_png": "deformgl.scene.body",
    "make_simulation": "deformgl.sim.simulation",
    "GuardedSimulation": "deformgl.sim.restartable",
    "Simulation": "deformgl.sim.simulation",
    "run": "deformgl.sim.run",
    "RunResult": "deformgl.sim.run",
    "ConvergeRule": "deformgl.sim.equilibrium",
    # scenes
    "load_scene": "deformgl.scene.schema",
    "Scene": "deformgl.scene.spec",
    "Region": "deformgl.scene.spec",
    "BACKENDS": "deformgl.scene.spec",
    "render_scene": "deformgl.scene.body",
    "render_to_png": "deformgl.scene.body",
    # animations, cameras, panels, sweeps
    "render_animation": "deformgl.scene.outputs",
    "render_frames": "deformgl.scene.animation",
    "frame_plan": "deformgl.scene.animation",
    "AnimationWriter": "deformgl.render.video",
    "sweep_scene": "deformgl.sweep.runner",
    "run_sweep": "deformgl.sweep.runner",
    "load_sweep": "deformgl.sweep.sweepfile",
    # meshes and grids
    "load_mesh": "deformgl.grid.meshio",
    "voxelize": "deformgl.grid.voxelize",
    "NodeGrid": "deformgl.grid.nodes",
    # spring systems, integrators, guards
    "SpringSystem": "deformgl.sim.springs",
    "from_grid": "deformgl.sim.springs",
    "cloth": "deformgl.sim.springs",
    "from_triangle_mesh": "deformgl.sim.springs",
    "Drag": "deformgl.sim.scripted",
    "Load": "deformgl.sim.scripted",
    "ElasticMaterial": "deformgl.sim.materials",
    "SheetMaterial": "deformgl.sim.materials",
    "PRESETS": "deformgl.sim.materials",
    "lattice_system": "deformgl.sim.materials",
    "sheet_system": "deformgl.sim.materials",
    "INTEGRATORS": "deformgl.sim.integrators",
    "EXPLICIT_INTEGRATORS": "deformgl.sim.integrators",
    "Constraints": "deformgl.sim.integrators",
    "Sphere": "deformgl.sim.integrators",
    "dt_limit": "deformgl.sim.limits",
    "check_dt": "deformgl.sim.limits",
    # GL and rendering
    "create_context": "deformgl.gl.context",
    "GLOwner": "deformgl.gl.resources",
    "View": "deformgl.render.camera",
    "frame_box": "deformgl.render.camera",
    "Lighting": "deformgl.render.passes",
    # the trilinear scene graph (Knuth, Kohlhammer & Kuijper)
    "Trilinear": "deformgl.trilinear.grid",
    "Box": "deformgl.trilinear.cuboid",
    "compose": "deformgl.trilinear.grid",
    "Twist": "deformgl.trilinear.deformations",
    "Taper": "deformgl.trilinear.deformations",
    "Bend": "deformgl.trilinear.deformations",
    "Helix": "deformgl.trilinear.deformations",
    "TorusWrap": "deformgl.trilinear.deformations",
    "Geometry": "deformgl.trilinear.graph_nodes",
    "Node": "deformgl.trilinear.graph_nodes",
    "GroupNode": "deformgl.trilinear.graph_nodes",
    "TransformNode": "deformgl.trilinear.graph_nodes",
    "GeometryNode": "deformgl.trilinear.graph_nodes",
    "ComposedScene": "deformgl.trilinear.batches",
    "compose_scene": "deformgl.trilinear.scenegraph",
    "SceneComposer": "deformgl.trilinear.scenegraph",
    "TrilinearRenderer": "deformgl.trilinear.renderer",
    "TubeAttachment": "deformgl.trilinear.attachments",
    "uv_sphere": "deformgl.trilinear.shapes",
    "tube": "deformgl.trilinear.shapes",
    "compose_within": "deformgl.trilinear.errorbound",
    "composition_bound": "deformgl.trilinear.grid",
    # scene-graph files (docs/SCENEGRAPH.md)
    "SceneGraph": "deformgl.trilinear.graphspec",
    "NodeSpec": "deformgl.trilinear.graphspec",
    "GraphTransform": "deformgl.trilinear.graphspec",
    "GraphMesh": "deformgl.trilinear.graphspec",
    "Deformation": "deformgl.trilinear.graphspec",
    "Keyframe": "deformgl.trilinear.graphspec",
    "GraphView": "deformgl.trilinear.graphspec",
    "GraphBody": "deformgl.trilinear.graphspec",
    "load_graph": "deformgl.trilinear.graphfile",
    "save_graph": "deformgl.trilinear.graphfile",
    "compose_graph": "deformgl.trilinear.graphbuild",
    "render_graph": "deformgl.trilinear.graphbuild",
    "render_graph_frames": "deformgl.trilinear.graphbuild",
    "graph_mesh": "deformgl.trilinear.graphbuild",
    "render_graph_file": "deformgl.scene.graphs",
    # errors
    "DeformglError": "deformgl.errors",
    "InputError": "deformgl.errors",
    "ArgumentError": "deformgl.errors",
    "SceneError": "deformgl.errors",
    "GLError": "deformgl.errors",
    "ShaderError": "deformgl.errors",
    "SimulationError": "deformgl.errors",
    "BlowUp": "deformgl.sim.guards",
    "SimulationSetupError": "deformgl.sim.simulation",
}

__all__ = sorted(_EXPORTS)

if TYPE_CHECKING:  # what type checkers and IDEs see; at run time __getattr__ imports lazily
    from deformgl.errors import ArgumentError, DeformglError, GLError, InputError, SceneError, ShaderError, SimulationError
    from deformgl.gl.context import create_context
    from deformgl.gl.resources import GLOwner
    from deformgl.grid.meshio import load_mesh
    from deformgl.grid.nodes import NodeGrid
    from deformgl.grid.voxelize import voxelize
    from deformgl.render.camera import View, frame_box
    from deformgl.render.passes import Lighting
    from deformgl.render.video import AnimationWriter
    from deformgl.scene.animation import frame_plan, render_frames
    from deformgl.scene.outputs import render_animation
    from deformgl.sweep.runner import run_sweep, sweep_scene
    from deformgl.sweep.sweepfile import load_sweep
    from deformgl.scene.body import Body, above, below, inside, render_scene, render_to_png, write_png
    from deformgl.scene.schema import load_scene
    from deformgl.scene.spec import BACKENDS, Region, Scene
    from deformgl.sim.guards import BlowUp
    from deformgl.sim.integrators import EXPLICIT_INTEGRATORS, INTEGRATORS, Constraints, Sphere
    from deformgl.sim.restartable import GuardedSimulation
    from deformgl.sim.run import RunResult, run
    from deformgl.sim.equilibrium import ConvergeRule
    from deformgl.sim.simulation import Simulation, SimulationSetupError, make_simulation
    from deformgl.sim.springs import SpringSystem, cloth, from_grid, from_triangle_mesh
    from deformgl.sim.scripted import Drag, Load
    from deformgl.sim.materials import PRESETS, ElasticMaterial, SheetMaterial, lattice_system, sheet_system
    from deformgl.sim.limits import check_dt, dt_limit
    from deformgl.trilinear.attachments import TubeAttachment
    from deformgl.trilinear.batches import ComposedScene
    from deformgl.trilinear.cuboid import Box
    from deformgl.trilinear.deformations import Bend, Helix, Taper, TorusWrap, Twist
    from deformgl.scene.graphs import render_graph_file
    from deformgl.trilinear.errorbound import compose_within
    from deformgl.trilinear.graphbuild import compose_graph, graph_mesh, render_graph, render_graph_frames
    from deformgl.trilinear.graphfile import load_graph, save_graph
    from deformgl.trilinear.graphspec import (
        Deformation, GraphBody, GraphMesh, GraphTransform, GraphView, Keyframe, NodeSpec, SceneGraph,
    )
    from deformgl.trilinear.grid import Trilinear, compose, composition_bound
    from deformgl.trilinear.graph_nodes import Geometry, GeometryNode, GroupNode, Node, TransformNode
    from deformgl.trilinear.renderer import TrilinearRenderer
    from deformgl.trilinear.scenegraph import compose_scene
    from deformgl.trilinear.shapes import tube, uv_sphere


def __getattr__(name: str) -> Any:
    """Import a public name on first use (PEP 562) and keep it in the module."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'deformgl' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """The public names with the module's own."""
    return sorted(set(globals()) | set(__all__))
