"""float64 NumPy reference of the fragment-pass simulation step: same equations, no GPU.

Spring forces follow eq. 1 (and its grouped form eq. 2) of Mosegaard & Sørensen 2005, normals
eq. 3, integration is position Verlet (Movania & Feng 2012):
``x' = 2x - x_prev + dt^2 a``, ``a = (g + m*gravity + pull - c*v) / m``, ``v = (x - x_prev)/dt``.
Fixed nodes keep their position exactly.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from deformgl.grid.nodes import REST_LENGTH_UNITS
from deformgl.sim.model import SpringModel
from deformgl.sim.normals import pack_normals


@dataclass
class SpringSums:
    """Per-node results of the neighbour loop: spring force and the eq. 3 unit-vector sum."""

    force: np.ndarray
    unit_sum: np.ndarray


def spring_sums(model: SpringModel, x: np.ndarray) -> SpringSums:
    """Spring force (eq. 1) and sum of unit vectors from the neighbours (eq. 3) for every node.

    Args:
        model: the spring model.
        x: (N, 3) float64 positions.
    """
    nb = model.grid.neighbours
    present = (nb >= 0)[..., None]
    xj = x[np.where(nb >= 0, nb, np.arange(len(x))[:, None])]
    d = x[:, None, :] - xj                                    # p_i - p_j, (N, 18, 3)
    length = np.linalg.norm(d, axis=-1, keepdims=True)
    unit = np.where(present, d / np.where(length > 0, length, 1.0), 0.0)
    rest = (model.grid.spacing * REST_LENGTH_UNITS)[None, :, None]
    k = model.spring_stiffness[None, :, None]
    force = np.sum(np.where(present, k * (rest - length) * unit, 0.0), axis=1)
    return SpringSums(force=force, unit_sum=unit.sum(axis=1))


def acceleration(model: SpringModel, x: np.ndarray, v: np.ndarray, pull: np.ndarray) -> tuple[np.ndarray, SpringSums]:
    """Acceleration of every node: ``(g + m*gravity + pull - c*v) / m``.

    Args:
        pull: (MAX_PULLS, 3) force per node of each pull group at this time.
    """
    s = spring_sums(model, x)
    m = model.mass[:, None]
    groups = model.pull_groups[:, None] >> np.arange(pull.shape[0]) & 1
    f = s.force + m * model.gravity - model.damping * v + groups @ pull
    return f / m, s


@dataclass
class ReferenceVerlet:
    """Position-Verlet integration of a :class:`SpringModel` in float64.

    Attributes:
        x: (N, 3) current positions; x_prev: (N, 3) previous; normals: (N,) packed eq. 3 normals
        of the last step (float32 integers, as in the alpha channel of the GPU texture).
    """

    model: SpringModel
    dt: float
    pull_force: Callable[[float], np.ndarray] | None = None  # t -> (MAX_PULLS, 3)
    x: np.ndarray = field(init=False)
    x_prev: np.ndarray = field(init=False)
    normals: np.ndarray = field(init=False)
    steps_done: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        self.x = self.model.grid.rest_positions.copy()
        self.x_prev = self.x.copy()
        self.normals = pack_normals(spring_sums(self.model, self.x).unit_sum)

    def pull_at(self, t: float) -> np.ndarray:
        """Pull forces of every group at time t (zeros without a pull schedule)."""
        if self.pull_force is None:
            return np.zeros((max(self.model.n_pulls, 1), 3))
        return np.asarray(self.pull_force(t), dtype=np.float64)

    def step(self, n: int = 1) -> None:
        """Advance n steps."""
        fixed = self.model.fixed[:, None]
        for _ in range(n):
            v = (self.x - self.x_prev) / self.dt
            a, s = acceleration(self.model, self.x, v, self.pull_at(self.steps_done * self.dt))
            new = 2.0 * self.x - self.x_prev + self.dt * self.dt * a
            self.normals = pack_normals(s.unit_sum)
            self.x_prev, self.x = self.x, np.where(fixed, self.x, new)
            self.steps_done += 1
