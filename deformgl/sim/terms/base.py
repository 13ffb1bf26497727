"""A physics term as one object: what every backend needs of it, declared in one place.

A :class:`Term` is one force of the model — a spring from each node to its rest position, a
per-cell elastic law — that acts on the nodes of a :class:`~deformgl.sim.springs.SpringSystem`
besides its springs (``SpringSystem.terms``). It declares, in its own module:

* its float64 force and energy (the NumPy reference, the equilibrium and growth checks),
* its stiffness ``K = -df/dx`` as a sparse matrix and its product (implicit Euler's
  ``A = M + dt C + dt^2 H``, the Jacobi and block-Jacobi preconditioners, the multigrid's Galerkin
  levels), and at rest its share of the dt bound (Gershgorin row sums and the exact highest
  frequency's product, :mod:`deformgl.sim.spectrum`),
* its GLSL chunk (:class:`GlslTerm`): the force of one node in the explicit gathers (the
  fragment backend's integrator stages, the foundation Verlet pass in the compact and the blocked
  layout, implicit Euler's right-hand side) and the implicit product's row and diagonal block,
  with the per-node tables and uniforms they read,
* its transform-feedback form (:meth:`Term.feedback_pairs` for a term linear in the positions, or
  a chunk of its own: :class:`FeedbackTerm`) and its XPBD form (:meth:`Term.xpbd`:
  :class:`~deformgl.sim.terms.constraints.TermConstraints`, with its GPU passes and
  :class:`~deformgl.sim.terms.constraints.XpbdChunk`), or a one-line refusal
  for each backend that has no form of it,
* what it will cost and refuse, known from the scene alone before its data exists
  (:class:`TermNeeds`: the memory budget's counts, the refusals a scene gets before the build),
  which the material that makes it returns (``material.term_needs``).

The backends loop over the system's terms and name none (:mod:`deformgl.sim.terms.glsl` composes
a pass's chunk list); a system compiles only the terms it holds. How to add a term:
docs/ARCHITECTURE.md, "Physics terms".

Units: positions in m, forces in N, stiffness in N/m, energy in J, mass in kg.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np
import scipy.sparse as sp

from deformgl.grid.nodes import NodeGrid

if TYPE_CHECKING:
    from collections.abc import Callable

    import moderngl

    from deformgl.sim.terms.constraints import TermConstraints

__all__ = ["FeedbackTerm", "GlslTerm", "NodeTable", "Term", "TermNeeds", "TermPass", "block_diagonal"]


@dataclass(frozen=True)
class NodeTable:
    """Per-node data a term's chunk reads: ``values`` (N, 4 * layers) float32, uploaded in the
    pass's node layout as a texture array of ``layers`` RGBA32F layers per node, sampled as
    ``uniform sampler2DArray <sampler>`` and read with ``term_table(<sampler>, layers, l, n)``
    (``shaders/lib/term_node.glsl``)."""

    sampler: str
    values: np.ndarray

    def __post_init__(self) -> None:
        v = np.asarray(self.values, np.float32)
        if v.ndim != 2 or v.shape[1] == 0 or v.shape[1] % 4:
            raise ValueError(f"NodeTable {self.sampler}: values of shape {v.shape}, expected (N, 4 * layers)")
        if not np.all(np.isfinite(v)):
            raise ValueError(f"NodeTable {self.sampler}: values not finite in float32")
        v.setflags(write=False)
        object.__setattr__(self, "values", v)

    @property
    def layers(self) -> int:
        """RGBA layers per node."""
        return int(self.values.shape[1] // 4)

    def layer(self, l: int) -> np.ndarray:
        """(N, 4) layer l."""
        return self.values[:, 4 * l: 4 * l + 4]


class TermPass(Protocol):
    """A term's own GPU pass (:attr:`GlslTerm.prepass`), owned and released by the backend that
    built it."""

    #: GPU bytes of its textures
    bytes_allocated: int

    def run(self, positions: "moderngl.Texture") -> None:
        """Render its outputs from the node positions (xyz, m) in the node layout."""

    def textures(self) -> "tuple[moderngl.Texture, ...]":
        """Its outputs, in the order of :attr:`GlslTerm.prepass_samplers`."""

    def release(self) -> None:
        """Release its GL objects (idempotent)."""


@dataclass(frozen=True)
class GlslTerm:
    """A term's GLSL form. ``source`` is the chunk's text (or ``file``, a path under ``shaders/``),
    included once per pass after ``lib/term_node.glsl``; it defines, for its ``prefix``::

        void PREFIX_force(inout vec3 f, TermNode n);            // adds the node's force, N
        void PREFIX_product(inout vec3 q, TermNode n, vec3 y);  // adds (K y)_i (implicit)
        void PREFIX_diagonal(inout vec3 d, inout vec3 off, inout float held, TermNode n);
            // adds K's 3x3 diagonal block of the node: d its diagonal, off (xy, xz, yz)

    ``PREFIX_product`` and ``PREFIX_diagonal`` only where ``implicit`` is True. A term that couples a
    node to its grid neighbours (``neighbours`` 18: the 6 axis and 12 face-diagonal neighbours of
    ``deformgl.grid.nodes.NEIGHBOUR_OFFSETS``; 24: and the 6 at 2h along the axes) defines besides::

        void PREFIX_begin(TermNode n);  // once per node, before its neighbours (both gathers)
        void PREFIX_neighbour(inout vec3 f, TermNode n, int j, vec3 d);  // d = x_n - x_j
        void PREFIX_neighbour_product(inout vec3 sk, inout vec3 dk, TermNode n, int j, vec3 dy);
            // (implicit) adds its (K y)_n share of neighbour j, dy = y_n - y_j, and its diagonal

    which the explicit gather calls with the springs, for each neighbour j in order (an absent one
    is the node itself: d = 0), and the implicit product with the springs' sums. A term that couples
    a node to any other (``others``) reads that node's state by its number: ``term_position(node)``,
    ``term_velocity(node)`` and, in its implicit functions, ``term_vector(node)`` (the vector y
    multiplied); the compact layouts' passes define them, the blocked layout does not run such a
    term (the foundation pass takes the compact layout for it). A term that reads the node's 3x3x3
    neighbourhood (``hood`` 1: its 18 face and edge neighbours, 2: and the 8 body diagonals; a
    per-cell term) finds the positions relative to the node in ``node_hood[27]`` (slot (dx + 1) +
    3 (dy + 1) + 9 (dz + 1); the node itself 0) when its force runs, filled by the pass
    (``shaders/lib/node_hood.glsl``, the springs' fetches kept); in its implicit functions
    ``hood_positions(n, p)`` and ``hood_vector(n, y)`` gather them and the vector multiplied.

    A ``TermNode`` holds the node's position ``x`` and velocity ``v`` at the evaluation state, its
    mass ``m``, where its tables are, ``bits`` (the 8 bits ``node_bits`` gave the node: one term per
    system may have them, stored in the node data's flag word, bits 6-13) and ``held`` (the implicit
    product passes: the flag a term with ``held`` set in ``PREFIX_diagonal``'s ``held`` at the step's
    start, e.g. "a barrier acts here"; 1 in the step's first pass). The implicit functions (and any
    function that calls ``term_vector``, ``hood_positions`` or ``hood_vector``, which only implicit
    Euler's passes define) go under ``#ifdef TERMS_IMPLICIT``. ``defines`` switch the chunk's
    variants (names starting with PREFIX in capitals). ``uniforms`` are set on every pass that
    compiles the chunk; their names, the tables' samplers and every function must start with
    ``prefix`` (or ``u_`` + prefix).

    A term whose force needs work shared by many nodes (a per-cell stress, a per-span rotation)
    gives ``prepass``: a factory ``prepass(ctx, layout) -> TermPass`` (``layout``: the node layout's
    uniforms, :func:`deformgl.grid.nodes.layout_uniforms`) of a GPU pass of its own that the
    explicit gathers run before each force evaluation on the evaluation state's positions, and
    whose output textures its chunk samples as ``prepass_samplers`` (bound after the tables). The
    passes that do not run it (the foundation pass, implicit Euler) refuse the term in one line.
    ``passes`` names the fragment shaders of its own passes (drawn with ``sim/fullscreen.vert``,
    no defines), which the shader pack compiles.
    """

    prefix: str
    source: str | None = None
    file: str | None = None
    implicit: bool = False
    neighbours: int = 0
    others: bool = False
    hood: int = 0
    held: bool = False
    defines: dict[str, object] = field(default_factory=dict)
    uniforms: dict[str, object] = field(default_factory=dict)
    tables: tuple[NodeTable, ...] = ()
    node_bits: np.ndarray | None = field(default=None, repr=False)
    prepass: "Callable[[moderngl.Context, dict[str, int]], TermPass] | None" = field(default=None, repr=False)
    prepass_samplers: tuple[str, ...] = ()
    passes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if (self.prepass is None) != (not self.prepass_samplers):
            raise ValueError(f"GlslTerm {self.prefix}: a pre-pass and its samplers come together")
        if (self.source is None) == (self.file is None):
            raise ValueError(f"GlslTerm {self.prefix}: give the chunk as source or as file, not both")
        if not self.prefix.isidentifier():
            raise ValueError(f"GlslTerm: prefix {self.prefix!r} is not a GLSL identifier")
        if self.neighbours not in (0, 18, 24):
            raise ValueError(f"GlslTerm {self.prefix}: neighbours must be 0, 18 or 24, got {self.neighbours}")
        if self.hood not in (0, 1, 2):
            raise ValueError(f"GlslTerm {self.prefix}: hood must be 0, 1 or 2, got {self.hood}")
        for name in self.defines:
            if not name.startswith(f"{self.prefix.upper()}_"):
                raise ValueError(f"GlslTerm {self.prefix}: define {name!r} must start with {self.prefix.upper()}_")
        if self.node_bits is not None:
            bits = np.asarray(self.node_bits)
            if bits.ndim != 1 or bits.dtype.kind not in "iu" or (len(bits) and (bits.min() < 0 or bits.max() > 255)):
                raise ValueError(f"GlslTerm {self.prefix}: node_bits must be (N,) integers in 0..255")
        for name in (*self.uniforms, *(t.sampler for t in self.tables), *self.prepass_samplers):
            if not name.startswith(f"u_{self.prefix}"):
                raise ValueError(f"GlslTerm {self.prefix}: uniform {name!r} must start with u_{self.prefix}")

    @property
    def include(self) -> str:
        """The include name of the chunk."""
        return self.file if self.file is not None else f"terms/{self.prefix}.glsl"


@dataclass(frozen=True)
class FeedbackTerm:
    """A term's transform-feedback form (:mod:`deformgl.sim.backends.feedback`): a chunk, the file
    ``file`` under ``shaders/``, that defines::

        void PREFIX_feedback(inout vec3 f, int i, vec3 xi);  // adds node i's force, N

    evaluated at the stage's state: ``xi`` the node's position, ``eval_x(j)`` (vec4, w the mass)
    and, with ``SPRING_DAMPING``, ``eval_v(j)`` any node's (the stage shader's hooks), and its
    per-node integer table ``table`` ((N, 4 * slots) int32, ``slots`` RGBA32I texels per node),
    sampled as ``uniform isampler2D <sampler>`` and read with ``texelFetch(<sampler>,
    node_slot_texel(i, slots, s), 0)`` (``shaders/lib/node_texel.glsl``). The backend composes the
    chunks into ``terms/feedback.glsl`` (:func:`deformgl.sim.terms.glsl.compose_feedback`), whose
    ``feedback_terms`` every stage calls under ``FEEDBACK_TERMS``. ``defines`` (names starting with
    PREFIX in capitals), ``uniforms`` and ``sampler`` as :class:`GlslTerm`'s; ``source``: the
    chunk's text, given inline under the include name ``file`` (a term outside the package), else
    the file is read. Float data travel bit-cast (``intBitsToFloat``). A term linear in the
    positions may give :meth:`Term.feedback_pairs` instead (no chunk)."""

    prefix: str
    file: str
    sampler: str
    table: np.ndarray
    defines: dict[str, object] = field(default_factory=dict)
    uniforms: dict[str, object] = field(default_factory=dict)
    source: str | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.table)
        if t.ndim != 2 or t.shape[1] == 0 or t.shape[1] % 4 or t.dtype.kind not in "iu":
            raise ValueError(f"FeedbackTerm {self.prefix}: table of shape {t.shape} and type {t.dtype}, "
                             f"expected (N, 4 * slots) integers")
        t = t.astype(np.int32)
        t.setflags(write=False)
        object.__setattr__(self, "table", t)
        for name in self.defines:
            if not name.startswith(f"{self.prefix.upper()}_"):
                raise ValueError(f"FeedbackTerm {self.prefix}: define {name!r} must start with {self.prefix.upper()}_")
        for name in (*self.uniforms, self.sampler):
            if not name.startswith(f"u_{self.prefix}"):
                raise ValueError(f"FeedbackTerm {self.prefix}: uniform {name!r} must start with u_{self.prefix}")

    @property
    def slots(self) -> int:
        """RGBA32I texels per node of its table."""
        return int(self.table.shape[1] // 4)

    def row_limit(self, limit: int) -> int:
        """The largest power of two of nodes per row whose table fits a texture ``limit`` texels wide."""
        width = 1
        while 2 * width * self.slots <= limit:
            width *= 2
        return width

    def image(self, node_row: int, rows: int) -> np.ndarray:
        """(rows, slots * node_row, 4) int32: the table's texture, node n's slot s at texel
        ``node_slot_texel(n, slots, s)`` (padding nodes: zeros)."""
        n = len(self.table)
        if n > node_row * rows:
            raise ValueError(f"FeedbackTerm {self.prefix}: {n} nodes do not fit {rows} rows of {node_row}")
        out = np.zeros((rows * node_row, 4 * self.slots), np.int32)
        out[:n] = self.table
        return out.reshape(rows, node_row * self.slots, 4)


@dataclass(frozen=True)
class TermNeeds:
    """What a term will cost and refuse, known from the scene alone, before its data exists: the
    memory estimate (:func:`deformgl.scene.budget.estimate`) sums these over the material's terms,
    and the scene checks refuse an integrator in ``refused`` before anything is built.

    Attributes:
        key: the scene key that turns the term on (``"material.<key>"``): refusals name it.
        host_bytes_per_node: host bytes per node its assembly adds at the peak (measured, with a margin).
        neighbours: the grid neighbours its GLSL form reads (:attr:`GlslTerm.neighbours`): 24 adds
            the neighbour table's 2h layer, which the estimate counts as the flexion lattice's (its
            2h springs too: an upper bound where the term has no 2h springs of its own).
        node_layers: RGBA32F layers per node its node tables add on the fragment backends.
        texel_bytes: bytes per node texel of its integer tables on the GPU backends.
        feedback_entries: list entries per node it adds on the transform-feedback backend (each
            one a spring end).
        refused: (integrator, why) pairs: the integrators with no form of it, each with the
            phrase a refusal says after the key.
    """

    key: str
    host_bytes_per_node: int = 0
    neighbours: int = 0
    node_layers: int = 0
    texel_bytes: int = 0
    feedback_entries: int = 0
    refused: tuple[tuple[str, str], ...] = ()

    def refusal(self, integrator: str) -> str | None:
        """Why ``integrator`` cannot run the term, or None."""
        return dict(self.refused).get(integrator)


class Term(ABC):
    """One physics term on the nodes (see the module docstring). Subclasses are immutable."""

    #: what the term is, in a user's words (messages name it: "rest anchors")
    name: str = "term"
    #: the grid neighbours its GLSL form reads (:attr:`GlslTerm.neighbours`): 0, 18 or 24
    neighbours: int = 0

    @abstractmethod
    def add_forces(self, x: np.ndarray, v: np.ndarray, t: float, out: np.ndarray) -> None:
        """Add the term's force on every node (N, 3), N, to ``out`` at positions x (m),
        velocities v (m/s), time t (s)."""

    @abstractmethod
    def energy(self, x: np.ndarray) -> float:
        """Its potential energy at x, J (0 for a term that stores none)."""

    @abstractmethod
    def stiffness(self, x: np.ndarray) -> sp.csr_matrix:
        """``K = -df/dx`` at x, (3N, 3N) N/m, symmetric positive semi-definite (the projected
        form where the exact one is indefinite): the implicit step's share of H."""

    def hessian(self, x: np.ndarray, geometric: str = "projected") -> sp.csr_matrix:
        """The implicit step's share of H at x for the springs' ``geometric`` option
        (:data:`deformgl.sim.implicit.GEOMETRIC`; the default: :meth:`stiffness`)."""
        return self.stiffness(x)

    def dt_stiffness(self, x_rest: np.ndarray, *, barrier: bool = False) -> sp.csr_matrix:
        """The stiffness the dt bound covers (:mod:`deformgl.sim.spectrum`, :mod:`deformgl.sim.limits`):
        K at rest; ``barrier``: the envelope of what the term stiffens to during a run, where that
        differs from rest (the default: K at rest in both)."""
        return self.stiffness(x_rest)

    def dt_product(self, x_rest: np.ndarray, dx: np.ndarray, *, barrier: bool = False) -> np.ndarray:
        """:meth:`dt_stiffness` times displacements dx (N, 3), N (the exact highest frequency's
        Lanczos iterations; override it where K need not be assembled)."""
        return (self.dt_stiffness(x_rest, barrier=barrier) @ np.asarray(dx, np.float64).reshape(-1)).reshape(-1, 3)

    def frequency_terms(self, x_rest: np.ndarray, *, barrier: bool = False) -> np.ndarray:
        """(N,) the Gershgorin row sums of :meth:`dt_stiffness`, N/m, the largest of each node's
        three rows (the dt bound's share, :func:`deformgl.sim.springs.max_angular_frequency`)."""
        k = abs(self.dt_stiffness(x_rest, barrier=barrier)).tocsr()
        rows = np.asarray(k.sum(axis=1)).reshape(-1, 3)
        return rows.max(axis=1)

    def describe(self) -> str:
        """The term as messages name it, with its constants ("rest anchors, k = 30 N/m")."""
        return self.name

    def limit_share(self, x_rest: np.ndarray, node: int, springs: float) -> str:
        """:meth:`describe` where the term is the larger part of ``node``'s stiffness in the dt
        bound (its :meth:`frequency_terms` with the envelope against ``springs``, the springs'
        ``2 sum k``, N/m), else "": the dt check's message names it (:mod:`deformgl.sim.limits`)."""
        return self.describe() if self.frequency_terms(x_rest, barrier=True)[node] > springs else ""

    def inversions(self, x: np.ndarray, grid: NodeGrid | None) -> tuple[int, str] | None:
        """The inversion census of the term's elements at positions x (N, 3), m: how many are
        inverted and a phrase naming the count and the first ("3 of 640 cells inverted (first:
        ...)"; "" for none), ``grid`` the system's node grid (to name an element by its place) or
        None; None for a term without elements (the run's census, ``RunResult.inverted_cells``)."""
        return None

    def acts(self) -> bool:
        """Whether the term exerts a force on its system (False: no pass compiles it, e.g. cells
        whose moduli are both 0)."""
        return True

    def glsl(self, grid: NodeGrid | None) -> GlslTerm | None:
        """The term's GLSL form on the system's node ``grid``, or None where it has none (the GPU
        backends refuse it)."""
        return None

    def feedback(self, grid: NodeGrid | None) -> FeedbackTerm | None:
        """The term's transform-feedback chunk on the system's node ``grid`` (ValueError, one line,
        where its data does not fit the grid), or None where it has none."""
        return None

    def xpbd(self, inverse_mass: np.ndarray) -> TermConstraints | None:
        """The term's XPBD form with the nodes' inverse masses (N,) 1/kg (0 at fixed nodes), or
        None where it has none (XPBD refuses it)."""
        return None

    def feedback_pairs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The transform-feedback form of a term linear in the positions, ``f_i = -sum_j c_ij (x_i
        - x_j)``: (rows, cols, c) with c in N/m, each pair in the list of its row (the backend
        stores them as springs of rest length 0); None where the term has none."""
        return None

    def refusal(self, backend: str) -> str | None:
        """Why ``backend`` ("feedback", "xpbd", "fragment", "implicit") cannot run this term, one
        phrase, or None. The default: the fragment backends run it where it has a GLSL form
        (implicit Euler where that form has its product: :func:`deformgl.sim.terms.glsl.pass_terms`
        checks); transform feedback where it has :meth:`feedback_pairs` or :meth:`feedback`; XPBD
        where it has :meth:`xpbd`."""
        if backend == "feedback" and (type(self).feedback is not Term.feedback or self.feedback_pairs() is not None):
            return None
        if backend == "xpbd" and type(self).xpbd is not Term.xpbd:
            return None
        if backend in ("feedback", "xpbd"):
            return f"{self.name} have no {'transform-feedback' if backend == 'feedback' else 'XPBD'} form"
        if type(self).glsl is Term.glsl:
            return f"{self.name} have no GLSL form"
        return None


def block_diagonal(blocks: np.ndarray) -> sp.csr_matrix:
    """(N, 3, 3) per-node blocks as a (3N, 3N) block-diagonal matrix (a term that couples each
    node only to itself)."""
    b = np.ascontiguousarray(blocks, np.float64)
    n = len(b)
    return sp.bsr_matrix((b, np.arange(n), np.arange(n + 1)), shape=(3 * n, 3 * n)).tocsr()
