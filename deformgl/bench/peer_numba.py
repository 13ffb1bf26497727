"""The fragment backend's Verlet fast path in Numba (``@njit(parallel=True)``, ``prange`` over the
nodes), the third CPU peer of :mod:`deformgl.bench.peers`: the same float32 step as the Taichi and
Warp peers, every scalar a float32. The ``prange`` loop runs on Numba's thread pool on the
``workqueue`` threading layer unless ``NUMBA_THREADING_LAYER`` says otherwise (the OpenMP layer's
threads spin-wait at each barrier on a shared machine). Imported lazily by
:func:`deformgl.bench.peers.make_stepper`; ``import numba`` happens in :func:`_kernel`."""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from deformgl.bench.peer_base import PeerStepper
from deformgl.sim.backends.verlet_data import FLAG_FIXED, MAX_PULLS, PULL_SHIFT
from deformgl.sim.springs import SpringSystem
from deformgl.sim.scripted import Load

_NB: dict[str, Any] = {}


def _kernel() -> tuple[Any, Callable[..., None]]:
    """Import Numba and build the parallel kernel once per process (compiled at its first call,
    once per argument type signature)."""
    if _NB:
        return _NB["numba"], _NB["kernel"]
    import os

    import numba
    from numba import prange

    if "NUMBA_THREADING_LAYER" not in os.environ:
        # (read at the first parallel launch; numba.config sets its names at import, unseen by
        # mypy: set by name, so that mypy judges it alike with and without the 'peers' extra)
        setattr(numba.config, "THREADING_LAYER", "workqueue")

    fixed_bit = np.int32(FLAG_FIXED)
    pull_shift = int(PULL_SHIFT)
    pulls = int(MAX_PULLS)
    tiny = np.float32(1e-30)
    two = np.float32(2.0)
    sqrt2 = np.float32(np.sqrt(2.0))

    @numba.njit(parallel=True, fastmath=False, nogil=True)
    def verlet(x, xp, out, nb, mask, offsets, dense, mass, flags, h, k1, k2, c, dt, gravity, pull):  # pragma: no cover - compiled
        n = x.shape[0]
        for i in prange(n):
            fl = flags[i]
            px, py, pz = x[i, 0], x[i, 1], x[i, 2]
            if fl & fixed_bit:
                out[i, 0], out[i, 1], out[i, 2] = px, py, pz
                continue
            s1x = s1y = s1z = p1x = p1y = p1z = np.float32(0.0)
            s2x = s2y = s2z = p2x = p2y = p2z = np.float32(0.0)
            bits = mask[i]
            for j in range(18):
                m = -1
                if dense:
                    if (bits >> j) & 1:
                        m = i + offsets[j]
                else:
                    m = nb[i, j]
                if m >= 0:
                    dx = px - x[m, 0]
                    dy = py - x[m, 1]
                    dz = pz - x[m, 2]
                    inv = np.float32(1.0) / max(np.sqrt(dx * dx + dy * dy + dz * dz), tiny)
                    if j < 6:
                        s1x += inv * dx
                        s1y += inv * dy
                        s1z += inv * dz
                        p1x += dx
                        p1y += dy
                        p1z += dz
                    else:
                        s2x += inv * dx
                        s2y += inv * dy
                        s2z += inv * dz
                        p2x += dx
                        p2y += dy
                        p2z += dz
            qx, qy, qz = xp[i, 0], xp[i, 1], xp[i, 2]
            mi = mass[i]
            fx = k1 * (h * s1x - p1x) + k2 * (sqrt2 * h * s2x - p2x) + mi * gravity[0] - c * (px - qx) / dt
            fy = k1 * (h * s1y - p1y) + k2 * (sqrt2 * h * s2y - p2y) + mi * gravity[1] - c * (py - qy) / dt
            fz = k1 * (h * s1z - p1z) + k2 * (sqrt2 * h * s2z - p2z) + mi * gravity[2] - c * (pz - qz) / dt
            for g in range(pulls):
                if (fl >> (pull_shift + g)) & 1:
                    fx += pull[g, 0]
                    fy += pull[g, 1]
                    fz += pull[g, 2]
            a = dt * dt / mi
            out[i, 0] = two * px - qx + a * fx
            out[i, 1] = two * py - qy + a * fy
            out[i, 2] = two * pz - qz + a * fz

    _NB.update(numba=numba, kernel=verlet)
    return numba, verlet


class NumbaStepper(PeerStepper):
    """The Verlet step as a Numba ``@njit(parallel=True)`` kernel (state in three (N, 3) float32
    arrays rotated between steps)."""

    name = "numba"

    def __init__(self, system: SpringSystem, dt: float, loads: tuple[Load, ...] = ()) -> None:
        super().__init__(system, dt, loads)
        self._numba, self._kernel = _kernel()
        self._state = [self.rest32.copy() for _ in range(3)]
        # dense grids: neighbours by mask and offset (the index table is not read, a 1x18 stand-in)
        self._nb = self._neighbours[:1].copy() if self.dense else self._neighbours
        self._off = np.array(self._offsets, np.int32)
        f32 = np.float32
        self._args = (*(f32(v) for v in self._scalars), np.array(self._gravity, f32))

    def _launch(self, pull: np.ndarray) -> None:
        x, xp, out = self._state
        self._kernel(x, xp, out, self._nb, self._mask, self._off, bool(self.dense), self._mass, self._flags,
                     *self._args, np.ascontiguousarray(pull, np.float32))
        self._state = [out, x, xp]

    def positions(self) -> np.ndarray:
        return self._state[0].copy()

    def set_state(self, x: np.ndarray, x_prev: np.ndarray | None = None) -> None:
        self._state[0] = np.ascontiguousarray(x, np.float32).copy()
        self._state[1] = np.ascontiguousarray(x if x_prev is None else x_prev, np.float32).copy()

    def release(self) -> None:
        """Drop the state arrays (the stepper is unusable afterwards)."""
        self._state = []

    @property
    def threads(self) -> int:
        return int(self._numba.get_num_threads())

    @property
    def threading_layer(self) -> str:
        """Numba's threading layer (known after the first step)."""
        try:
            return str(self._numba.threading_layer())
        except ValueError:  # no parallel launch yet
            return str(self._numba.config.THREADING_LAYER)
