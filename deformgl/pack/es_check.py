"""``python -m deformgl.pack.es_check OUT.npz SCENE...``: render scenes on an OpenGL ES 3 context.

The ES profile's end-to-end check (``tests/test_es_profile.py``): each scene is simulated and
drawn by :func:`deformgl.scene.pipeline.render` exactly as ``deformgl render`` does, but every
program is built from the ``es`` profile of the shaders on the context of
:func:`deformgl.gl.es_context.create_es_context` (a process of its own: that context becomes the
thread's current one). A SCENE named ``trilinear:NAME`` is one of the trilinear scene-graph
scenes (3D-texture atlas with linear filtering). Writes the images (``image_<i>``), the GL
version and the seconds per scene to ``OUT.npz``; ``--integrators`` adds the node positions
(``x_<backend>_<integrator>_<constraint>``) after :data:`STEPS` steps of every integrator on
both backends from :func:`integrator_case`'s start, and of the stable integrators
(:data:`STABLE`: implicit Euler, XPBD; fragment backend only) at :data:`STABLE_DT`.
"""

from __future__ import annotations

import dataclasses

import sys
import time
from pathlib import Path

import numpy as np

from deformgl.files import write_atomic
from deformgl.gl.es_context import create_es_context
from deformgl.scene.pipeline import render
from deformgl.scene.schema import load_scene

SIZE = (160, 120)
STEPS = 5
CONSTRAINTS = ("none", "ground", "sphere")
#: The stable integrators of the check with their options (fragment backend), and their step in s.
STABLE = {"implicit-euler": {"cg_iterations": 10}, "xpbd": {"iterations": 4, "substeps": 2}}
STABLE_DT = 1e-2


def integrator_case(constraint: str):
    """A damped 3x3x3 grid with wind, flexion and a fixed node, its start state and constraint."""
    from deformgl.grid.nodes import NodeGrid
    from deformgl.sim import springs
    from deformgl.sim.integrators import Constraints, Sphere, initial_state

    grid = NodeGrid(np.array([0.2, 0.5, -0.1]), 0.1, np.ones((3, 3, 3), bool))
    fixed = np.zeros(grid.count, bool)
    fixed[0] = True
    system = springs.from_grid(grid, k_structural=50.0, k_shear=20.0, k_flexion=10.0, damping_structural=0.1,
                               damping_shear=0.05, damping_flexion=0.025, mass=0.1, fixed=fixed,
                               velocity_damping=0.02, wind=(1.0, 0.0, 0.5), wind_drag=0.01)
    state = initial_state(system, 1e-3, v=np.random.default_rng(1).normal(size=(grid.count, 3)))
    constraints = {"none": None, "ground": Constraints(ground=-0.05),
                   "sphere": Constraints(spheres=(Sphere((0.3, 0.6, 0.0), 0.05),))}[constraint]
    return system, grid, state, constraints


def integrators(ctx) -> dict[str, np.ndarray]:
    """Positions after :data:`STEPS` steps, every backend, integrator and constraint."""
    from deformgl.sim.backends.feedback import FeedbackSimulation
    from deformgl.sim.backends.explicit_gpu import FragmentIntegrator
    from deformgl.sim.integrators import EXPLICIT_INTEGRATORS

    out = {}
    for backend in ("fragment", "feedback"):
        for name in EXPLICIT_INTEGRATORS:
            for constraint in CONSTRAINTS:
                system, grid, state, c = integrator_case(constraint)
                sim = (FragmentIntegrator(ctx, system, grid, name, 1e-3, state=state, constraints=c)
                       if backend == "fragment" else
                       FeedbackSimulation(ctx, system, name, 1e-3, state=state, constraints=c))
                try:
                    sim.step(STEPS)
                    out[f"x_{backend}_{name}_{constraint}"] = np.asarray(sim.positions(), np.float32)
                finally:
                    sim.release()
    out.update(stable_integrators(ctx))
    return out


def stable_integrators(ctx, backend: str = "fragment") -> dict[str, np.ndarray]:
    """Positions after :data:`STEPS` steps of :data:`STABLE_DT` of each :data:`STABLE`
    integrator and constraint on ``backend`` (fragment, or numpy: the reference)."""
    from deformgl.sim.simulation import make_simulation

    out = {}
    for name, options in STABLE.items():
        for constraint in CONSTRAINTS:
            system, grid, state, c = integrator_case(constraint)
            sim = make_simulation(system, name, backend, dt=STABLE_DT, ctx=ctx,
                                  grid=grid if backend == "fragment" else None, state=state, constraints=c, **options)
            try:
                sim.step(STEPS)
                out[f"x_{backend}_{name}_{constraint}"] = np.asarray(sim.positions(), np.float64 if backend == "numpy"
                                                                     else np.float32)
            finally:
                sim.release()
    return out


def render_named(ctx, name: str) -> np.ndarray:
    """``deformgl render`` of a scene file (``fxaa:PATH``: with ``[render] aa = "fxaa"``), or
    ``trilinear:NAME`` at :data:`SIZE`."""
    if name.startswith("trilinear:"):
        from deformgl.trilinear.scenes import render_trilinear_scene

        return render_trilinear_scene(ctx, name.split(":", 1)[1], (2 * SIZE[0], SIZE[1]))
    fxaa = name.startswith("fxaa:")
    scene = load_scene(Path(name.split(":", 1)[1] if fxaa else name)).with_overrides(size=SIZE)
    if fxaa:
        scene = dataclasses.replace(scene, render=dataclasses.replace(scene.render, aa="fxaa"))
    return render(ctx, scene).image


def main(argv: list[str]) -> int:
    out, scenes = Path(argv[0]), [a for a in argv[1:] if a != "--integrators"]
    ctx = create_es_context()
    arrays: dict[str, np.ndarray] = {"version": np.array(ctx.info["GL_VERSION"])}
    if "--integrators" in argv:
        arrays.update(integrators(ctx))
    for i, name in enumerate(scenes):
        t = time.perf_counter()
        arrays[f"image_{i}"] = render_named(ctx, name)
        arrays[f"seconds_{i}"] = np.array(time.perf_counter() - t)
    write_atomic(out, lambda f: np.savez(f, allow_pickle=False, **arrays))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
