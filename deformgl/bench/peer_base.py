"""The common part of the CPU peers of :mod:`deformgl.bench.peers` (Taichi, Warp) and
:mod:`deformgl.bench.peer_numba`: the system data in float32 and the step loop."""

import numpy as np

from deformgl.grid.nodes import NEIGHBOUR_OFFSETS, node_strides
from deformgl.sim.backends.verlet_data import MAX_PULLS, VerletTerms, node_flags, verlet_terms
from deformgl.sim.springs import SpringSystem
from deformgl.sim.scripted import Load, load_groups


def _pull_rows(loads: tuple[Load, ...], t: float) -> np.ndarray:
    """(MAX_PULLS, 3) float32 force per node of each load at time t (loads per node only: the
    stepper refuses per-kg loads), as the fragment pass gets it."""
    out = np.zeros((MAX_PULLS, 3), np.float32)
    for g, load in enumerate(loads):
        out[g] = np.asarray(load.force(t), dtype=np.float64)
    return out


class PeerStepper:
    """Common part of the peer steppers: system data in float32, rotation of three state buffers.

    Args:
        system: a grid spring system the foundation pass models (:func:`verlet_terms`).
        dt: time step (s).
        loads: at most ``MAX_PULLS`` scripted loads, evaluated at ``steps_done * dt`` before each
            step (as the fragment pass).

    Raises:
        ValueError: dt <= 0, a system without a grid or with physics the pass does not model.
    """

    name = ""

    def __init__(self, system: SpringSystem, dt: float, loads: tuple[Load, ...] = ()) -> None:
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        grid = system.grid
        if grid is None:
            raise ValueError("the peers step grid systems (springs.from_grid or springs.cloth)")
        terms = verlet_terms(system, grid, loads=tuple(loads))
        if not isinstance(terms, VerletTerms):
            raise ValueError(f"the peers do not model {terms}")
        if terms.weights is not None or terms.mass_damping:
            raise ValueError("the peers do not model per-spring stiffness or mass damping (a material's "
                             "calibrated lattice): they step the per-spring form of the paper scenes")
        if any(load.per_kg for load in loads):
            raise ValueError("the peers apply loads per node, not per kilogram (a material scene's pull)")
        self.system = system
        self.dt = float(dt)
        self.loads = tuple(loads)
        self.steps_done = 0
        self.rest32 = np.ascontiguousarray(grid.rest_positions, dtype=np.float32)
        self._neighbours = np.ascontiguousarray(grid.neighbours, dtype=np.int32)
        # dense grids (every node of the box exists): neighbour j of node i is i + offsets[j] when
        # bit j of the mask is set, as the fragment pass's COMPACT_DENSE variant does
        self.dense = grid.full
        self._offsets = tuple(int(v) for v in NEIGHBOUR_OFFSETS @ np.array(node_strides(grid.shape)))
        self._mask = np.ascontiguousarray(grid.neighbour_mask, dtype=np.int32)
        self._mass = np.ascontiguousarray(system.mass, dtype=np.float32)
        self._flags = np.ascontiguousarray(node_flags(system.fixed, load_groups(self.loads, grid.count)),
                                           dtype=np.int32)
        self._scalars = tuple(float(np.float32(v)) for v in (
            grid.spacing, terms.k_structural, terms.k_shear, terms.damping, self.dt))
        self._gravity = tuple(float(g) for g in np.asarray(terms.gravity, np.float32))
        self._zero_pull = np.zeros((MAX_PULLS, 3), np.float32)

    @property
    def time(self) -> float:
        """Simulated time (s)."""
        return self.steps_done * self.dt

    def _pull(self) -> np.ndarray:
        if not self.loads:
            return self._zero_pull
        return _pull_rows(self.loads, self.time)

    def step(self, n: int = 1) -> None:
        """Advance n steps (state stays in the peer's arrays)."""
        for _ in range(n):
            self._launch(self._pull())
            self.steps_done += 1
        self._sync()

    def _launch(self, pull: np.ndarray) -> None:
        raise NotImplementedError

    def _sync(self) -> None:
        pass

    def positions(self) -> np.ndarray:
        """(N, 3) float32 current positions (one copy out)."""
        raise NotImplementedError

    def set_state(self, x: np.ndarray, x_prev: np.ndarray | None = None) -> None:
        """Overwrite the current (and previous, default: same) positions, e.g. for a test."""
        raise NotImplementedError

    @property
    def threads(self) -> int:
        """Worker threads a step uses."""
        raise NotImplementedError

    def release(self) -> None:
        """Free the peer's arrays now (otherwise they go with the stepper)."""
