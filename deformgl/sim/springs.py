"""An immutable mass-spring system built from explicit spring lists, and its forces (float64).

The reference backend of the five-integrator milestone (Movania & Feng 2012). Every spring is a
row of plain arrays (``i``, ``j``, ``rest_length``, ``stiffness``, ``damping``, ``spring_class``)
and every node a row of ``rest_positions``, ``mass``, ``fixed``, so a GPU backend can upload them
as buffers or textures one-to-one and evaluate :func:`forces` per node with the same formula.

Spring classes (Movania & Feng 2012, section 3, after Chen & Zhu [20]): structural springs link
a node to its immediate neighbours along the axes, shear springs the diagonal neighbours,
flexion (bend) springs a node to the node two steps away along an axis. Only what the scene
requires is modelled: a class whose stiffness is 0 is not built at all (no zero-force rows for a
GPU to loop over).

Units: stiffness ``k`` is the physical spring constant in N/m (deformgl's convention, see
docs/EQUATIONS.md: ``k = k_ij / 2`` of Mosegaard & Sørensen 2005, eq. 1, so a scene's stiffness
means the same in every backend and integrator, and in Movania & Feng's ``F = k (L - |d|) d/|d|``), damping in N*s/m, mass kg.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from deformgl.grid.nodes import N_STRUCTURAL, NodeGrid
from deformgl.sim.terms.volume.energy import CellVolumes
from deformgl.sim.terms.volume.term import VolumeTerm
from deformgl.sim.terms.bending import SheetBending
from deformgl.sim.scripted import Drag, Load
from deformgl.sim.terms.base import Term

STRUCTURAL = 0
SHEAR = 1
FLEXION = 2
CLASS_NAMES = ("structural", "shear", "flexion")
_AXES = np.eye(3, dtype=np.int64)
_REST_BLOCK = 1 << 16  # springs per block of the rest-length computation


def _frozen(a: ArrayLike, dtype: type, shape: tuple[int, ...], name: str) -> np.ndarray:
    arr: np.ndarray = np.array(a, dtype=dtype)  # a private copy: the caller's array keeps its flags
    if arr.shape != shape:
        raise ValueError(f"SpringSystem.{name}: shape {arr.shape}, expected {shape}")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        raise ValueError(f"SpringSystem.{name}: not finite")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class SpringSystem:
    """What does not change during a run: nodes, springs and the global force constants.

    Attributes:
        rest_positions: (N, 3) float64 world positions at rest (the initial state).
        mass: (N,) float64 kg, > 0.
        fixed: (N,) bool, nodes that keep their position exactly.
        i: (S,) int64 first node of each spring.
        j: (S,) int64 second node of each spring (i != j; each spring listed once).
        rest_length: (S,) float64 rest length L in world units.
        stiffness: (S,) float64 k in N/m, >= 0.
        damping: (S,) float64 spring damping c_s along the spring, N*s/m, >= 0.
        spring_class: (S,) int8, STRUCTURAL, SHEAR or FLEXION (triangle-mesh edges: STRUCTURAL).
        velocity_damping: global damping c in N*s/m (force -c v on every node).
        mass_damping: Rayleigh mass-proportional damping alpha in 1/s (force -alpha m_i v_i on
            node i; :mod:`deformgl.sim.materials` sets it from a material).
        gravity: (3,) float64 m/s^2.
        wind: (3,) float64 air velocity in m/s.
        wind_drag: N*s/m, linear drag toward the air velocity: F = wind_drag * (wind - v).
        spacing: the system's length scale in world units (grid spacing h; the mean edge length
            of a triangle mesh); the default convergence threshold is 0.001 * spacing.
        grid: the node grid the system was built from (:func:`from_grid`, :func:`cloth`; node
            order is the grid's), or None (a triangle mesh, or springs listed by hand). The
            fragment backend needs it.
        material: the :mod:`deformgl.sim.materials` material the springs were assembled from
            (:func:`~deformgl.sim.materials.lattice_system`), or None (per-spring constants); the
            dt check words its refusal in the material's terms.
        cells: the volumetric term of the grid's full cells (:mod:`deformgl.sim.terms.volume.energy`: any
            Poisson's ratio, the inversion barrier), or None (springs only).
        bending: a sheet's bending term (:mod:`deformgl.sim.terms.bending`: the plate's D in N·m,
            ``f = -B x``), or None.
        extra_terms: further physics terms (:class:`deformgl.sim.terms.Term`), each one object that
            every backend runs through its declared forms (or refuses in one line naming it);
            :attr:`terms` is every term of the system, the cells' and a sheet's bending first.
    """

    rest_positions: np.ndarray
    mass: np.ndarray
    fixed: np.ndarray
    i: np.ndarray
    j: np.ndarray
    rest_length: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    spring_class: np.ndarray
    velocity_damping: float = 0.0
    mass_damping: float = 0.0
    gravity: np.ndarray = field(default_factory=lambda: np.array([0.0, -9.81, 0.0]))
    wind: np.ndarray = field(default_factory=lambda: np.zeros(3))
    wind_drag: float = 0.0
    spacing: float = 1.0
    grid: NodeGrid | None = None
    material: object = None
    cells: CellVolumes | None = None
    bending: SheetBending | None = None
    extra_terms: tuple[Term, ...] = ()

    def __post_init__(self) -> None:
        n = np.shape(self.rest_positions)[0]
        s = np.shape(self.i)[0]
        specs = {"rest_positions": (np.float64, (n, 3)), "mass": (np.float64, (n,)),
                 "fixed": (np.bool_, (n,)), "i": (np.int64, (s,)), "j": (np.int64, (s,)),
                 "rest_length": (np.float64, (s,)), "stiffness": (np.float64, (s,)),
                 "damping": (np.float64, (s,)), "spring_class": (np.int8, (s,)),
                 "gravity": (np.float64, (3,)), "wind": (np.float64, (3,))}
        for name, (dtype, shape) in specs.items():
            object.__setattr__(self, name, _frozen(getattr(self, name), dtype, shape, name))
        if np.any(self.mass <= 0):
            raise ValueError("SpringSystem.mass: every node needs a positive mass")
        if s and (min(self.i.min(), self.j.min()) < 0 or max(self.i.max(), self.j.max()) >= n):
            raise ValueError(f"SpringSystem.i/j: node numbers outside 0..{n - 1}")
        if np.any(self.i == self.j):
            raise ValueError("SpringSystem.i/j: a spring connects a node to itself")
        for name in ("rest_length", "stiffness", "damping"):
            if np.any(getattr(self, name) < 0):
                raise ValueError(f"SpringSystem.{name}: negative values")
        if np.any((self.spring_class < STRUCTURAL) | (self.spring_class > FLEXION)):
            raise ValueError("SpringSystem.spring_class: values outside 0..2")
        if min(self.velocity_damping, self.mass_damping, self.wind_drag) < 0 or not self.spacing > 0:
            raise ValueError("SpringSystem: velocity_damping, mass_damping and wind_drag >= 0, spacing > 0")
        if self.grid is not None and self.grid.count != n:
            raise ValueError(f"SpringSystem.grid: {self.grid.count} nodes, the system {n}")
        if self.cells is not None and self.cells.count and (self.cells.corners.min() < 0
                                                            or self.cells.corners.max() >= n):
            raise ValueError(f"SpringSystem.cells: corner node numbers outside 0..{n - 1}")
        if self.bending is not None and self.bending.count != n:
            raise ValueError(f"SpringSystem.bending: {self.bending.count} nodes, the system {n}")
        object.__setattr__(self, "extra_terms", tuple(self.extra_terms))
        for k, term in enumerate(self.extra_terms):
            if not isinstance(term, Term):
                raise ValueError(f"SpringSystem.extra_terms[{k}]: {type(term).__name__} is not a deformgl.sim.terms.Term")
            if isinstance(term, (VolumeTerm, SheetBending)):
                field_name = "cells=term.cells" if isinstance(term, VolumeTerm) else "bending=term"
                raise ValueError(f"SpringSystem.extra_terms[{k}]: {term.name} go in the system's own field "
                                 f"({field_name})")
        # the cells' volumetric term and a sheet's bending are terms too, first (the backends sum
        # in the terms' order)
        built_in = ((VolumeTerm(self.cells),) if self.cells is not None else ()) + (
            (self.bending,) if self.bending is not None else ())
        object.__setattr__(self, "_terms", built_in + self.extra_terms)

    @property
    def terms(self) -> tuple[Term, ...]:
        """Every physics term of the system, in the order the backends sum them: the cells'
        volumetric term (``cells``), a sheet's bending (``bending``), then :attr:`extra_terms`."""
        terms: tuple[Term, ...] = self.__dict__["_terms"]
        return terms

    @property
    def count(self) -> int:
        """Number of nodes N."""
        return int(self.rest_positions.shape[0])

    @property
    def spring_count(self) -> int:
        """Number of springs S."""
        return int(self.i.shape[0])

    def class_counts(self) -> dict[str, int]:
        """Springs per class, e.g. ``{"structural": 54, "shear": 72, "flexion": 27}``."""
        counts = np.bincount(self.spring_class, minlength=len(CLASS_NAMES))
        return {name: int(c) for name, c in zip(CLASS_NAMES, counts)}


def _node_array(value: float | ArrayLike, n: int, dtype: type) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, dtype=dtype), (n,)).copy()


def _assemble(x0: np.ndarray, pairs: np.ndarray, classes: np.ndarray,
              class_k: tuple[float, ...], class_c: tuple[float, ...], *, mass: float | ArrayLike,
              fixed: ArrayLike | None, spacing: float, velocity_damping: float,
              gravity: ArrayLike, wind: ArrayLike, wind_drag: float,
              grid: NodeGrid | None = None) -> SpringSystem:
    """A SpringSystem from rest positions and candidate springs; classes with k = 0 are dropped."""
    k_of_class = np.asarray(class_k, dtype=np.float64)
    keep = k_of_class[classes] > 0  # model only what the scene requires
    if not keep.all():
        pairs, classes = pairs[keep], classes[keep]
    del keep
    order = np.argsort(classes, kind="stable")  # structural first, then shear, then flexion
    pairs, classes = pairs[order], classes[order]
    del order
    # Rest length from the rest positions with the same arithmetic as forces(): the rest state
    # is then an exact equilibrium (L - |d| == 0 bit for bit). Row by row, so in blocks (the
    # same values) to keep the (S, 3) temporaries small.
    rest = np.empty(len(pairs), dtype=np.float64)
    for start in range(0, len(pairs), _REST_BLOCK):
        p = pairs[start:start + _REST_BLOCK]
        rest[start:start + len(p)] = np.linalg.norm(x0[p[:, 0]] - x0[p[:, 1]], axis=1)
    n = len(x0)
    # SpringSystem copies every array it is given (_frozen): hand it contiguous columns and
    # drop ours right after, so only one copy of each (S,) array outlives the call.
    i, j = np.ascontiguousarray(pairs[:, 0]), np.ascontiguousarray(pairs[:, 1])
    del pairs
    return SpringSystem(
        rest_positions=x0, mass=_node_array(mass, n, np.float64),
        fixed=np.zeros(n, bool) if fixed is None else _node_array(fixed, n, np.bool_),
        i=i, j=j, rest_length=rest, stiffness=k_of_class[classes],
        damping=np.asarray(class_c, dtype=np.float64)[classes], spring_class=classes,
        velocity_damping=float(velocity_damping), gravity=np.asarray(gravity, float),
        wind=np.asarray(wind, float), wind_drag=float(wind_drag), spacing=float(spacing), grid=grid)


def from_grid(grid: NodeGrid, *, k_structural: float, k_shear: float, k_flexion: float = 0.0,
              damping_structural: float = 0.0, damping_shear: float = 0.0,
              damping_flexion: float = 0.0, mass: float | ArrayLike = 1.0,
              fixed: ArrayLike | None = None, velocity_damping: float = 0.0,
              gravity: ArrayLike = (0.0, -9.81, 0.0), wind: ArrayLike = (0.0, 0.0, 0.0),
              wind_drag: float = 0.0) -> SpringSystem:
    """Springs of a node grid, each once: 6 structural (distance h), 12 shear (h*sqrt(2)) and
    6 flexion (2h along an axis) neighbours per node where they exist.

    Structural and shear springs are the 18 implicit neighbours of Mosegaard & Sørensen 2005
    (section 3.1, ``grid.NEIGHBOUR_OFFSETS``); flexion springs follow Movania & Feng 2012
    (section 3: "structural springs connected to the nodes one node away"), so a flexion spring
    is built only where both ends *and the node between them* exist: it never bridges a hole.

    Args:
        grid: the node grid (node order and rest positions are the grid's).
        k_structural, k_shear, k_flexion: N/m per class; a class with 0 is not built.
        damping_structural, damping_shear, damping_flexion: spring damping per class, N*s/m.
        mass: kg per node, a scalar or (N,).
        fixed: (N,) bool or None.
        velocity_damping, gravity, wind, wind_drag: see :class:`SpringSystem`.
    """
    # Candidates are built in the grid's (int32) node numbers and widened to int64 once; the
    # per-node intermediates are dropped as soon as they are used (memory: issue 14).
    own: np.ndarray = np.arange(grid.count, dtype=grid.index_dtype)
    nb = grid.neighbours                                   # (N, 18), -1 where absent
    rows, cols = np.nonzero(nb > own[:, None])              # each pair once (the larger number)
    del own
    near = np.empty((len(rows), 2), dtype=np.int64)
    near[:, 0], near[:, 1] = rows, nb[rows, cols]
    near_class = np.where(cols < N_STRUCTURAL, STRUCTURAL, SHEAR).astype(np.int8)
    del rows, cols
    padded = np.pad(grid.index, 2, constant_values=-1)
    base = grid.ijk[:, None, :] + 2                         # (N, 1, 3) in the padded grid
    axes = _AXES.astype(base.dtype)
    mid = padded[tuple(np.moveaxis(base + axes, -1, 0))]        # (N, 3): node at +1 along axis
    far = padded[tuple(np.moveaxis(base + 2 * axes, -1, 0))]    # (N, 3): node at +2 along axis
    del padded, base
    rows, axes_of = np.nonzero((mid >= 0) & (far >= 0))
    flex = np.empty((len(rows), 2), dtype=np.int64)
    flex[:, 0], flex[:, 1] = rows, far[rows, axes_of]
    del mid, far, rows, axes_of
    pairs = np.concatenate([near, flex])
    classes = np.concatenate([near_class, np.full(len(flex), FLEXION, np.int8)])
    del near, flex, near_class
    return _assemble(grid.rest_positions, pairs, classes,  # (SpringSystem copies it)
                     (k_structural, k_shear, k_flexion),
                     (damping_structural, damping_shear, damping_flexion), mass=mass,
                     fixed=fixed, spacing=grid.spacing, velocity_damping=velocity_damping,
                     gravity=gravity, wind=wind, wind_drag=wind_drag, grid=grid)


def cloth(nx: int, nz: int, spacing: float, *, k_structural: float, k_shear: float,
          k_flexion: float = 0.0, origin: ArrayLike = (0.0, 0.0, 0.0),
          **options: object) -> SpringSystem:
    """A cloth of nx x nz nodes in the xz-plane (y = origin y): 4 structural, 4 shear diagonal
    and 4 flexion neighbours per inner node (Movania & Feng 2012, section 3 and section 5).

    Node (a, b) sits at ``origin + spacing * (a, 0, b)`` and has number ``a * nz + b``. Built as a
    one-node-thick :class:`NodeGrid`, so the springs are exactly those of :func:`from_grid`.

    Args:
        nx, nz: nodes along x and z (>= 1).
        spacing: distance of neighbouring nodes.
        k_structural, k_shear, k_flexion: N/m per class; a class with 0 is not built.
        origin: position of node (0, 0).
        **options: the remaining keyword arguments of :func:`from_grid`.
    """
    if nx < 1 or nz < 1:
        raise ValueError(f"cloth: {nx}x{nz} nodes")
    grid = NodeGrid(np.array(origin, dtype=np.float64), float(spacing),
                    np.ones((nx, 1, nz), dtype=bool))
    return from_grid(grid, k_structural=k_structural, k_shear=k_shear, k_flexion=k_flexion,
                     **options)  # type: ignore[arg-type]


def from_triangle_mesh(vertices: ArrayLike, faces: ArrayLike, *, stiffness: float,
                       damping: float = 0.0, mass: float | ArrayLike = 1.0,
                       fixed: ArrayLike | None = None, velocity_damping: float = 0.0,
                       gravity: ArrayLike = (0.0, -9.81, 0.0), wind: ArrayLike = (0.0, 0.0, 0.0),
                       wind_drag: float = 0.0) -> SpringSystem:
    """One STRUCTURAL spring along each unique edge of a triangle mesh (the non-grid spring mesh).

    Args:
        vertices: (N, 3) rest positions.
        faces: (F, 3) vertex numbers; edges of degenerate faces that join a vertex to itself are
            dropped.
        stiffness: N/m of every edge spring (> 0; 0 builds no springs).
        damping: spring damping, N*s/m.
        mass, fixed, velocity_damping, gravity, wind, wind_drag: see :func:`from_grid`.

    Raises:
        ValueError: faces not (F, 3) or naming vertices that do not exist.
    """
    x0 = np.array(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"from_triangle_mesh: faces of shape {f.shape}, expected (F, 3)")
    if f.size and (f.min() < 0 or f.max() >= len(x0)):
        raise ValueError(f"from_triangle_mesh: faces name vertices outside 0..{len(x0) - 1}")
    edges = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    edges = np.unique(edges[edges[:, 0] != edges[:, 1]], axis=0).reshape(-1, 2)
    lengths = np.linalg.norm(x0[edges[:, 0]] - x0[edges[:, 1]], axis=1)
    spacing = float(lengths.mean()) if len(lengths) and lengths.mean() > 0 else 1.0
    return _assemble(x0, edges, np.zeros(len(edges), np.int8), (stiffness, 0.0, 0.0),
                     (damping, 0.0, 0.0), mass=mass, fixed=fixed, spacing=spacing,
                     velocity_damping=velocity_damping, gravity=gravity, wind=wind,
                     wind_drag=wind_drag)


def forces(system: SpringSystem, x: np.ndarray, v: np.ndarray, t: float,
           drags: tuple[Drag, ...] = (), loads: tuple[Load, ...] = ()) -> np.ndarray:
    """Total force on every node (fixed nodes included; the integrators ignore theirs).

    Per spring (i, j) with ``d = x_i - x_j``, ``u = d/|d|`` (u = 0 for a zero-length spring, so
    it pulls nothing and never gives NaN), the force on i (and its negative on j) is

    * elastic: ``k (L - |d|) u`` (Movania & Feng 2012 eq. 2; docs/EQUATIONS.md ``F_j``),
    * spring damping along the spring: ``-c_s ((v_i - v_j) . u) u``;

    per full cell (``system.cells``): the volumetric term and the corner barrier of
    :func:`deformgl.sim.terms.volume.energy.volume_forces`; each of ``system.terms`` (a sheet's bending ``-B x``
    among them) :meth:`~deformgl.sim.terms.Term.add_forces`;
    per node: gravity ``m g``, wind ``wind_drag (wind - v)``, global damping ``-c v``
    (Movania & Feng 2012 eq. 1) and Rayleigh mass damping ``-alpha m v``, each drag's ``k_d (target(t) - x)`` and each load's
    ``force(t)`` on its nodes (per kg: times each node's mass).

    Args:
        system: the spring system.
        x: (N, 3) positions.
        v: (N, 3) velocities.
        t: time in s (the drag targets are evaluated at t).
        drags: scripted drags.
        loads: scripted per-node forces.

    Returns:
        (N, 3) float64 force in N.
    """
    # The same arithmetic in place (no second (S, 3) array per step of the formula) and the
    # sums one component at a time: the values and the order of every sum are unchanged.
    d = x[system.i]
    d -= x[system.j]
    length = np.linalg.norm(d, axis=1)
    d /= np.where(length > 0, length, 1.0)[:, None]  # d = 0 -> u = 0
    u = d
    dv = v[system.i]
    dv -= v[system.j]
    along = np.einsum("sk,sk->s", dv, u)
    del dv
    length = np.subtract(system.rest_length, length, out=length)
    scale = system.stiffness * length
    del length
    scale -= system.damping * along
    del along
    u *= scale[:, None]
    f = u                                                 # force on i of each spring, (S, 3)
    del scale
    ends = np.concatenate([system.i, system.j])
    n = system.count
    total = np.empty((n, 3), dtype=np.float64)
    for c in range(3):
        fc = f[:, c]
        total[:, c] = np.bincount(ends, weights=np.concatenate([fc, -fc]), minlength=n)
    del ends, f, u
    for term in system.terms:
        term.add_forces(x, v, t, total)
    total += (system.mass[:, None] * system.gravity + system.wind_drag * (system.wind - v)
              - (system.velocity_damping + system.mass_damping * system.mass)[:, None] * v)
    for drag in drags:
        total[drag.node] += drag.stiffness * (np.asarray(drag.target(t), float) - x[drag.node])
    for load in loads:
        total[load.nodes] += load.node_forces(t, system.mass)
    return total


@dataclass(frozen=True)
class FrequencyBound:
    """Bound of the highest angular frequency of the linearised undamped system.

    Attributes:
        omega: rad/s, w_max <= omega.
        node: the free node whose ``2 sum_j k_ij / m_i`` is largest (-1 without free nodes).
        spring: the stiffest spring at that node (-1 if it has none).
    """

    omega: float
    node: int
    spring: int


def max_angular_frequency(system: SpringSystem, *, barrier: bool = False) -> FrequencyBound:
    """``w_max^2 <= max_i 2 sum_j k_ij / m_i`` over the free nodes (STYLE.md; Gershgorin).

    Proof sketch: ``x^T K x = sum_s k_s ((x_i - x_j) . u_s)^2 <= sum_s 2 k_s (|x_i|^2 + |x_j|^2)``
    and fixed nodes have x = 0, so the Rayleigh quotient ``x^T K x / x^T M x`` is at most the
    largest ``2 sum_j k_ij / m_i`` over free nodes. Stretched springs (L < |d|) keep it: their
    geometric stiffness ``k (1 - L/|d|)`` across the spring is below k. Drags are not included
    (a drag of stiffness k_d adds ``2 k_d / m`` at its node). Each of ``system.terms`` adds its
    :meth:`~deformgl.sim.terms.Term.frequency_terms` (``barrier``: with the envelope of what it
    stiffens to in a run): the cells' centre term ``1.5 kappa h`` per cell at the node and their
    inversion barrier, inactive at rest, only with ``barrier``
    (:func:`deformgl.sim.terms.volume.energy.frequency_terms`); a sheet's bending its row sum ``sum_j |B_ij|``.
    """
    n = system.count
    ksum = (np.bincount(system.i, weights=system.stiffness, minlength=n)
            + np.bincount(system.j, weights=system.stiffness, minlength=n))
    term_rows: np.ndarray | float = 0.0
    for term in system.terms:
        term_rows = term_rows + term.frequency_terms(system.rest_positions, barrier=barrier)
    bound = np.where(system.fixed, -1.0, (2.0 * ksum + term_rows) / system.mass)
    if n == 0 or bound.max() < 0:
        return FrequencyBound(0.0, -1, -1)
    node = int(np.argmax(bound))
    at_node = np.nonzero((system.i == node) | (system.j == node))[0]
    spring = int(at_node[np.argmax(system.stiffness[at_node])]) if len(at_node) else -1
    return FrequencyBound(float(np.sqrt(bound[node])), node, spring)
