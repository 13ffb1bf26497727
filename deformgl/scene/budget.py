"""How much memory a scene will need, estimated from the scene file before anything is built,
and the refusal (one :class:`~deformgl.errors.InputError` line) when the machine has less.

The estimate never voxelizes: the node count is bounded by the grid box the voxelizer would use
(``round(E / h) + 1`` nodes along each axis of the mesh's extent ``E``, :func:`deformgl.grid.voxelize.voxelize`),
which is exact for a cloth and for a mesh that fills its box, and an upper bound otherwise; the
springs are those of a full box of that shape (:func:`deformgl.sim.springs.from_grid`).

Host bytes (peak; the phases that hold the most at once, see :data:`HOST_BYTES`):

* grid: ``NodeGrid`` (occupied, int32 index, ijk, rest positions, the (N, 18) int32 neighbours)
  and, for a mesh, the voxelizer's box-sized intermediates;
* springs: ``SpringSystem`` (i, j int64; rest length, stiffness, damping float64; class int8) and
  its per-node arrays;
* integrator state: the float64 initial state (x, v, x_prev, a) and the per-spring temporaries of
  one :func:`deformgl.sim.springs.forces` call, the rest normals, the upload images;
* binding and mesh: the detailed mesh and its per-vertex binding (mapped modes);
* render read-back: the RGB image and its flipped copy.

GPU bytes: the node textures of the backend (static RGBA32F node data, the RGBA32I neighbour
layers unless the grid is dense, the state textures ``16 x len(integrators.GPU_BUFFERS[name])``
per texel), the grid-surface buffers, and the render target: ``w h samples (4 + 4)`` (colour +
depth) plus the ``w h 4`` resolve buffer with MSAA. On a software renderer (llvmpipe) GPU memory
is host memory, so :func:`check` adds it to the host need.

The lead calls :func:`check_scene` once, before building anything.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from deformgl.errors import InputError
from deformgl.scene.spec import MIN_EXTENT
from deformgl.sim.integrators import GPU_BUFFERS, VEC4_BYTES

__all__ = ["Budget", "HOST_BYTES", "estimate", "check", "check_scene", "probe_framebuffer",
           "available_host_bytes", "grid_box", "box_springs"]

#: Host bytes per unit, by phase (measured with tracemalloc and peak RSS, tests/test_budget.py).
#: "node": per node, "spring": per spring, "box": per position of the grid box.
HOST_BYTES: dict[str, dict[str, float]] = {
    # NodeGrid: rest positions 24, ijk 12, neighbours 72; SpringSystem rest positions 24,
    # mass 8, fixed 1; the initial state x, v, x_prev 72; driven/state read-backs
    "retained": {"node": 24 + 12 + 72 + 33 + 72, "spring": 8 + 8 + 8 + 8 + 8 + 1, "box": 1 + 4},
    # transient at the simulation's start: the rest normals of sim.normals.unit_sums (one
    # neighbour at a time: (N, 3) temporaries, ~100 per node), the upload images (node, neighbour
    # layers, state: 16 + 80 + 160 + 64), and forces()' per-spring temporaries, which forces()
    # builds one axis at a time and which overlap the images only in part: 30 per spring,
    # calibrated against peak RSS (tests/test_budget.py; 48 + 32 counted would be the ceiling)
    "simulation": {"node": 100 + 16 + 80 + 160 + 64, "spring": 30, "box": 0},
    # the voxelizer's box-sized intermediates (votes, parity, surface, fill) and the spring
    # candidates of from_grid before SpringSystem copies them
    "build": {"node": 0, "spring": 16 + 16 + 8 + 24, "box": 24},
}
#: Bytes per detailed-mesh vertex and face (trimesh arrays, the binding, the mapped-vertex data).
MESH_BYTES = {"vertex": 24 + 24 + 200, "face": 24 + 24}
#: Bytes per GPU texel of the fragment backend's static data: RGBA32F node data, and (grids that
#: are not dense) the RGBA32I neighbour layers, 5 (6 with flexion springs).
NODE_TEXEL = VEC4_BYTES
NEIGHBOUR_LAYER = VEC4_BYTES
#: Feedback backend: per spring end, the R32I other node and the RGBA32F spring data.
FEEDBACK_SPRING_END = 4 + VEC4_BYTES
#: Software renderers keep GPU memory in host memory.
SOFTWARE_RENDERERS = ("llvmpipe", "softpipe", "swrast", "software")


@dataclass(frozen=True)
class Budget:
    """A scene's estimated memory.

    Attributes:
        source: the scene file's name (for messages).
        nodes: node count (exact for a cloth or a box-filling mesh, else an upper bound).
        springs: spring count (as ``nodes``).
        box: positions of the grid box.
        host: bytes of host memory by part (grid, springs, integrator state, binding and mesh,
            render read-back), at the peak.
        gpu: bytes of GPU memory by part (simulation textures, draw buffers, render target).
        size: render (width, height).
        samples: MSAA samples (0: none).
        key: the grid key to lower in a message (``grid.nodes_along_longest``, ``grid.spacing``
            or ``cloth.nodes``) and its value.
    """

    source: str
    nodes: int
    springs: int
    box: int
    host: dict[str, int]
    gpu: dict[str, int]
    size: tuple[int, int]
    samples: int
    key: tuple[str, Any]

    @property
    def host_bytes(self) -> int:
        """Total host bytes at the peak."""
        return sum(self.host.values())

    @property
    def gpu_bytes(self) -> int:
        """Total GPU bytes."""
        return sum(self.gpu.values())

    def needs_host(self, software: bool) -> int:
        """Host bytes needed: the host estimate, plus the GPU's on a software renderer."""
        return self.host_bytes + (self.gpu_bytes if software else 0)


def grid_box(extent: np.ndarray, nodes_along_longest: int | None, spacing: float | None) -> tuple[int, int, int]:
    """Nodes along each axis of the voxelizer's grid (before trimming; padding excluded), as
    :func:`deformgl.grid.voxelize.voxelize` computes them."""
    extent = np.asarray(extent, dtype=np.float64)
    if nodes_along_longest is not None:  # (a mesh below MIN_EXTENT: the build refuses it, naming it)
        h = float(extent.max()) / (nodes_along_longest - 1) if extent.max() >= MIN_EXTENT else 1.0
    else:
        h = float(spacing)  # type: ignore[arg-type]
    n = np.rint(extent / h) + 1
    return int(n[0]), int(n[1]), int(n[2])


def box_springs(shape: tuple[int, int, int], flexion: bool) -> int:
    """Springs of a full box of nodes (:func:`deformgl.sim.springs.from_grid`): structural along
    each axis, two shear diagonals in each plane, flexion two steps along each axis."""
    nx, ny, nz = shape
    dims = (nx, ny, nz)
    total = 0
    for a in range(3):
        others = math.prod(d for b, d in enumerate(dims) if b != a)
        total += max(dims[a] - 1, 0) * others  # structural
        if flexion:
            total += max(dims[a] - 2, 0) * others
    for a, b in ((0, 1), (0, 2), (1, 2)):
        c = 3 - a - b
        total += 2 * max(dims[a] - 1, 0) * max(dims[b] - 1, 0) * dims[c]  # shear
    return total


def _texels(count: int) -> int:
    """Texels of the compact layout of ``count`` nodes (power-of-two width, whole rows)."""
    n = max(count, 1)
    width = 1 << max(4, int(math.ceil(math.log2(math.sqrt(n)))))
    return width * -(-n // width)


def _mesh_counts(scene: Any) -> tuple[np.ndarray, int, int]:
    """(extent (3,), vertices, faces) of the scene's detailed mesh (loaded, not voxelized)."""
    from deformgl.grid.meshio import load_mesh

    mesh = load_mesh(scene.mesh.path)
    faces = np.asarray(mesh.faces).reshape(-1, 3)
    if len(faces) == 0:
        return np.zeros(3), len(mesh.vertices), 0
    tri = np.asarray(mesh.vertices, dtype=np.float64)[faces]
    return tri.max(axis=(0, 1)) - tri.min(axis=(0, 1)), len(mesh.vertices), len(faces)


#: Host bytes per node that a ``[material]`` scene's lattice assembly adds at its peak, measured
#: on a 125k-node block: +456 over ``from_grid``'s peak for the cell counts and the weighted
#: stiffness, +1,258 for the spring-weight table and its lookup keys; 2,000 with a margin.
MATERIAL_HOST_BYTES_PER_NODE = 2000


def estimate(scene: Any) -> Budget:
    """The memory ``scene`` (a :class:`~deformgl.scene.schema.Scene`) will need, from the scene
    alone: the grid box bounds the node count, nothing is voxelized or allocated."""
    physics = scene.physics
    material = getattr(physics, "material", None)
    # the terms the material's lattice holds besides the springs, each with its counts
    # (deformgl.sim.terms.TermNeeds, declared in the term's own module)
    needs = tuple(getattr(material, "term_needs", ()))
    flexion = (physics.flexion.stiffness > 0 if material is None
               else bool(getattr(material, "flexion_ratio", 0.0)) or any(t.neighbours == 24 for t in needs))
    if scene.cloth is not None:
        nx, nz = scene.cloth.nodes
        shape = (int(nx), 1, int(nz))
        vertices, faces = nx * nz, 2 * (nx - 1) * (nz - 1)
        key: tuple[str, Any] = ("cloth.nodes", f"{nx}x{nz}")
        mesh_box = 0
    else:
        extent, vertices, faces = _mesh_counts(scene)
        shape = grid_box(extent, scene.grid.nodes_along_longest, scene.grid.spacing)
        if scene.grid.spacing is not None:
            key = ("grid.spacing", scene.grid.spacing)
        else:
            key = ("grid.nodes_along_longest", scene.grid.nodes_along_longest)
        mesh_box = math.prod(n + 3 for n in shape)  # the voxelizer's padded corner lattice
        if material is not None and not hasattr(material, "areal_density"):
            # a solid's grid is the cells its material fills (deformgl.grid.fill): up to one node
            # plane more on each side, and the fill's samples, box-sized intermediates of their own
            from deformgl.grid.fill import MAX_SAMPLES, MIN_SAMPLES, SAMPLES_ALONG_LONGEST

            along = max(max(shape) - 1, 1)
            per_cell = max(MIN_SAMPLES, math.ceil(SAMPLES_ALONG_LONGEST / along))
            mesh_box += min(MAX_SAMPLES, math.prod((n + 1) * per_cell for n in shape))
            shape = (shape[0] + 2, shape[1] + 2, shape[2] + 2)
    nodes = math.prod(shape)
    springs = box_springs(shape, flexion)
    box = nodes

    def part(phase: str) -> int:
        c = HOST_BYTES[phase]
        return int(c["node"] * nodes + c["spring"] * springs + c["box"] * (box + mesh_box))

    retained = part("retained")
    transient = max(part("simulation"), part("build"))
    w, h = (int(v) for v in scene.render.size)
    samples = scene.render.samples
    grid_bytes = int((24 + 12 + 72 + 5 / max(nodes, 1) * box) * nodes + 5 * mesh_box)
    spring_bytes = int(HOST_BYTES["retained"]["spring"] * springs + 33 * nodes)
    host = {
        "grid": grid_bytes,
        "springs": spring_bytes,
        "integrator state": max(retained - grid_bytes - spring_bytes, 0) + transient,
        "binding and mesh": int(MESH_BYTES["vertex"] * vertices + MESH_BYTES["face"] * faces),
        "render read-back": w * h * 3 * 2,
    }
    if material is not None:
        # the cell assembly (a second (S,) stiffness and its temporaries) and the (N, 18 or 24)
        # float64 spring weights with their lookup keys (MATERIAL_HOST_BYTES_PER_NODE)
        host["material lattice"] = int(MATERIAL_HOST_BYTES_PER_NODE * nodes)
        # its terms' own assembly (a solid's cells: their corners and gather table)
        host["material lattice"] += int(sum(t.host_bytes_per_node for t in needs) * nodes)
    term_texel = sum(t.texel_bytes for t in needs)  # the terms' integer tables per node texel
    texels = _texels(nodes)
    if physics.backend == "fragment":
        dense = scene.cloth is not None  # a box mesh is dense too; counted as not (an upper bound)
        layers = 0 if dense else (6 if flexion else 5)
        weights = (6 if flexion else 5) if material is not None else 0  # the spring-weight layers
        weights += sum(t.node_layers for t in needs)  # the terms' node tables
        if physics.integrator == "xpbd":  # always a neighbour texture, and the stiffness layers
            layers, weights = 2 * (6 if flexion else 5), 0
        # Verlet's blocked layout (several nodes per fragment, deformgl.sim.backends.blocked) adds
        # its compact view and place texture, 2 texels per node; its block-neighbour table (7 layers
        # a block of 4, the default) stays under the 5 index layers a node counted here. Members
        # without a node (a shape's boundary blocks) are not counted: the default block never
        # spans the thin axis of a sheet, so a sheet fills its blocks
        blocked = 2 if physics.integrator == "verlet" and physics.layout != "compact" else 0
        sim = texels * (NODE_TEXEL + NEIGHBOUR_LAYER * layers + VEC4_BYTES * weights
                        + VEC4_BYTES * (len(GPU_BUFFERS[physics.integrator]) + blocked) + term_texel)
    elif physics.backend == "feedback":
        sim = (texels * (VEC4_BYTES + VEC4_BYTES * len(GPU_BUFFERS[physics.integrator]) + term_texel)
               + 2 * springs * FEEDBACK_SPRING_END
               + sum(t.feedback_entries for t in needs) * nodes * FEEDBACK_SPRING_END)
    else:  # the NumPy reference: its state is host memory; textures only to draw
        sim = texels * 2 * VEC4_BYTES
    gpu = {
        "simulation": int(sim),
        "draw buffers": int(8 * vertices + 12 * faces),
        "render target": w * h * max(samples, 1) * (4 + 4) + (w * h * 4 if samples or scene.render.fxaa else 0),
    }
    return Budget(source=Path(str(scene.source)).name, nodes=nodes, springs=springs, box=box,
                  host=host, gpu=gpu, size=(w, h), samples=samples, key=key)


def available_host_bytes() -> int:
    """Host memory available now: ``MemAvailable`` of /proc/meminfo, else free pages x page size."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 1 << 62  # unknown: refuse nothing


def _gb(n: float) -> str:
    return f"{n / 1e9:.1f} GB" if n >= 1e8 else f"{n / 1e6:.0f} MB"


def check(budget: Budget, *, available_host: int | None = None, gl_limits: dict[str, Any] | None = None,
          software: bool = False) -> None:
    """Refuse a scene the machine cannot hold, with one line: the estimate, what the machine has,
    and what to change.

    Args:
        budget: from :func:`estimate`.
        available_host: host bytes available (default: :func:`available_host_bytes`).
        gl_limits: ``ctx.info`` (``GL_MAX_RENDERBUFFER_SIZE``, ``GL_MAX_TEXTURE_SIZE``,
            ``GL_MAX_SAMPLES``, ``GL_MAX_VIEWPORT_DIMS``, ``GL_RENDERER``), or None to skip them.
        software: GPU memory is host memory (llvmpipe); also true when ``gl_limits`` names a
            software renderer.

    Raises:
        InputError: not enough host memory, or a render target over the GL limits.
    """
    src = budget.source
    w, h = budget.size
    if gl_limits is not None:
        renderer = str(gl_limits.get("GL_RENDERER", "")).lower()
        software = software or any(s in renderer for s in SOFTWARE_RENDERERS)
        max_samples = int(gl_limits.get("GL_MAX_SAMPLES", 1) or 1)
        if budget.samples > max(max_samples, 1):
            raise InputError(f"{src}: render.msaa: {budget.samples}x is more than this renderer's "
                             f"{max_samples}x: lower render.msaa")
        limit = min(int(gl_limits.get(k, 1 << 30) or (1 << 30))
                    for k in ("GL_MAX_RENDERBUFFER_SIZE", "GL_MAX_TEXTURE_SIZE"))
        vp = gl_limits.get("GL_MAX_VIEWPORT_DIMS")
        if vp:
            limit = min(limit, *(int(v) for v in vp))
        if max(w, h) > limit:
            raise InputError(f"{src}: render.size: {w}x{h} is more than this renderer's {limit}x{limit} "
                             f"limit: lower render.size")
    need = budget.needs_host(software)
    have = available_host_bytes() if available_host is None else int(available_host)
    if need > have:
        name, value = budget.key
        target = budget.gpu["render target"]
        if software and target > need / 2:
            fix = f"lower render.size ({w}x{h}) or render.msaa ({budget.samples}x)"
        else:
            # a finer spacing means more nodes: the spacing is raised, the node counts lowered
            fix = f"{'raise' if name == 'grid.spacing' else 'lower'} {name} ({value})"
        raise InputError(f"{src}: needs about {_gb(need)} of host memory for {budget.nodes:,} nodes; "
                         f"{_gb(have)} available: {fix}")


def probe_framebuffer(ctx: Any, size: tuple[int, int], samples: int) -> None:
    """Check that a colour + depth framebuffer of ``size`` with ``samples`` MSAA samples is
    complete, before any simulation (what :class:`~deformgl.render.passes.RenderTarget` builds).

    The limits are checked first; with MSAA the framebuffer is then built and released: an
    incomplete one (llvmpipe refuses multisampled buffers of 2**31 bytes or more with
    INCOMPLETE_ATTACHMENT) fails at once without allocating, a complete one costs what the render
    will allocate anyway. Without MSAA the limits decide.

    Raises:
        InputError: the configuration cannot be built, naming render.size / render.msaa.
    """
    w, h = (int(v) for v in size)
    info = ctx.info
    max_samples = int(info.get("GL_MAX_SAMPLES", 1) or 1)
    samples = samples if samples > 1 else 0
    if samples > max(max_samples, 1):
        raise InputError(f"render.msaa: {samples}x is more than this renderer's {max_samples}x: lower render.msaa")
    limit = min(int(info.get(k, 1 << 30) or (1 << 30)) for k in ("GL_MAX_RENDERBUFFER_SIZE", "GL_MAX_TEXTURE_SIZE"))
    if max(w, h) > limit:
        raise InputError(f"render.size: {w}x{h} is more than this renderer's {limit}x{limit} limit: lower render.size")
    if not samples:
        return
    made: list[Any] = []
    try:
        made.append(ctx.renderbuffer((w, h), 4, samples=samples))
        made.append(ctx.depth_renderbuffer((w, h), samples=samples))
        made.append(ctx.framebuffer(color_attachments=[made[0]], depth_attachment=made[1]))
    except Exception as exc:  # moderngl.Error: "the framebuffer is not complete (...)"
        raise InputError(f"render.size: a {w}x{h} framebuffer with {samples}x MSAA cannot be built "
                         f"here ({exc}): lower render.size or render.msaa") from None
    finally:
        fbo = ctx.fbo
        for obj in reversed(made):
            if fbo is obj:
                ctx.detect_framebuffer(0).use()
            obj.release()


def check_scene(ctx: Any, scene: Any, *, available_host: int | None = None) -> Budget:
    """Everything before building a scene: estimate, check host memory and the GL limits, probe
    the render target. Returns the budget (for a log line).

    Raises:
        InputError: one line naming the scene, the estimate, what the machine has, what to change.
    """
    budget = estimate(scene)
    check(budget, available_host=available_host, gl_limits=dict(ctx.info))
    try:
        probe_framebuffer(ctx, budget.size, budget.samples)
    except InputError as exc:
        raise InputError(f"{budget.source}: {exc}") from None
    return budget
