"""A trilinear scene graph as plain data (Knuth, Kohlhammer & Kuijper, section 4): what a
scene-graph file holds (:mod:`deformgl.trilinear.graphfile` reads and writes it, one to one) and
what the Python API builds. :mod:`deformgl.trilinear.graphbuild` turns it into the runtime nodes
of :mod:`deformgl.trilinear.graph_nodes` and renders it.

A :class:`SceneGraph` names its meshes (:class:`GraphMesh`), its deformations (:class:`Deformation`,
with optional keyframes of their parameters) and its nodes (:class:`NodeSpec`); a node lists its
children by name, so one child under many parents is drawn once per parent (instancing), and an
``array`` transform repeats its children over a lattice of translations. Depth is unbounded: the
nesting lives in the names, not in TOML tables. Units: metres, radians unless a key says degrees.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
import numpy as np

from deformgl.errors import InputError
from deformgl.trilinear.cuboid import Function
from deformgl.trilinear.deformations import Helix, Taper, TorusWrap, Twist

#: Built-in shapes and their parameters with defaults (None: required), see shapes.py.
SHAPES: dict[str, dict[str, float | int | None]] = {
    "tube": {"length": None, "radius": None, "sections": 12, "rings": 16},
    "sphere": {"radius": None, "segments": 16, "rings": 9},
    "tile": {"resolution": 40},
}
#: Integer shape parameters.
SHAPE_INTEGERS = ("sections", "rings", "segments", "resolution")

#: Named deformations and their parameters (all required, floats): torus wrap (figures 1, 9),
#: twist (``rate`` rad/m about z), taper (``rate`` 1/m), helix (``radius`` m, ``pitch`` m per
#: turn), bend (``angle`` rad over ``length`` m of the x axis, in the x-z plane).
DEFORMATIONS: dict[str, tuple[str, ...]] = {
    "torus": ("length", "width", "major", "minor"),
    "twist": ("rate",),
    "taper": ("rate",),
    "helix": ("radius", "pitch"),
    "bend": ("angle", "length"),
}

#: Most leaves (mesh instances) a graph may draw, and most lattice points of one grid.
MAX_LEAVES = 1 << 21
#: Most node instances a root may expand to: every node counted once under each path from the root
#: (each parent, each array instance), whether or not a mesh is below it: what building and
#: composing the graph walk. An array instance is a node (its translation) over the children;
#: four per drawn mesh instance let MAX_LEAVES of them have a few nodes each above them.
MAX_EXPANDED = 4 * MAX_LEAVES
MAX_LATTICE_POINTS = 1 << 22
#: Deepest graph (nodes on the longest path from a root to a leaf).
MAX_GRAPH_DEPTH = 10000

#: Transform kinds of a node (at most one per node).
TRANSFORM_KINDS = ("matrix", "trs", "cuboid", "coefficients", "grid", "array", "attach")


@dataclass(frozen=True)
class BendAngle:
    """Bends the x axis by ``angle`` radians over ``length`` metres around a circle in the x-z
    plane (centre above, at z = length / angle); ``angle = 0`` is the identity, so a bend can be
    keyframed from straight."""

    angle: float
    length: float

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        k = self.angle / self.length  # curvature, 1/m
        if k == 0.0:
            return p.copy()
        a = p[:, 0] * k
        r = 1.0 / k - p[:, 2]
        return np.stack([r * np.sin(a), p[:, 1], 1.0 / k - r * np.cos(a)], 1)


@dataclass
class GraphMesh:
    """Geometry: a built-in ``shape`` (:data:`SHAPES`) with ``params``, or a mesh ``file``
    (any trimesh-readable format; relative to the scene-graph file)."""

    shape: str | None = None
    params: dict[str, float] = field(default_factory=dict)
    file: str | None = None

    def __post_init__(self) -> None:
        if (self.shape is None) == (self.file is None):
            raise InputError("a mesh needs exactly one of shape and file")
        if self.shape is not None:
            if self.shape not in SHAPES:
                raise InputError(f"unknown shape {self.shape!r}; choose one of {', '.join(SHAPES)}")
            defaults = SHAPES[self.shape]
            unknown = set(self.params) - set(defaults)
            if unknown:
                raise InputError(f"shape {self.shape!r} has no parameter {sorted(unknown)[0]!r}")
            for k, v in defaults.items():
                if k not in self.params:
                    if v is None:
                        raise InputError(f"shape {self.shape!r} needs {k!r}")
                    self.params[k] = v


@dataclass
class Keyframe:
    """One keyframe: parameter values at time ``t`` (seconds)."""

    t: float
    values: dict[str, float]


@dataclass
class Deformation:
    """A named deformation (:data:`DEFORMATIONS`) with its parameters, and optional keyframes
    (times increasing) of some of them, linearly interpolated and held outside their range."""

    kind: str
    params: dict[str, float]
    keys: list[Keyframe] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.kind not in DEFORMATIONS:
            raise InputError(f"unknown deformation {self.kind!r}; choose one of {', '.join(DEFORMATIONS)}")
        names = DEFORMATIONS[self.kind]
        for k in names:
            if k not in self.params:
                raise InputError(f"deformation {self.kind!r} needs {k!r}")
        for k in self.params:
            if k not in names:
                raise InputError(f"deformation {self.kind!r} has no parameter {k!r}")
        times = [key.t for key in self.keys]
        if any(b <= a for a, b in zip(times, times[1:])):
            raise InputError(f"deformation {self.kind!r}: keyframe times must increase, got {times}")
        for key in self.keys:
            for k in key.values:
                if k not in names:
                    raise InputError(f"deformation {self.kind!r}: a keyframe sets unknown parameter {k!r}")

    def values_at(self, t: float) -> dict[str, float]:
        """The parameters at time ``t`` (s): each keyframed one interpolated linearly."""
        out = dict(self.params)
        for name in {k for key in self.keys for k in key.values}:
            ts = np.array([key.t for key in self.keys if name in key.values])
            vs = np.array([key.values[name] for key in self.keys if name in key.values])
            out[name] = float(np.interp(float(t), ts, vs))
        return out

    def function(self, t: float = 0.0) -> Function:
        """The deformation at time ``t`` as a function of (N, 3) points."""
        v = self.values_at(t)
        if self.kind == "torus":
            return TorusWrap(length=v["length"], width=v["width"], major=v["major"], minor=v["minor"])
        if self.kind == "twist":
            return Twist(v["rate"])
        if self.kind == "taper":
            return Taper(v["rate"])
        if self.kind == "helix":
            return Helix(radius=v["radius"], pitch=v["pitch"])
        return BendAngle(angle=v["angle"], length=v["length"])


@dataclass
class GraphTransform:
    """A node's transform; ``kind`` (:data:`TRANSFORM_KINDS`) says which fields are used:

    * ``matrix``: ``matrix`` a 4x4 affine matrix;
    * ``trs``: ``translate`` (3,), ``rotate`` (axis (3,), ``degrees``), ``scale`` (3,), applied
      scale first, translation last;
    * ``cuboid``: ``corners`` (8, 3) in Knuth, Kohlhammer & Kuijper, eq. 1 order over ``box``;
    * ``coefficients``: ``coefficients`` the 3x8 matrix C of eq. 2-4 over ``box``;
    * ``grid``: ``deformation`` (a name) sampled on ``cells`` over ``box`` (section 3.3), or the
      lattice from ``file`` (a ``.npy`` of shape (nx+1, ny+1, nz+1, 3)) over ``box``;
      ``box = None`` is the bounding box of the children's content;
    * ``array``: instances translated by ``offset + (i, j, k) * step`` for (i, j, k) < ``count``,
      each instance ``(i + j + k) mod len(colours)`` coloured from ``colours`` when given; with
      ``tangent_of`` (a deformation) each instance is placed instead by the tangent affine map of
      that deformation at the instance's ``tangent_at`` point (a linear scene graph's placement);
    * ``attach``: anchors on a simulated, mapped body (section 5) along the path ``start`` ->
      ``end`` (bounding-box fractions), ``anchors`` of them; the children's box
      [0, 1] x [-0.5, 0.5] x [0, 1] is laid along the path, ``width`` across and ``height`` up
      (both in bounding-box diagonals of the body).
    """

    kind: str
    matrix: np.ndarray | None = None
    translate: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    degrees: float = 0.0
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    corners: np.ndarray | None = None
    coefficients: np.ndarray | None = None
    box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    deformation: str | None = None
    cells: tuple[int, int, int] = (1, 1, 1)
    file: str | None = None
    count: tuple[int, int, int] = (1, 1, 1)
    step: tuple[float, float, float] = (0.0, 0.0, 0.0)
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    colours: tuple[tuple[float, float, float], ...] = ()
    tangent_of: str | None = None
    tangent_at: tuple[float, float, float] = (0.0, 0.0, 0.0)
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    end: tuple[float, float, float] = (1.0, 1.0, 1.0)
    anchors: int = 8
    width: float = 0.02
    height: float = 0.02

    def __post_init__(self) -> None:
        if self.kind not in TRANSFORM_KINDS:
            raise InputError(f"unknown transform kind {self.kind!r}; choose one of {', '.join(TRANSFORM_KINDS)}")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, GraphTransform):
            return NotImplemented
        for f in dataclasses.fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if a is None or b is None or not np.array_equal(a, b):
                    return False
            elif a != b:
                return False
        return True

    def trs_matrix(self) -> np.ndarray:
        """The 4x4 matrix of a ``trs`` transform: translate @ rotate @ scale."""
        m = np.identity(4)
        axis = np.asarray(self.axis, dtype=np.float64)
        n = float(np.linalg.norm(axis))
        if n == 0.0:
            raise InputError("rotate: the axis must not be zero")
        k = axis / n
        a = np.radians(self.degrees)
        cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        rot = np.identity(3) + np.sin(a) * cross + (1.0 - np.cos(a)) * cross @ cross  # Rodrigues
        m[:3, :3] = rot * np.asarray(self.scale, dtype=np.float64)[None, :]
        m[:3, 3] = self.translate
        return m


@dataclass
class NodeSpec:
    """A node: a transform (or None: a group), children by name, or a ``mesh`` (a leaf).

    ``colour`` (RGB in [0, 1]) and ``normals`` (``"direct"`` / ``"tangent"``, section 4.2) are
    inherited by the leaves below unless they set their own.
    """

    transform: GraphTransform | None = None
    children: list[str] = field(default_factory=list)
    mesh: str | None = None
    colour: tuple[float, float, float] | None = None
    normals: str | None = None


@dataclass
class GraphView:
    """The camera and image: ``size`` (width, height) pixels, ``azimuth`` / ``elevation``
    (degrees), ``distance`` (bounding-box diagonals), MSAA ``samples``, ``background`` RGB."""

    size: tuple[int, int] = (960, 480)
    azimuth: float = 20.0
    elevation: float = 35.0
    distance: float = 1.25
    samples: int = 4
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)


@dataclass
class GraphBody:
    """The simulated body that ``attach`` transforms are anchored on: a simulation scene file
    (relative to the scene-graph file), simulated and drawn with the graph (section 5)."""

    scene: str


@dataclass
class SceneGraph:
    """A whole scene-graph file: ``roots`` (one, or two drawn side by side with one camera),
    meshes, deformations, nodes, the view, an optional output PNG, an optional body."""

    roots: list[str]
    nodes: dict[str, NodeSpec]
    meshes: dict[str, GraphMesh] = field(default_factory=dict)
    deformations: dict[str, Deformation] = field(default_factory=dict)
    view: GraphView = field(default_factory=GraphView)
    output: str | None = None
    body: GraphBody | None = None
    description: str = ""

    #: Nodes on the longest path from a root to a leaf, set by :meth:`check`.
    depth: int = field(default=0, init=False, repr=False, compare=False)

    def view_check(self) -> None:
        """The camera's ranges, those of a simulation scene's ``render.camera``: beyond them the
        framing is degenerate (near = far in float64 at a distance of 1e20 diagonals, a view
        straight down the up axis at 90 degrees) or the content smaller than a pixel."""
        v = self.view
        for key, value, lo, hi, unit in (("azimuth", v.azimuth, -360.0, 360.0, " degrees"),
                                         ("elevation", v.elevation, -89.0, 89.0, " degrees"),
                                         ("distance", v.distance, 1e-3, 1e3, " box diagonals")):
            if not (isinstance(value, (int, float)) and lo <= value <= hi):
                raise InputError(f"view.{key}: must be in [{lo:g}, {hi:g}]{unit}, got {value!r}")

    def check(self) -> SceneGraph:
        """Refuse dangling names, a leaf with children, cycles and graphs too large to build
        (:data:`MAX_LEAVES`, :data:`MAX_EXPANDED`, :data:`MAX_GRAPH_DEPTH`, :data:`MAX_LATTICE_POINTS`),
        in time linear in the file's nodes and edges; returns self.

        Raises:
            InputError: naming the node and what is wrong.
        """
        if not 1 <= len(self.roots) <= 2:
            raise InputError(f"graph.roots: one or two roots, got {len(self.roots)}")
        self.view_check()
        for name in self.roots:
            if name not in self.nodes:
                raise InputError(f"graph.roots: no node named {name!r}")
        for name, node in self.nodes.items():
            if node.mesh is not None:
                if node.mesh not in self.meshes:
                    raise InputError(f"nodes.{name}.mesh: no mesh named {node.mesh!r}")
                if node.children or node.transform is not None:
                    raise InputError(f"nodes.{name}: a mesh node has no children and no transform")
            for child in node.children:
                if child not in self.nodes:
                    raise InputError(f"nodes.{name}.children: no node named {child!r}")
            t = node.transform
            if t is not None:
                for ref in (t.deformation, t.tangent_of):
                    if ref is not None and ref not in self.deformations:
                        raise InputError(f"nodes.{name}.{t.kind}: no deformation named {ref!r}")
            if t is not None and t.kind == "attach" and self.body is None:
                raise InputError(f"nodes.{name}.attach: needs a [body] to attach to")
        state: dict[str, int] = {}
        leaves: dict[str, int] = {}  # mesh instances below each node (capped)
        expanded: dict[str, int] = {}  # node instances of each node's expanded subtree (capped)
        depths: dict[str, int] = {}
        for root in self.roots:  # iterative depth-first search for cycles, counting leaves
            stack: list[tuple[str, int]] = [(root, 0)]
            while stack:
                name, i = stack.pop()
                kids = self.nodes[name].children
                if i == 0:
                    if state.get(name) == 1:
                        raise InputError(f"nodes.{name}: the graph has a cycle through this node")
                    if state.get(name) == 2:
                        continue
                    state[name] = 1
                if i < len(kids):
                    stack.append((name, i + 1))
                    if state.get(kids[i]) == 1:
                        raise InputError(f"nodes.{kids[i]}: the graph has a cycle through this node")
                    stack.append((kids[i], 0))
                else:
                    state[name] = 2  # done: its children's leaf counts are known
                    node = self.nodes[name]
                    n = 1 if node.mesh is not None else sum(leaves[c] for c in kids)
                    e = sum(expanded[c] for c in kids)
                    if node.transform is not None and node.transform.kind == "array":
                        count = int(np.prod(node.transform.count))
                        n *= count
                        e = count * (1 + e)  # one translation node per instance over the children
                    leaves[name] = min(n, MAX_LEAVES + 1)
                    expanded[name] = min(1 + e, MAX_EXPANDED + 1)
                    depths[name] = 1 + max((depths[c] for c in kids), default=0)
                    if depths[name] > MAX_GRAPH_DEPTH:
                        raise InputError(f"nodes.{name}: more than {MAX_GRAPH_DEPTH} levels below this node")
        self.depth = max(depths[r] for r in self.roots)
        for root in self.roots:
            if leaves[root] > MAX_LEAVES:
                raise InputError(f"graph.roots: {root!r} draws more than {MAX_LEAVES} mesh instances")
            if expanded[root] > MAX_EXPANDED:
                raise InputError(f"graph.roots: {root!r} expands to more than {MAX_EXPANDED} node instances "
                                 "(each node counted under every parent and array instance above it, "
                                 "with or without a mesh below)")
        for name, node in self.nodes.items():
            t = node.transform
            if t is not None and t.kind == "grid" and t.file is None:
                points = int(np.prod(np.array(t.cells) + 1))
                if points > MAX_LATTICE_POINTS:
                    raise InputError(f"nodes.{name}.grid.cells: {points} lattice points, at most {MAX_LATTICE_POINTS}")
        return self

    @property
    def duration(self) -> float:
        """Last keyframe time of any deformation (s), 0 for a still graph."""
        return max((k.t for d in self.deformations.values() for k in d.keys), default=0.0)

    def frame_times(self, frames: int) -> list[float]:
        """``frames`` times (s) from 0 to :attr:`duration`, evenly spaced (for an animation)."""
        if frames < 1:
            raise InputError(f"frames must be >= 1, got {frames}")
        return [float(t) for t in np.linspace(0.0, self.duration, frames)] if frames > 1 else [0.0]

    def at(self, t: float) -> SceneGraph:
        """The still graph at time ``t`` (s): every deformation's keyframed parameters replaced
        by their interpolated values, keyframes dropped."""
        deformations = {name: Deformation(d.kind, d.values_at(t)) for name, d in self.deformations.items()}
        return dataclasses.replace(self, deformations=deformations)
