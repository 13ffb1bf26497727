"""Immutable physical model of a node grid: per-node attributes and spring constants.

The spring force on node i from neighbour j is eq. 1 of Mosegaard & Sørensen 2005,
``g_i = sum_j 1/2 k_ij (l_ij - |p_i - p_j|) (p_i - p_j)/|p_i - p_j|``. deformgl's stiffness
``k`` is the physical spring constant in N/m, i.e. ``k = k_ij / 2`` of the paper, so a scene's
stiffness means the same thing in every backend and integrator (and in Movania & Feng's form
``F = k (L - |d|) d/|d|``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deformgl.grid.nodes import N_STRUCTURAL, REST_LENGTH_UNITS, NodeGrid

#: Node flag bits, stored in the G channel of the static node texture.
FLAG_EXISTS = 1
FLAG_FIXED = 2
#: Bit of pull group g is ``1 << (PULL_SHIFT + g)``.
PULL_SHIFT = 2
MAX_PULLS = 4


@dataclass(frozen=True, eq=False)
class SpringModel:
    """What does not change during a run.

    Attributes:
        grid: the node grid.
        mass: (N,) float64 kg per node, > 0.
        fixed: (N,) bool, nodes that keep their position exactly.
        pull_groups: (N,) uint8, bit g set when node belongs to scripted pull g (< MAX_PULLS).
        k_structural: N/m of the 6 springs at distance h (set D1).
        k_shear: N/m of the 12 springs at distance h*sqrt(2) (set D2).
        damping: N*s/m global velocity damping per node.
        gravity: (3,) float64 m/s^2.
        n_pulls: number of pull groups in use.
    """

    grid: NodeGrid
    mass: np.ndarray
    fixed: np.ndarray
    pull_groups: np.ndarray
    k_structural: float
    k_shear: float
    damping: float
    gravity: np.ndarray
    n_pulls: int = 0

    def __post_init__(self) -> None:
        n = self.grid.count
        for name in ("mass", "fixed", "pull_groups"):
            arr = getattr(self, name)
            if arr.shape != (n,):
                raise ValueError(f"SpringModel.{name}: shape {arr.shape}, expected ({n},)")
            arr.setflags(write=False)
        self.gravity.setflags(write=False)

    @property
    def equal_stiffness(self) -> bool:
        """All springs share one stiffness: eq. 2 applies."""
        return self.k_structural == self.k_shear

    @property
    def spring_stiffness(self) -> np.ndarray:
        """(18,) stiffness of each neighbour slot, in NEIGHBOUR_OFFSETS order."""
        k = np.full(len(REST_LENGTH_UNITS), self.k_shear)
        k[:N_STRUCTURAL] = self.k_structural
        return k

    def flags(self) -> np.ndarray:
        """(N,) int64 flag bits: exists, fixed, pull groups."""
        return (FLAG_EXISTS + FLAG_FIXED * self.fixed.astype(np.int64)
                + (self.pull_groups.astype(np.int64) << PULL_SHIFT))

    def max_angular_frequency(self) -> float:
        """Upper bound of the highest angular frequency: w_max^2 <= max_i 2*sum_j k_ij / m_i."""
        present = self.grid.neighbours >= 0
        ksum = (present * self.spring_stiffness).sum(axis=1)
        return float(np.sqrt(np.max(2.0 * ksum / self.mass)))
