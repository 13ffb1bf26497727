"""``python -m studies.mapping_accuracy``: how well each mapping (Mosegaard & Sørensen 2005, 3.2-3.3)
follows a known deformation, and what it costs to draw.

A bend or twist (:class:`~deformgl.mapping.node_drivers.Motion`) is applied analytically to the rest
node grid and uploaded (:class:`~deformgl.mapping.node_drivers.DrivenNodes`, GPU Mosegaard & Sørensen 2005, eq. 3 normals); the
detailed mesh is captured from the real vertex shader (transform feedback). The truth is the
same motion, with the same box, applied to the mesh's rest vertices in float64. Errors are in
grid spacings:

* constant (Mosegaard & Sørensen 2005, eq. 6), curvature (eq. 8) and auto (eq. 8 where ``Binding.curvature_ok``, else
  Mosegaard & Sørensen 2005, eq. 6): per-vertex correspondence error ``|v' - truth|`` of the eq. 9 vertex.
* one-to-one (3.2): the grid surface replaces the mesh, so there is no vertex correspondence.
  The figure is a *surface distance*: from each truth vertex to the closest point of the
  deformed grid surface (exact closest points, :func:`deformgl.mapping.closest.closest_on_triangles`).
  Its rest value is the approximation error of drawing the grid surface instead of the mesh;
  only the growth beyond it is due to the deformation.

The rest columns (nodes at rest) are a self-check for the triangle-basis modes and the
approximation error for one-to-one. What "exact" means here: a rigid motion rotates the node
differences that build Mosegaard & Sørensen 2005, eq. 6 (translation cancels), so the constant mode is exact to float32;
the Mosegaard & Sørensen 2005, eq. 3 normals behind eq. 8 rotate with the grid too, but they are packed into 15.5-bit
octahedral codes (<= 0.007 degrees, :mod:`deformgl.sim.normals`) whose rounding does not rotate, so
the curvature and auto modes are exact only to about 1e-4 x the offset length, at rest as well.
This study found where that rounding turned Mosegaard & Sørensen 2005, eq. 8's basis over (the weighted normal along T, the
dragon on 16 nodes: 0.7 spacings at rest); curvature mode now keeps Mosegaard & Sørensen 2005, eq. 6 there
(``mapping_setup.MIN_SIN_CURVATURE``), auto excludes more (``Binding.curvature_ok``).
"""

from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass
from pathlib import Path

import moderngl
import numpy as np

from deformgl.bench.sim_speed import timed
from deformgl.data import packaged_scene
from deformgl.sim.normals import rest_normals
from deformgl.mapping.closest import closest_on_triangles
from deformgl.sim.backends.verlet_data import NodeTextures
from deformgl.bench import report_files
from deformgl.render.mapped import MappedMeshPass
from deformgl.mapping.bases import constant_basis
from deformgl.render.mapped_setup import get_binding, mapped_vertices, mesh_uv
from deformgl.mapping.node_drivers import DrivenNodes, Motion
from deformgl.scene.pipeline import build_scene_model, scene_lighting, scene_view
from deformgl.render.passes import GridSurfacePass, RenderTarget
from deformgl.scene.schema import Scene, load_scene
from deformgl.grid.surface import grid_surface

MODES = ("one-to-one", "constant", "curvature", "auto")
#: The dragon of the paper's figure 6 (relative to the working directory, like ``studies.render_speed``'s
#: scene: the scenes are in the repository, not the wheel).
DEFAULT_SCENE = packaged_scene("dragon_bend_constant")
DEFAULT_GRIDS = (4, 8, 16)
DEFAULT_MOTIONS = (Motion("bend", 80.0, along=0, towards=1), Motion("twist", 90.0, along=0))


def motion_label(motion: Motion) -> str:
    """Short name of a motion, e.g. ``"bend 80"`` (degrees)."""
    return f"{motion.kind} {motion.angle:g}"


@dataclass(frozen=True)
class MappingRow:
    """One (grid, motion, mode) of the study; errors in grid spacings of that grid.

    Attributes:
        grid: nodes along the longest side; nodes: node count; spacing: world units;
            diagonal: the mesh's bounding-box diagonal, world units (for absolute errors).
        motion: :func:`motion_label`; mode: mapping mode.
        metric: "vertex" (correspondence error) or "surface" (one-to-one surface distance).
        rms, p95, max: error under the motion. rest_rms, rest_max: the same with nodes at rest.
        ms: median ms per draw (ctx.finish() included). bind_ms: one-time binding (None for
            one-to-one). curvature_share: fraction of vertices on the Mosegaard & Sørensen 2005, eq. 8 basis.
    """

    grid: int
    nodes: int
    spacing: float
    diagonal: float
    motion: str
    mode: str
    metric: str
    rms: float
    p95: float
    max: float
    rest_rms: float
    rest_max: float
    ms: float
    bind_ms: float | None
    curvature_share: float

    def to_record(self) -> dict[str, object]:
        """The row as a flat dict (JSON/CSV)."""
        return dataclasses.asdict(self)


def error_stats(error: np.ndarray) -> tuple[float, float, float]:
    """(RMS, 95th percentile, max) of per-vertex errors."""
    return (float(np.sqrt(np.mean(error ** 2))), float(np.percentile(error, 95)), float(error.max()))


class GridMappings:
    """A scene's mesh on a grid of driven nodes, with one draw pass per mapping mode.

    Args:
        ctx: GL context.
        scene: the scene (mesh, camera, light); its grid is replaced.
        nodes_along_longest: grid resolution.
        modes: mapping modes to build passes for.
        use_cache: reuse a cached binding (then ``bind_ms`` is the cache load time).
    """

    def __init__(self, ctx: moderngl.Context, scene: Scene, nodes_along_longest: int,
                 modes: tuple[str, ...] = MODES, *, use_cache: bool = False) -> None:
        self.ctx = ctx
        self.scene = dataclasses.replace(scene, grid=dataclasses.replace(
            scene.grid, nodes_along_longest=nodes_along_longest, spacing=None))
        self.built = built = build_scene_model(self.scene)
        self.rest = built.grid.rest_positions
        self.bounds = np.array([self.rest.min(axis=0), self.rest.max(axis=0)])
        self.spacing = built.grid.spacing
        self.surface = grid_surface(built.grid)
        # None once released
        self.textures: NodeTextures | None = NodeTextures(ctx, built.grid)
        self.nodes: DrivenNodes | None = DrivenNodes(ctx, self.textures, built.grid)
        layout = self.textures.layout
        self.passes: dict[str, GridSurfacePass | MappedMeshPass] = {}
        self.bind_ms: float | None = None
        self.curvature_share: dict[str, float] = {"one-to-one": 0.0}
        try:
            if any(m != "one-to-one" for m in modes):
                t0 = time.perf_counter()
                binding = get_binding(built.mesh, built.grid, self.surface, use_cache=use_cache,
                                      uv=mesh_uv(built.mesh))
                self.bind_ms = (time.perf_counter() - t0) * 1e3
                normals = rest_normals(built.grid)
            for mode in modes:
                if mode == "one-to-one":
                    self.passes[mode] = GridSurfacePass(ctx, built.grid, layout)
                    continue
                data = mapped_vertices(binding, mode, self.rest, normals)
                self.curvature_share[mode] = float(data.use_curvature.mean())
                self.passes[mode] = MappedMeshPass(ctx, built.grid, layout, built.mesh.faces, data)
        except BaseException:
            self.release()
            raise

    def _driven(self) -> DrivenNodes:
        """The driven nodes; raises RuntimeError after :meth:`release`."""
        if self.nodes is None:
            raise RuntimeError("GridMappings: used after release()")
        return self.nodes

    def set_positions(self, positions: np.ndarray) -> None:
        """Upload (N, 3) node positions (recentred frame); the GPU computes Mosegaard & Sørensen 2005, eq. 3 normals."""
        self._driven().set_positions(positions)

    def capture(self, mode: str) -> np.ndarray:
        """(V, 3) float64 vertices the vertex shader of ``mode`` computes for the current nodes
        (for one-to-one: the grid-surface vertices, one per ``surface.nodes`` entry)."""
        vertices, _ = self.passes[mode].capture(self._driven().position_texture)
        return vertices.astype(np.float64)

    def moved(self, motion: Motion, amount: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """(node positions, truth mesh vertices) under ``motion``, both with the nodes' box."""
        return (motion.apply(self.rest, amount, self.bounds),
                motion.apply(self.built.mesh.vertices, amount, self.bounds))

    def errors(self, mode: str, truth: np.ndarray) -> np.ndarray:
        """Per-vertex error in spacings for the current nodes: ``|v' - truth|`` (Mosegaard & Sørensen 2005, eq. 9 modes) or
        the distance from each truth vertex to the drawn grid surface (one-to-one)."""
        drawn = self.capture(mode)
        if mode != "one-to-one":
            return np.linalg.norm(drawn - truth, axis=1) / self.spacing
        corners = drawn[self.surface.triangles]
        _, ok = constant_basis(corners[:, 0], corners[:, 1], corners[:, 2])
        tri, w = closest_on_triangles(truth, corners, ~ok, drawn)
        closest = np.einsum("vi,vij->vj", w, corners[tri])
        return np.linalg.norm(closest - truth, axis=1) / self.spacing

    def draw_ms(self, mode: str, target: RenderTarget, repeats: int) -> float:
        """Median ms of one draw of ``mode`` into ``target`` (with ctx.finish()), current nodes."""
        view, lighting = scene_view(self.scene, self.built.bbox), scene_lighting(self.scene)
        r, g, b = self.scene.render.background  # a list or tuple of 3 (the schema checks it)
        background = (r, g, b)

        def draw() -> None:
            target.begin(background)
            self.passes[mode].draw(self._driven().position_texture, view, lighting)
            self.ctx.finish()

        draw()  # warm-up: shader compile and first upload
        return timed(draw, repeats) * 1e3

    def release(self) -> None:
        """Release every GL object."""
        for p in self.passes.values():
            p.release()
        self.passes = {}
        nodes = getattr(self, "nodes", None)  # absent when __init__ failed before setting it
        if nodes is not None:
            nodes.release()
            self.nodes = None
        textures = getattr(self, "textures", None)
        if textures is not None:
            textures.release()
            self.textures = None


def mapping_accuracy(ctx: moderngl.Context, *, scene_path: str | Path = DEFAULT_SCENE,
                     grids: tuple[int, ...] = DEFAULT_GRIDS, motions: tuple[Motion, ...] = DEFAULT_MOTIONS,
                     modes: tuple[str, ...] = MODES, size: tuple[int, int] = (512, 512), samples: int = 4,
                     repeats: int = 7, use_cache: bool = False) -> list[MappingRow]:
    """Error of every mapping against the analytic deformation, and its draw cost.

    Args:
        ctx: GL context.
        scene_path: scene whose mesh, camera and light are used (its grid and nodes are not).
        grids: nodes along the longest side, one grid each.
        motions: analytic motions at their full extent (amount 1), box = the rest node box.
        modes: mapping modes (see :data:`MODES`).
        size: (width, height) of the offscreen target; samples: its MSAA.
        repeats: draws per timing (median).
        use_cache: reuse cached bindings (default off, so ``bind_ms`` is a real binding).

    Returns:
        One row per grid x motion x mode, in that order.
    """
    width, height = size
    scene = load_scene(scene_path).with_overrides(size=(width, height))
    rows: list[MappingRow] = []
    target = RenderTarget(ctx, (width, height), samples)
    try:
        for n in grids:
            g = GridMappings(ctx, scene, n, tuple(modes), use_cache=use_cache)
            try:
                g.set_positions(g.rest)
                rest = {mode: error_stats(g.errors(mode, g.built.mesh.vertices)) for mode in modes}
                for motion in motions:
                    positions, truth = g.moved(motion)
                    g.set_positions(positions)
                    for mode in modes:
                        rms, p95, mx = error_stats(g.errors(mode, truth))
                        rows.append(MappingRow(
                            grid=n, nodes=g.built.grid.count, spacing=g.spacing,
                            diagonal=float(np.linalg.norm(np.ptp(g.built.bbox, axis=0))), motion=motion_label(motion),
                            mode=mode, metric="surface" if mode == "one-to-one" else "vertex", rms=rms,
                            p95=p95, max=mx, rest_rms=rest[mode][0], rest_max=rest[mode][2],
                            ms=g.draw_ms(mode, target, repeats),
                            bind_ms=None if mode == "one-to-one" else g.bind_ms,
                            curvature_share=g.curvature_share[mode]))
            finally:
                g.release()
    finally:
        target.release()
    return rows


#: A rest-state error above this many spacings is a failed self-check of a Mosegaard & Sørensen 2005, eq. 9 mode (the
#: expected level is float32 and the 0.007 degree octahedral packing of eq. 3 normals: ~1e-4).
REST_CHECK = 1e-3


def _per_mille(r: MappingRow) -> float:
    """RMS error in thousandths of the mesh's bounding-box diagonal."""
    return 1e3 * r.rms * r.spacing / r.diagonal


def conclusions(rows: list[MappingRow]) -> list[str]:
    """Sentences read off the rows: the most accurate Mosegaard & Sørensen 2005, eq. 9 mode per motion and grid, how errors
    fall with the grid, the draw cost of each mode, one-to-one's approximation, the self-check."""
    out = []
    mapped = [r for r in rows if r.metric == "vertex"]
    grids = list(dict.fromkeys(r.grid for r in rows))
    for motion in dict.fromkeys(r.motion for r in mapped):
        parts = []
        for n in grids:
            here = [r for r in mapped if r.motion == motion and r.grid == n]
            if here:
                best, worst = min(here, key=lambda r: r.rms), max(here, key=lambda r: r.rms)
                parts.append(f"{n} nodes {best.mode} (RMS {best.rms:.3g} spacings, max {best.max:.2g}; "
                             f"worst by RMS {worst.mode} {worst.rms:.3g}, max {worst.max:.2g})")
        trend = []
        for mode in dict.fromkeys(r.mode for r in mapped):
            series = [r for r in mapped if r.motion == motion and r.mode == mode]
            if len(series) > 1:
                trend.append(f"{mode} {_per_mille(series[0]):.2f} -> {_per_mille(series[-1]):.2f}")
        out.append(f"{motion}: most accurate: " + "; ".join(parts) + ".")
        if trend:
            out.append(f"  RMS in per mille of the mesh diagonal, {grids[0]} -> {grids[-1]} nodes: "
                       + ", ".join(trend) + ".")
    cost = {mode: float(np.median([r.ms for r in rows if r.mode == mode]))
            for mode in dict.fromkeys(r.mode for r in rows)}
    out.append("draw cost, median ms/frame over grids and motions: "
               + ", ".join(f"{mode} {ms:.2f}" for mode, ms in cost.items())
               + " (the Mosegaard & Sørensen 2005, eq. 9 modes draw the whole mesh; one-to-one only the grid surface).")
    one = [r for r in rows if r.mode == "one-to-one"]
    if one:
        grow = max(one, key=lambda r: r.rms - r.rest_rms)
        out.append(f"one-to-one: the grid surface is {min(r.rest_rms for r in one):.3g}-"
                   f"{max(r.rest_rms for r in one):.3g} spacings RMS from the mesh already at rest "
                   f"(approximation, not deformation); largest growth under a motion "
                   f"{grow.rest_rms:.3g} -> {grow.rms:.3g} ({grow.motion}, {grow.grid} nodes).")
    failed = {(r.grid, r.mode): r for r in mapped if r.rest_max > REST_CHECK}
    for (n, mode), r in failed.items():
        out.append(f"rest self-check FAILED: {mode} on {n} nodes is {r.rest_max:.2g} spacings off the rest "
                   f"mesh (max; RMS {r.rest_rms:.2g}); the known cause is Mosegaard & Sørensen 2005, eq. 8 bases built where the weighted node "
                   f"normal is almost parallel to T, where one code of normal packing turns the basis over "
                   f"(auto excludes them).")
    if mapped and not failed:
        out.append(f"rest self-check: every Mosegaard & Sørensen 2005, eq. 9 mode within {max(r.rest_max for r in mapped):.2g} spacings.")
    return out


def format_mapping_accuracy(rows: list[MappingRow], machine: str) -> str:
    """The ``studies.mapping_accuracy`` table, then the conclusions in words."""
    lines = [machine,
             "error in grid spacings against the same analytic motion applied to the mesh (float64); "
             "Mosegaard & Sørensen 2005, eq. 9 modes: per-vertex |v' - truth|; one-to-one (*): distance from the true vertex to the "
             "drawn grid surface (no correspondence); rest: nodes at rest; o/oo: RMS in per mille of the "
             "mesh diagonal; ms: median draw with ctx.finish(), no normal map; bind: one-time binding",
             f"{'grid':>4} {'nodes':>5} {'motion':>9} {'mode':>11} | {'RMS':>7} {'p95':>7} {'max':>7} {'o/oo':>6} | "
             f"{'rest RMS':>8} {'rest max':>8} | {'eq8 %':>6} | {'ms/frame':>8} {'bind ms':>7}"]
    lines.append("-" * len(lines[-1]))
    for r in rows:
        star = "*" if r.metric == "surface" else " "
        bind = "-" if r.bind_ms is None else f"{r.bind_ms:.0f}"
        lines.append(f"{r.grid:>4} {r.nodes:>5} {r.motion:>9} {r.mode + star:>11} | {r.rms:>7.4f} {r.p95:>7.4f} "
                     f"{r.max:>7.4f} {_per_mille(r):>6.2f} | {r.rest_rms:>8.2g} {r.rest_max:>8.2g} | "
                     f"{100 * r.curvature_share:>6.1f} | {r.ms:>8.2f} {bind:>7}")
    lines += ["", "in words:"] + [f"  {c}" for c in conclusions(rows)]
    return "\n".join(lines)


def to_records(rows: list[MappingRow]) -> list[dict[str, object]]:
    """Rows as flat dicts."""
    return [r.to_record() for r in rows]


def write_json(path: str | os.PathLike[str], rows: list[MappingRow], machine: str) -> None:
    """Write ``{"machine": ..., "rows": [...]}`` atomically (temporary file, then rename)."""
    report_files.write_json(path, {"machine": machine, "rows": to_records(rows)})


def write_csv(path: str | os.PathLike[str], rows: list[MappingRow]) -> None:
    """Write one CSV line per row (header: the field names) atomically."""
    report_files.write_csv(path, to_records(rows), [f.name for f in dataclasses.fields(MappingRow)])


def write_chart(path: str | os.PathLike[str], rows: list[MappingRow], machine: str) -> None:
    """PNG: RMS error (per mille of the mesh diagonal, comparable across grids) against ms per
    frame, one panel per motion, one line per mode through its grid sizes (labelled), log-log;
    one-to-one hollow (a surface distance).

    Raises:
        DeformglError: matplotlib is not installed (``pip install 'deformgl[plot]'``).
    """
    from deformgl.bench.charts import new_figure, save_png

    motions = list(dict.fromkeys(r.motion for r in rows))
    fig, axes = new_figure(1, len(motions), width=5.2, height=4.2, what="mappings")
    markers = {"one-to-one": "o", "constant": "s", "curvature": "^", "auto": "D"}
    for ax, motion in zip(axes[0], motions):
        for mode in dict.fromkeys(r.mode for r in rows):
            pts = sorted((r.grid, r.ms, _per_mille(r)) for r in rows if r.motion == motion and r.mode == mode)
            if not pts:
                continue
            hollow = mode == "one-to-one"
            line, = ax.plot([p[1] for p in pts], [p[2] for p in pts], marker=markers.get(mode, "o"), lw=1,
                            mfc="none" if hollow else None, label=mode + (" (surface distance)" if hollow else ""))
            for grid, ms, err in pts:
                ax.annotate(str(grid), (ms, err), textcoords="offset points", xytext=(4, 3), fontsize=6,
                            color=line.get_color())
        ax.set(xscale="log", yscale="log", xlabel="ms per frame (draw, 512x512)",
               ylabel="RMS error [per mille of the mesh diagonal]", title=f"{motion} (labels: nodes along the longest side)")
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=7)
    fig.suptitle(f"mapping error against draw cost; {machine}", fontsize=8)
    fig.tight_layout()
    save_png(fig, path)


def main(argv: list[str] | None = None) -> int:
    """``python -m studies.mapping_accuracy [--scene FILE] [--out DIR]``: the table, and with
    ``--out`` DIR/mappings.csv, .json and .png."""
    from deformgl.bench.sim_speed import machine_line
    from deformgl.data import scene_file
    from deformgl.files import OutputSet
    from studies.common import chart, gl_context, parse, parser

    p = parser("mapping_accuracy", "each mapping's error against an analytic bend and twist, and its draw time")
    p.add_argument("--scene", type=Path, default=None,
                   help="the scene whose mesh, camera and light are used (default: the shipped dragon_bend_constant.toml)")
    args = parse(p, argv)
    scene = scene_file(args.scene, "--scene") if args.scene else DEFAULT_SCENE
    out = args.out
    outputs = OutputSet([out / f"mappings.{ext}" for ext in ("csv", "json", "png")] if out else [])
    with gl_context(args) as ctx:
        rows = mapping_accuracy(ctx, scene_path=scene)
        machine = machine_line(ctx)
    print(format_mapping_accuracy(rows, machine))
    if out is not None:
        with outputs:
            write_csv(out / "mappings.csv", rows)
            write_json(out / "mappings.json", rows, machine)
            chart(lambda: write_chart(out / "mappings.png", rows, machine))
    return 0


if __name__ == "__main__":
    from studies.common import run_main

    run_main(main)
