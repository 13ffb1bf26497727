"""Uniform values every GPU backend sets the same way: moderngl's form of a uniform array, and
the moving spheres' uniforms of a step (``lib/constraints.glsl``)."""

from __future__ import annotations

from deformgl.sim.integrators import Constraints

__all__ = ["uniform_array", "sphere_uniforms", "pull_uniforms"]


def uniform_array(values: list) -> object:
    """A uniform array value for moderngl: an array of length 1 is set as its element."""
    return values[0] if len(values) == 1 else values


def pull_uniforms(pull, n_pulls: int, who: str) -> dict[str, object]:
    """``u_pull_force`` of the foundation's Verlet passes (one-node and blocked): the first
    ``n_pulls`` rows of ``pull`` (N per node, or N/kg on nodes flagged ``FLAG_PULLS_PER_KG``, this
    step); empty without pulls.

    Raises:
        TypeError: pull groups but no forces (``who`` names the pass).
    """
    if not n_pulls:
        return {}
    if pull is None:
        raise TypeError(f"{who}: {n_pulls} pull group(s) need pull forces")
    return {"u_pull_force": uniform_array([tuple(map(float, f)) for f in pull[:n_pulls]])}


def sphere_uniforms(constraints: Constraints | None, t: float, dt: float) -> dict[str, object]:
    """``u_spheres`` (centre at t + dt, radius) and ``u_sphere_velocity`` (the centre's mean
    velocity over the step, m/s) of the step from ``t``; empty without spheres."""
    if constraints is None or not constraints.spheres:
        return {}
    spheres, velocities = [], []
    for sphere in constraints.spheres:
        end = sphere.centre_at(t + dt)
        spheres.append((*map(float, end), float(sphere.radius)))
        velocities.append(tuple(map(float, (end - sphere.centre_at(t)) / dt)))
    return {"u_spheres": uniform_array(spheres), "u_sphere_velocity": uniform_array(velocities)}
