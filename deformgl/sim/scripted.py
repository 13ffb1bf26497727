"""Scripted boundary conditions of a run, evaluated at each stage's time (s): drags (a node pulled
toward a moving target by a zero-rest-length spring) and loads (forces on groups of nodes, per node
or per kilogram), and the load groups' bits every GPU backend keeps in its static node data.
:func:`deformgl.sim.springs.forces` adds them to the system's forces (float64)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["Drag", "LOAD_PER_KG_BIT", "Load", "MAX_LOADS", "load_groups"]


@dataclass(frozen=True, eq=False)
class Drag:
    """A scripted drag: a zero-rest-length spring pulling one node toward a moving target.

    Force on the node: ``stiffness * (target(t) - x_node)`` (the user-intervention external force
    of Movania & Feng 2012, section 3; section 5 picks and moves a point).

    Attributes:
        node: node number.
        target: t (s) -> (3,) target position.
        stiffness: N/m.
    """

    node: int
    target: Callable[[float], ArrayLike]
    stiffness: float


#: Load groups a GPU backend supports (one bit each in the static node data).
MAX_LOADS = 4


#: Bit of :func:`load_groups`' word set on the nodes of loads given per kilogram.
LOAD_PER_KG_BIT = MAX_LOADS


@dataclass(frozen=True, eq=False)
class Load:
    """A scripted force applied to each node of a set (a scene's ``[[physics.pull]]``).

    Force on every node in ``nodes``: ``force(t)`` in N (the external force of Movania & Feng
    2012 eq. 1; the foundation's pull groups of Mosegaard & Sørensen 2005, section 3.1), or with
    ``per_kg`` ``force(t)`` in N/kg times the node's mass: a pull spread over the material the
    nodes carry, as a material scene's total force is (a node at the edge of the mesh, carrying a
    sliver of a cell, gets its sliver of the force, not a whole node's).

    Attributes:
        nodes: (N,) bool, the nodes it acts on.
        force: t (s) -> (3,) force per node in N, or per kilogram of node mass in N/kg.
        per_kg: whether ``force`` is per kilogram.
    """

    nodes: np.ndarray
    force: Callable[[float], ArrayLike]
    per_kg: bool = False

    def __post_init__(self) -> None:
        mask = np.array(self.nodes, dtype=bool)
        mask.setflags(write=False)
        object.__setattr__(self, "nodes", mask)

    def node_forces(self, t: float, mass: np.ndarray) -> np.ndarray:
        """(K, 3) force in N on each of its K nodes at time t (``mass``: (N,) every node's, kg)."""
        f = np.asarray(self.force(t), dtype=np.float64)[None, :]
        return f * np.asarray(mass, np.float64)[self.nodes, None] if self.per_kg else \
            np.repeat(f, int(self.nodes.sum()), axis=0)


def load_groups(loads: tuple[Load, ...], count: int) -> np.ndarray:
    """(N,) int32 bit g set where load g acts, and bit :data:`LOAD_PER_KG_BIT` where its loads
    are per kilogram (what the GPU backends store per node; shaders/lib/node_forces.glsl).

    Raises:
        ValueError: more than :data:`MAX_LOADS` loads, a mask of the wrong length, or loads per
            node and per kilogram on one node.
    """
    if len(loads) > MAX_LOADS:
        raise ValueError(f"{len(loads)} loads; the GPU backends support at most {MAX_LOADS}")
    bits = np.zeros(count, np.int32)
    per_kg = np.zeros(count, bool)
    per_node = np.zeros(count, bool)
    for g, load in enumerate(loads):
        if load.nodes.shape != (count,):
            raise ValueError(f"load {g}: node mask of shape {load.nodes.shape}, expected ({count},)")
        bits |= load.nodes.astype(np.int32) << g
        (per_kg if load.per_kg else per_node)[load.nodes] = True
    if (per_kg & per_node).any():
        raise ValueError(f"node {int(np.argmax(per_kg & per_node))} is in a load per node and a load per "
                         f"kilogram; a node's loads must be all one or the other")
    return bits | (per_kg.astype(np.int32) << LOAD_PER_KG_BIT)
