"""Every method's step in its own terms (issue 29, item 4): fragment passes, texel fetches,
reductions and scalar reads, priced by a renderer's measured rates.

A step of the fragment backend is a fixed sequence of full-screen passes over node textures (the
compact layout: ``width x rows`` texels, ``width`` the power of two of
:meth:`~deformgl.grid.nodes.CompactLayout.for_grid`). Its cost on a renderer is, to first order,

    seconds = passes pass_s + sum_k fetches_k fetch_s[k] + reductions reduction_s + reads read_s

with ``fetches_k`` the texel fetches of every fragment of every pass of kind k (:data:`FETCHES`,
per pass, for the 18-neighbour lattice; counted from ``shaders/sim``): "force" an explicit
step's spring forces, "product" the implicit passes that evaluate the step matrix at the 18
neighbours (``A y``, SETUP's forces and ``H v``, the fine level's multigrid smoothing), "other"
the per-node vector updates, the multigrid transfers and its coarse levels' stencils. A fetch
costs more where more arithmetic hangs on it (a product's 3 x 3 Gauss-Newton block per neighbour
against a force's one spring), so each kind has its own rate. ``reductions`` are the sums of a
product texture down to one texel (a chain of 4 x 4 reduction passes, ``implicit/reduce.frag``: its
passes and fetches are in ``reduction_s``) and ``reads`` the GPU-to-CPU scalar reads of a solve
with a tolerance (each a pipeline stall). :data:`RATES` are those rates fitted on a renderer by
``python -m studies.plan_rates`` (non-negative least squares over explicit and implicit
steps of several sizes; the read timed apart), which prints the fit's error per configuration.

The passes are those the backends draw: explicit Verlet one pass a step (the foundation pass),
semi-implicit Euler one, midpoint two, RK4 four (:mod:`deformgl.sim.stages`); implicit Euler
(:mod:`deformgl.sim.backends.implicit_gpu`) SETUP, a sum, the scaled warm start (WARM, a sum,
INIT), a sum, per CG iteration MATVEC, a sum, UPDATE, a sum, DIRECTION, then FINAL; with the
multigrid preconditioner (:mod:`deformgl.sim.backends.multigrid_gpu`) each application adds a
V-cycle: on the finest level :data:`~deformgl.sim.multigrid.SWEEPS` smoothing passes, a residual,
the restriction, every coarse level's own smoothing, residual and restriction down to the
coarsest's dense solve, the prolongations back and the post-smoothing, then RZ.
``tests/test_plan_cost.py`` records the passes a real step draws and checks them against
:func:`implicit_passes` and :func:`explicit_passes`, pass by pass.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from deformgl.sim.multigrid import COARSEST_NODES, SWEEPS

__all__ = ["Pass", "Work", "Rates", "RATES", "FETCHES", "CELL_FETCHES", "KINDS", "kind", "layout_texels", "coarse_counts",
           "explicit_passes", "implicit_passes", "explicit_work", "implicit_work", "work"]

#: Texel fetches per fragment of each pass on the 18-neighbour lattice of a full box (the plan
#: prices a body as its bounding box: the compact layout is dense, node n's neighbours found by
#: arithmetic). An explicit force reads the node texel, x (and x_prev or v) and the 18 neighbours'
#: positions (Verlet's foundation pass 21; the stage passes also the 5 spring-weight layers);
#: an implicit pass reads the node texel, the neighbour indices and weights (5 + 5 layers) and
#: what it reads per neighbour and per node: SETUP the 18 neighbours' positions and velocities
#: (forces and ``H v``); the product ``A y`` (MATVEC, WARM, TRUE_RESIDUAL, MG_RESIDUAL,
#: MG_SMOOTH) their positions and ``y``; a coarse level's stencil pass its 7 index layers, 27
#: neighbours' values and 81 stencil layers.
FETCHES: dict[str, int] = {
    "verlet": 21, "semi-implicit": 26, "midpoint": 26, "rk4": 28,
    "SETUP": 49, "WARM": 50, "INIT": 7, "MATVEC": 49, "UPDATE": 9, "DIRECTION": 7, "TRUE_RESIDUAL": 50,
    "FINAL": 4, "MG_SMOOTH_ZERO": 4, "MG_SMOOTH": 52, "MG_RESIDUAL": 50, "RZ": 3,
    "LEVEL_SMOOTH_ZERO": 4, "LEVEL_SMOOTH": 119, "LEVEL_RESIDUAL": 116, "RESTRICT": 41, "PROLONG": 13,
}
#: What the cells' volumetric term (Poisson's ratio above 1/4: :mod:`deformgl.sim.terms.volume.energy`) adds to
#: a pass that evaluates forces or products: an explicit force its 8 body diagonals' positions
#: (the rest of the neighbourhood is the springs'); an implicit product its 7 neighbourhood index
#: layers and the 26 neighbours' positions and ``y``. The implicit backend's SETUP always gathers
#: the neighbourhood (the corner barriers are on at any nu).
CELL_FETCHES: dict[str, int] = {"force": 8, "product": 59}
_FORCE_PASSES = ("verlet", "semi-implicit", "midpoint", "rk4")
_PRODUCT_PASSES = ("SETUP", "WARM", "MATVEC", "TRUE_RESIDUAL", "MG_SMOOTH", "MG_RESIDUAL")
#: The kinds of fetch, each with its own rate (module docstring).
KINDS = ("force", "product", "other")


def kind(name: str) -> str:
    """The kind of the fetches of pass ``name``."""
    return "force" if name in _FORCE_PASSES else "product" if name in _PRODUCT_PASSES else "other"


@dataclass(frozen=True)
class Pass:
    """One full-screen pass: its name, the texels it draws and the fetches of each."""

    name: str
    texels: int
    fetches: int

    @property
    def total(self) -> int:
        """Texel fetches of the whole pass."""
        return self.texels * self.fetches


@dataclass(frozen=True)
class Rates:
    """A renderer's measured cost of each unit, in seconds."""

    pass_s: float                      # one full-screen pass (state changes, framebuffer, dispatch)
    fetch_s: tuple[float, float, float]  # one texel fetch of one fragment, per kind (:data:`KINDS`)
    reduction_s: float                 # one sum of a node texture to one texel (its chain of passes)
    read_s: float                      # one scalar read back to the CPU (a stall)
    renderer: str = ""


#: Fitted by ``python -m studies.plan_rates`` (2-core AMD EPYC, llvmpipe (LLVM 15.0.6),
#: Mesa 22.3.6, 2026-12-06, 5 rounds: the model within 0.77-1.21 of the measured median on all 23
#: configurations, within 10 % on 18; docs/PERFORMANCE.md "Pricing the plan").
RATES = Rates(pass_s=200.5e-6, fetch_s=(4.499e-9, 1.746e-9, 14.94e-9), reduction_s=602.2e-6, read_s=96.97e-6,
              renderer="llvmpipe (LLVM 15.0.6), 2-core AMD EPYC")


@dataclass(frozen=True)
class Work:
    """A step's (or a frame's) units of cost."""

    passes: int
    by_kind: tuple[int, int, int]   # texel fetches per kind (:data:`KINDS`)
    reductions: int
    reads: int

    @property
    def fetches(self) -> int:
        """Texel fetches of every kind."""
        return sum(self.by_kind)

    def __add__(self, other: Work) -> Work:
        a, b = self.by_kind, other.by_kind
        return Work(self.passes + other.passes, (a[0] + b[0], a[1] + b[1], a[2] + b[2]),
                    self.reductions + other.reductions, self.reads + other.reads)

    def times(self, n: int) -> Work:
        """``n`` of these (steps of a frame)."""
        f = self.by_kind
        return Work(n * self.passes, (n * f[0], n * f[1], n * f[2]), n * self.reductions, n * self.reads)

    def seconds(self, rates: Rates = RATES) -> float:
        """The predicted wall time on the renderer of ``rates``."""
        return (self.passes * rates.pass_s + sum(f * r for f, r in zip(self.by_kind, rates.fetch_s))
                + self.reductions * rates.reduction_s + self.reads * rates.read_s)

    def words(self) -> str:
        return (f"{self.passes} passes, {self.fetches / 1e6:.3g} M texel fetches, {self.reductions} reductions"
                + (f", {self.reads} reads" if self.reads else ""))


def layout_texels(count: int, max_size: int = 16384) -> int:
    """Texels of the compact layout of ``count`` nodes (every pass draws all of them)."""
    n = max(count, 1)
    width = min(1 << max(4, int(math.ceil(math.log2(math.sqrt(n))))), 1 << int(math.floor(math.log2(max_size))))
    return width * max(1, -(-n // width))


def coarse_counts(shape: tuple[int, int, int]) -> list[int]:
    """Node counts of a full box's coarse levels (:func:`~deformgl.sim.multigrid.grid_levels`:
    every other node along each axis, n // 2 + 1 of n, down to at most
    :data:`~deformgl.sim.multigrid.COARSEST_NODES`; at least one level where some axis has 3)."""
    out: list[int] = []
    dims = list(shape)
    while (math.prod(dims) > COARSEST_NODES or not out) and max(dims) > 2:
        dims = [d // 2 + 1 if d > 1 else 1 for d in dims]   # (deformgl.sim.multigrid._coarse_axis)
        out.append(math.prod(dims))
    return out


def _fetches(name: str, cells: bool) -> int:
    extra = 0
    if cells and name in _FORCE_PASSES:
        extra = CELL_FETCHES["force"]
    elif cells and name in _PRODUCT_PASSES:
        extra = CELL_FETCHES["product"]
    return FETCHES[name] + extra


def explicit_passes(nodes: int, integrator: str, *, cells: bool = False) -> list[Pass]:
    """The passes of one explicit step of ``nodes`` nodes (:mod:`deformgl.sim.stages`)."""
    from deformgl.sim.stages import spec

    count = 1 if integrator == "verlet" else len(spec(integrator).stages)
    texels = layout_texels(nodes)
    return [Pass(integrator, texels, _fetches(integrator, cells))] * count


def _cycle(fine: int, fine_texels: int, coarse: list[int], cells: bool) -> list[Pass]:
    """One V-cycle's passes (:meth:`~deformgl.sim.backends.multigrid_gpu.GpuMultigrid.cycle`)."""
    out = [Pass("MG_SMOOTH_ZERO", fine_texels, FETCHES["MG_SMOOTH_ZERO"])]
    out += [Pass("MG_SMOOTH", fine_texels, _fetches("MG_SMOOTH", cells))] * (SWEEPS - 1)
    out.append(Pass("MG_RESIDUAL", fine_texels, _fetches("MG_RESIDUAL", cells)))
    texels = [layout_texels(c) for c in coarse]
    for level, count in enumerate(coarse):
        out.append(Pass("RESTRICT", texels[level], FETCHES["RESTRICT"]))
        if level == len(coarse) - 1:
            out.append(Pass("COARSEST", texels[level], 4 * count))
            break
        out.append(Pass("LEVEL_SMOOTH_ZERO", texels[level], FETCHES["LEVEL_SMOOTH_ZERO"]))
        out += [Pass("LEVEL_SMOOTH", texels[level], FETCHES["LEVEL_SMOOTH"])] * (SWEEPS - 1)
        out.append(Pass("LEVEL_RESIDUAL", texels[level], FETCHES["LEVEL_RESIDUAL"]))
    for level in range(len(coarse) - 2, -1, -1):
        out.append(Pass("PROLONG", texels[level], FETCHES["PROLONG"]))
        out += [Pass("LEVEL_SMOOTH", texels[level], FETCHES["LEVEL_SMOOTH"])] * SWEEPS
    out.append(Pass("PROLONG", fine_texels, FETCHES["PROLONG"]))
    out += [Pass("MG_SMOOTH", fine_texels, _fetches("MG_SMOOTH", cells))] * SWEEPS
    out.append(Pass("RZ", fine_texels, FETCHES["RZ"]))
    return out


def implicit_passes(nodes: int, iterations: int, preconditioner: str = "jacobi", *,
                    coarse: list[int] | None = None, cells: bool = False,
                    tolerance: bool = False) -> tuple[list[Pass], int, int]:
    """(passes, reductions, reads) of one implicit-Euler step of ``nodes`` nodes that runs all
    ``iterations`` CG iterations (the scaled warm start), ``coarse`` the multigrid's coarse level
    node counts (:func:`coarse_counts`); ``tolerance``: with the TRUE_RESIDUAL pass and a read
    per iteration (``cg_check_every`` 1) and the step's two."""
    t = layout_texels(nodes)

    def p(name: str) -> Pass:
        return Pass(name, t, _fetches(name, cells))

    multigrid = preconditioner == "multigrid"
    if multigrid and not coarse:
        raise ValueError("implicit_passes: the multigrid preconditioner needs the coarse levels' node counts")
    cycle = _cycle(nodes, t, coarse or [], cells) if multigrid else []
    out = [Pass("SETUP", t, _fetches("SETUP", True)), p("WARM"), p("INIT"), *cycle]
    reductions = 3
    for _ in range(iterations):
        out += [p("MATVEC"), p("UPDATE"), *cycle, p("DIRECTION")]
        reductions += 2
    reads = 0
    if tolerance:
        out.append(p("TRUE_RESIDUAL"))
        reductions += 1
        reads = iterations + 2  # b.b, r.r before each iteration, the true residual
    out.append(p("FINAL"))
    return out, reductions, reads


def work(passes: list[Pass], reductions: int = 0, reads: int = 0) -> Work:
    """The units of ``passes``."""
    by_kind = [0, 0, 0]
    for x in passes:
        by_kind[KINDS.index(kind(x.name))] += x.total
    return Work(len(passes), (by_kind[0], by_kind[1], by_kind[2]), reductions, reads)


def explicit_work(nodes: int, integrator: str, *, cells: bool = False) -> Work:
    """One explicit step's units (:func:`explicit_passes`)."""
    return work(explicit_passes(nodes, integrator, cells=cells))


def implicit_work(nodes: int, iterations: int, preconditioner: str = "jacobi", *,
                  coarse: list[int] | None = None, cells: bool = False, tolerance: bool = False) -> Work:
    """One implicit step's units (:func:`implicit_passes`)."""
    return work(*implicit_passes(nodes, iterations, preconditioner, coarse=coarse, cells=cells,
                                 tolerance=tolerance))
