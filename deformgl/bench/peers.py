"""The fragment backend's Verlet fast path (:mod:`deformgl.sim.backends.verlet_data`) in Taichi,
NVIDIA Warp and Numba on the CPU, for ``deformgl bench sim --peers``.

Each peer runs the same float32 position-Verlet step as ``shaders/sim/verlet.frag`` (Mosegaard &
Sørensen 2005, eq. 1 and 2: the 18 neighbours, per-class stiffness, velocity damping, gravity,
pull groups, fixed nodes) and keeps its state between steps. The packages are optional (the
'peers' extra) and imported lazily. Taichi runs on its CPU backend (one SNode tree and kernel per
system); Warp on ``device="cpu"`` (one thread); Numba (:mod:`deformgl.bench.peer_numba`) with
``prange``. On dense grids neighbour ``j`` of node ``i`` is ``i + offsets[j]`` when bit ``j`` of
the node's mask is set; elsewhere the (N, 18) neighbour table."""

# no "from __future__ import annotations": Taichi and Warp read the kernel annotations as objects

import numpy as np

from deformgl.bench.peer_base import PeerStepper
from deformgl.sim.backends.verlet_data import FLAG_FIXED, MAX_PULLS, PULL_SHIFT
from deformgl.sim.springs import SpringSystem
from deformgl.sim.scripted import Load

PEERS = ("taichi", "warp", "numba")


def available_peers() -> dict[str, str | None]:
    """Version of each installed peer package; None where it cannot be imported.

    Returns:
        ``{"taichi": "1.7.4" | None, "warp": "1.19.0" | None, "numba": "0.68.1" | None}``; use :func:`peer_import_errors`
        for the reason of a None.
    """
    return {name: version for name, (version, _) in _probe().items()}


def peer_import_errors() -> dict[str, str]:
    """The import error of each peer that is not available."""
    return {name: err for name, (_, err) in _probe().items() if err is not None}


def _probe() -> dict[str, tuple[str | None, str | None]]:
    out: dict[str, tuple[str | None, str | None]] = {}
    for name in PEERS:
        try:
            mod = __import__(name)
        except Exception as exc:  # ImportError, or a native library that fails to load
            out[name] = (None, f"{type(exc).__name__}: {exc}")
            continue
        version = getattr(mod, "__version__", None)
        if isinstance(version, tuple):
            version = ".".join(map(str, version))
        out[name] = (str(version), None)
    return out


# ---------------------------------------------------------------------------------------------
# Taichi

_TI: dict = {}


def _taichi():
    """Import Taichi and ``ti.init(arch=ti.cpu)`` once per process (a second ``ti.init`` would
    invalidate every field already allocated)."""
    if _TI:
        return _TI["ti"]
    import taichi as ti
    from taichi.lang import impl

    if impl.get_runtime().prog is None:
        ti.init(arch=ti.cpu)
    elif impl.current_cfg().arch not in (ti.x64, ti.arm64):
        raise RuntimeError(f"taichi is already initialised on {impl.current_cfg().arch}, not the CPU")
    _TI["ti"] = ti
    return ti


class TaichiStepper(PeerStepper):
    """The Verlet step as a Taichi CPU kernel over this system's own fields.

    The fields (state ``(3, N)`` vec3, neighbours, mass, flags, pulls) live in their own SNode tree
    (``ti.FieldsBuilder``), so models come and go without ``ti.reset()``; :meth:`release` frees
    them. The kernel is compiled per stepper with the system constants folded in (like uniforms
    that never change) and takes one int argument, the rotation phase of the three state rows:
    Taichi's Python-side launch cost grows with each kernel argument.
    """

    name = "taichi"

    def __init__(self, system: SpringSystem, dt: float, loads: tuple[Load, ...] = ()) -> None:
        super().__init__(system, dt, loads)
        ti = _taichi()
        self._ti = ti
        n = system.count
        fb = ti.FieldsBuilder()
        state = ti.Vector.field(3, ti.f32)
        nb = ti.field(ti.i32)
        mass = ti.field(ti.f32)
        flags = ti.field(ti.i32)
        pull = ti.Vector.field(3, ti.f32)
        dense = self.dense
        offsets = self._offsets
        fb.dense(ti.ij, (3, n)).place(state)
        if dense:
            fb.dense(ti.i, n).place(nb)  # the neighbour mask
        else:
            fb.dense(ti.ij, (n, 18)).place(nb)
        fb.dense(ti.i, n).place(mass, flags)
        fb.dense(ti.i, MAX_PULLS).place(pull)
        self._tree = fb.finalize()
        self._fields = (state, nb, mass, flags, pull)
        state.from_numpy(np.broadcast_to(self.rest32, (3, n, 3)).copy())
        nb.from_numpy(self._mask if dense else self._neighbours)
        mass.from_numpy(self._mass)
        flags.from_numpy(self._flags)
        pull.from_numpy(self._zero_pull)
        self._pull_now = self._zero_pull
        self._phase = 0  # state row of x is phase, x_prev (phase + 2) % 3, new (phase + 1) % 3
        h, k1, k2, c, dt32 = self._scalars
        gx, gy, gz = self._gravity
        sqrt2 = float(np.sqrt(2.0))
        vec3 = ti.math.vec3

        @ti.kernel
        # (taichi takes a kernel's argument types as annotations read at run time; ``ti`` is a
        # local module object here, which mypy cannot read as a type)
        def verlet(phase: ti.i32):  # type: ignore[name-defined]
            cur, prev, new = phase, (phase + 2) % 3, (phase + 1) % 3
            gravity = vec3(gx, gy, gz)
            for i in range(n):
                p = state[cur, i]
                fl = flags[i]
                if fl & FLAG_FIXED:
                    state[new, i] = p
                else:
                    s1 = vec3(0.0)
                    p1 = vec3(0.0)
                    s2 = vec3(0.0)
                    p2 = vec3(0.0)
                    mask = 0
                    if ti.static(dense):
                        mask = nb[i]
                    for j in ti.static(range(18)):
                        m_j = 0
                        ok = False
                        if ti.static(dense):
                            m_j = i + offsets[j]
                            ok = ((mask >> j) & 1) == 1
                        else:
                            m_j = nb[i, j]
                            ok = m_j >= 0
                        if ok:
                            d = p - state[cur, m_j]
                            inv = 1.0 / ti.max(d.norm(), 1e-30)
                            if ti.static(j < 6):
                                s1 += inv * d
                                p1 += d
                            else:
                                s2 += inv * d
                                p2 += d
                    q = state[prev, i]
                    m = mass[i]
                    f = k1 * (h * s1 - p1) + k2 * (sqrt2 * h * s2 - p2) + m * gravity - c * (p - q) / dt32
                    for g in ti.static(range(MAX_PULLS)):
                        if (fl >> (PULL_SHIFT + g)) & 1:
                            f += pull[g]
                    state[new, i] = 2.0 * p - q + (dt32 * dt32 / m) * f

        self._kernel = verlet

    def _launch(self, pull: np.ndarray) -> None:
        if pull is not self._pull_now and not np.array_equal(pull, self._pull_now):
            self._fields[4].from_numpy(pull)
        self._pull_now = pull
        self._kernel(self._phase)
        self._phase = (self._phase + 1) % 3

    def _sync(self) -> None:
        self._ti.sync()

    def positions(self) -> np.ndarray:
        return self._fields[0].to_numpy()[self._phase].astype(np.float32)

    def set_state(self, x: np.ndarray, x_prev: np.ndarray | None = None) -> None:
        state = self._fields[0].to_numpy()
        state[self._phase] = x
        state[(self._phase + 2) % 3] = x if x_prev is None else x_prev
        self._fields[0].from_numpy(state)

    def release(self) -> None:
        """Free this system's fields (the stepper is unusable afterwards)."""
        if self._tree is not None:
            self._tree.destroy()
            self._tree = None

    @property
    def threads(self) -> int:
        from taichi.lang import impl

        return int(impl.current_cfg().cpu_max_num_threads)


# ---------------------------------------------------------------------------------------------
# Warp

_WP: dict = {}


def _warp():
    """Import and initialise Warp once, and build the kernel (its own module, no backward pass)."""
    if _WP:
        return _WP["wp"], _WP["kernel"]
    import warp as wp

    # warp 1.19's typed config module no longer declares ``quiet`` (older releases read it):
    # set by name, so that mypy judges it alike with and without the 'peers' extra installed
    setattr(wp.config, "quiet", True)
    wp.init()
    sqrt2 = float(np.sqrt(2.0))

    @wp.kernel(enable_backward=False, module="unique")
    # (warp's kernel API declares argument types as calls such as ``wp.array(dtype=...)``, read at
    # run time; mypy accepts no call in an annotation)
    def verlet(x: wp.array(dtype=wp.vec3), xp: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3),  # type: ignore[valid-type]
               nb: wp.array2d(dtype=wp.int32), mask: wp.array(dtype=wp.int32), offsets: wp.array(dtype=wp.int32),  # type: ignore[valid-type]
               dense: wp.int32, mass: wp.array(dtype=wp.float32), flags: wp.array(dtype=wp.int32),  # type: ignore[valid-type]
               h: wp.float32, k1: wp.float32, k2: wp.float32, c: wp.float32, dt: wp.float32,
               gravity: wp.vec3, pull0: wp.vec3, pull1: wp.vec3, pull2: wp.vec3, pull3: wp.vec3):
        i = wp.tid()
        p = x[i]
        fl = flags[i]
        if (fl & FLAG_FIXED) != 0:
            out[i] = p
            return
        s1 = wp.vec3(0.0)
        p1 = wp.vec3(0.0)
        s2 = wp.vec3(0.0)
        p2 = wp.vec3(0.0)
        bits = int(0)
        if dense != 0:
            bits = mask[i]
        for j in range(18):
            n = int(-1)
            if dense != 0:
                if ((bits >> j) & 1) != 0:
                    n = i + offsets[j]
            else:
                n = nb[i, j]
            if n >= 0:
                d = p - x[n]
                u = d / wp.max(wp.length(d), 1e-30)
                if j < 6:
                    s1 += u
                    p1 += d
                else:
                    s2 += u
                    p2 += d
        q = xp[i]
        m = mass[i]
        f = k1 * (h * s1 - p1) + k2 * (sqrt2 * h * s2 - p2) + m * gravity - c * (p - q) / dt
        if ((fl >> PULL_SHIFT) & 1) != 0:
            f += pull0
        if ((fl >> (PULL_SHIFT + 1)) & 1) != 0:
            f += pull1
        if ((fl >> (PULL_SHIFT + 2)) & 1) != 0:
            f += pull2
        if ((fl >> (PULL_SHIFT + 3)) & 1) != 0:
            f += pull3
        out[i] = 2.0 * p - q + (dt * dt / m) * f

    _WP.update(wp=wp, kernel=verlet)
    return wp, verlet


class WarpStepper(PeerStepper):
    """The Verlet step as a Warp kernel on ``device="cpu"`` (state kept in three wp arrays)."""

    name = "warp"

    def __init__(self, system: SpringSystem, dt: float, loads: tuple[Load, ...] = ()) -> None:
        super().__init__(system, dt, loads)
        wp, self._kernel = _warp()
        self._wp = wp
        dev = "cpu"
        self._state = [wp.array(self.rest32, dtype=wp.vec3, device=dev) for _ in range(3)]
        # dense grids: neighbours by mask and offset (the index table is not passed, a 1x18 stand-in)
        self._nb = wp.array(self._neighbours[:1] if self.dense else self._neighbours, dtype=wp.int32, device=dev)
        self._bits = wp.array(self._mask, dtype=wp.int32, device=dev)
        self._off = wp.array(np.array(self._offsets, np.int32), dtype=wp.int32, device=dev)
        self._m = wp.array(self._mass, dtype=wp.float32, device=dev)
        self._fl = wp.array(self._flags, dtype=wp.int32, device=dev)
        self._g = wp.vec3(*self._gravity)
        self._zero = [wp.vec3(0.0, 0.0, 0.0)] * MAX_PULLS
        self._n = system.count

    def _launch(self, pull: np.ndarray) -> None:
        wp = self._wp
        x, xp, out = self._state
        pulls = self._zero if pull is self._zero_pull else [wp.vec3(*map(float, r)) for r in pull]
        wp.launch(self._kernel, dim=self._n, device="cpu",
                  inputs=[x, xp, out, self._nb, self._bits, self._off, int(self.dense), self._m, self._fl,
                          *self._scalars, self._g, *pulls])
        self._state = [out, x, xp]

    def _sync(self) -> None:
        self._wp.synchronize_device("cpu")

    def positions(self) -> np.ndarray:
        return self._state[0].numpy().astype(np.float32)

    def set_state(self, x: np.ndarray, x_prev: np.ndarray | None = None) -> None:
        wp = self._wp
        self._state[0] = wp.array(np.ascontiguousarray(x, np.float32), dtype=wp.vec3, device="cpu")
        self._state[1] = wp.array(np.ascontiguousarray(x if x_prev is None else x_prev, np.float32),
                                  dtype=wp.vec3, device="cpu")

    @property
    def threads(self) -> int:
        return 1


STEPPERS: dict[str, type[PeerStepper]] = {"taichi": TaichiStepper, "warp": WarpStepper}  # numba: imported lazily


def make_stepper(peer: str, system: SpringSystem, dt: float, loads: tuple[Load, ...] = ()) -> PeerStepper:
    """The stepper of ``peer`` (one of :data:`PEERS`) for ``system``.

    Raises:
        ValueError: unknown peer. ImportError: the peer package is not installed.
    """
    if peer not in PEERS:
        raise ValueError(f"peer must be one of {PEERS}, got {peer!r}")
    if peer == "numba":
        from deformgl.bench.peer_numba import NumbaStepper

        return NumbaStepper(system, dt, loads)
    return STEPPERS[peer](system, dt, loads)
