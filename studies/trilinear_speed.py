"""``python -m studies.trilinear_speed``: the benchmark of Knuth, Kohlhammer & Kuijper, section 6 (linear
against trilinear scene graphs, and the cost of depth), on the scenes of
:mod:`deformgl.trilinear.scenes`.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass

import moderngl

from deformgl.bench.sim_speed import machine_line
from deformgl.render.camera import View
from deformgl.render.passes import RenderTarget
from deformgl.trilinear.renderer import TrilinearRenderer, shader_defines
from deformgl.trilinear.scenegraph import SceneComposer, compose_scene
from deformgl.trilinear.batches import ComposedScene
from deformgl.trilinear.graph_nodes import Node
from deformgl.trilinear.scenes import BACKGROUND, BuiltScene, depth_scene, helix_scene, spheres_scene
from deformgl.trilinear.graphbuild import LIGHT, scene_view


@dataclass(frozen=True)
class BenchSetup:
    """One row of the paper's table: scene, objects, sphere tessellation, paper's FPS."""

    scene: str
    objects: int
    segments: int
    rings: int
    paper_fps: tuple[float, float]

    def build(self, mode: str) -> BuiltScene:
        """The scene graph of this set-up with linear or trilinear transforms."""
        if self.scene == "spheres":
            return spheres_scene(mode, along=37, around=self.objects // 37, segments=self.segments, rings=self.rings)
        return helix_scene(mode, self.objects, segments=self.segments, rings=self.rings)


#: 185 x 8,064 = 1.49M, 4,617 x 36 = 166k and 2,566 x 256 = 657k triangles (paper: 1.5M, 164k, 656k).
BENCH_SETUPS = (
    BenchSetup("spheres", 185, 64, 64, (19.5, 14.9)),
    BenchSetup("helix", 4617, 6, 4, (16.5, 13.3)),
    BenchSetup("helix", 2566, 16, 9, (10.8, 8.4)),
)


@dataclass
class TrilinearRow:
    """Linear vs trilinear timings of one set-up (milliseconds, medians)."""

    setup: BenchSetup
    triangles: int
    compose_ms: dict[str, float]
    draw_ms: dict[str, float]
    paths: dict[str, dict[str, int]]
    grid_error: float
    cold_ms: dict[str, float]

    def fps(self, mode: str) -> float:
        """Frames per second including the CPU composition."""
        return 1e3 / (self.compose_ms[mode] + self.draw_ms[mode])

    def ratio(self) -> float:
        """Trilinear over linear frames per second (the paper's figure)."""
        return self.fps("trilinear") / self.fps("linear")

    def scratch_ratio(self) -> float:
        """Trilinear over linear frames per second with both composed from scratch."""
        return ((self.cold_ms["linear"] + self.draw_ms["linear"])
                / (self.cold_ms["trilinear"] + self.draw_ms["trilinear"]))

    def draw_ratio(self) -> float:
        """Trilinear over linear, GPU draw only."""
        return self.draw_ms["linear"] / self.draw_ms["trilinear"]


def time_frames(ctx: moderngl.Context, roots: dict[str, Node], size: tuple[int, int], repeats: int, *,
                view: View | None = None) -> tuple[dict[str, tuple[float, ...]], dict[str, ComposedScene]]:
    """Median compose and draw times (ms) of full frames of several scenes, interleaved frame by
    frame (in alternating order) so that all see the same machine load. A frame: compose on the
    CPU (each scene's :class:`SceneComposer`, which recomposes only what changed since its
    previous frame: here nothing), then upload, draw and ``ctx.finish()`` into a ``size``
    offscreen target without MSAA. Before each frame, the same scene is also composed from
    scratch (:func:`compose_scene`: the cost of a frame in which every transform changed),
    timed apart. The camera frames the first scene unless ``view`` is given; the first frame of
    each (compiling programs, allocating buffers) is not counted.

    Returns:
        Per key: (compose ms, draw ms, from-scratch compose ms); and the last composed scene of each.
    """
    target = RenderTarget(ctx, size, 0)
    renderer = TrilinearRenderer(ctx)
    try:
        composers = {key: SceneComposer() for key in roots}
        scenes = {key: composers[key].compose(root) for key, root in roots.items()}
        view = view or scene_view(next(iter(scenes.values())), size)
        times: dict[str, list[tuple[float, float, float]]] = {key: [] for key in roots}
        keys = list(roots)
        for i in range(repeats + 1):
            for key in keys if i % 2 else keys[::-1]:  # alternate the order: no position bias
                root = roots[key]
                c0 = time.perf_counter()
                compose_scene(root)
                t0 = time.perf_counter()
                scenes[key] = composers[key].compose(root)
                t1 = time.perf_counter()
                target.begin(BACKGROUND)
                renderer.draw(scenes[key], view, LIGHT)
                ctx.finish()
                t2 = time.perf_counter()
                if i:
                    times[key].append((t1 - t0, t2 - t1, t0 - c0))
        medians = {key: tuple(statistics.median(v[j] for v in t) * 1e3 for j in range(3)) for key, t in times.items()}
        return medians, scenes
    finally:
        renderer.release()
        target.release()


def bench_trilinear(ctx: moderngl.Context, *, size: tuple[int, int] = (512, 512), repeats: int = 16,
                    setups: tuple[BenchSetup, ...] = BENCH_SETUPS) -> list[TrilinearRow]:
    """Frames per second with linear vs trilinear transforms for the paper's three set-ups.

    Both modes draw the same meshes with the same camera; the linear scene places every object
    with the tangent affine map, the trilinear one by a grid at the root, composed per leaf.
    """
    rows = []
    for setup in setups:
        built = {mode: setup.build(mode) for mode in ("trilinear", "linear")}
        medians, scenes = time_frames(ctx, {m: b.root for m, b in built.items()}, size, repeats)
        error = max((g.error for g in built["trilinear"].grids.values()), default=0.0)
        rows.append(TrilinearRow(setup, scenes["trilinear"].triangle_count,
                                 {m: medians[m][0] for m in medians}, {m: medians[m][1] for m in medians},
                                 {m: s.paths() for m, s in scenes.items()}, error, {m: medians[m][2] for m in medians}))
    return rows


@dataclass
class DepthRow:
    """The same geometry under ``depth`` nested grid transforms."""

    depth: int
    compose_ms: float
    draw_ms: float
    cold_ms: float
    cells: tuple[int, int, int]
    defines: dict[str, object]
    triangles: int


def bench_depth(ctx: moderngl.Context, *, size: tuple[int, int] = (512, 512), repeats: int = 16,
                depths: tuple[int, ...] = (1, 8)) -> list[DepthRow]:
    """Shader cost per depth: ms/frame of one sphere under 1 vs 8 nested 8^3 grids."""
    roots = {str(d): depth_scene(d).root for d in depths}
    medians, scenes = time_frames(ctx, roots, size, repeats)
    rows = []
    for d in depths:
        scene = scenes[str(d)]
        (batch,) = scene.batches
        cells = tuple(s - 1 for s in batch.grids[0].shape[1:4]) if batch.path == "grid" else (1, 1, 1)
        compose_ms, draw_ms, cold_ms = medians[str(d)]
        rows.append(DepthRow(d, compose_ms, draw_ms, cold_ms, cells, shader_defines(batch.path, batch.normals),
                             scene.triangle_count))
    return rows


def format_trilinear(rows: list[TrilinearRow], depth_rows: list[DepthRow], machine: str, *,
                     size: tuple[int, int], repeats: int) -> str:
    """The ``studies.trilinear_speed`` report."""
    lines = [machine,
             f"trilinear scene graph (Knuth et al., section 6): {size[0]}x{size[1]} offscreen, no MSAA, "
             f"median of {repeats} frames; a frame = CPU composition (cached: only what changed since the "
             "previous frame is recomposed, here nothing) + upload + draw + finish; scratch: composing "
             "every leaf anew (a frame in which every transform changed)",
             f"{'scene':>8} {'objects':>7} {'triangles':>9} | {'linear':>6} {'compose':>8} {'draw':>8} | "
             f"{'trilin.':>7} {'compose':>8} {'draw':>8} {'paths (trilinear)':>22} | {'fps ratio':>9} "
             f"{'draw ratio':>10} | {'paper':>5} | {'grid err':>8} | {'scratch lin/tri':>15} {'ratio':>6}"]
    lines.append("-" * len(lines[-1]))
    for r in rows:
        p = r.paths["trilinear"]
        path_text = f"{p['affine']}a/{p['cuboid']}c/{p['grid']}g"
        paper = r.setup.paper_fps[1] / r.setup.paper_fps[0]
        lines.append(
            f"{r.setup.scene:>8} {r.setup.objects:>7} {r.triangles:>9} | {r.fps('linear'):>6.2f} "
            f"{r.compose_ms['linear']:>6.1f}ms {r.draw_ms['linear']:>6.1f}ms | {r.fps('trilinear'):>7.2f} "
            f"{r.compose_ms['trilinear']:>6.1f}ms {r.draw_ms['trilinear']:>6.1f}ms {path_text:>22} | "
            f"{r.ratio():>8.2f}x {r.draw_ratio():>9.2f}x | {paper:>5.2f} | {r.grid_error:>8.1e} | "
            f"{r.cold_ms['linear']:>5.1f}/{r.cold_ms['trilinear']:>5.1f}ms {r.scratch_ratio():>5.2f}x")
    lines.append("fps: frames/s; fps ratio = trilinear / linear (target >= 0.8); draw ratio: GPU part only; "
                 "paths: leaves drawn affine / one cuboid (Knuth, Kohlhammer & Kuijper, eq. 4) / 3D-texture grid; grid err: stated "
                 "approximation error of the root grid (scene units, objects have diameter 1)")
    if depth_rows:
        lines.append("")
        lines.append("shader cost vs depth: one sphere under nested 8^3 grids (twist/taper), composed per frame")
        lines.append(f"{'depth':>5} {'triangles':>9} {'compose ms':>10} {'scratch ms':>10} {'draw ms':>8} "
                     f"{'leaf grid':>9}  shader defines")
        for d in depth_rows:
            lines.append(f"{d.depth:>5} {d.triangles:>9} {d.compose_ms:>10.3f} {d.cold_ms:>10.3f} {d.draw_ms:>8.2f} "
                         f"{'x'.join(map(str, d.cells)):>9}  {d.defines}")
    return "\n".join(lines)


def trilinear_bench_report(ctx: moderngl.Context, *, size: tuple[int, int] = (512, 512), repeats: int = 16,
                           progress: Callable[[str], None] | None = None) -> str:
    """``python -m studies.trilinear_speed``: run both benchmarks and format the report."""
    if progress:
        progress("linear vs trilinear, three set-ups")
    rows = bench_trilinear(ctx, size=size, repeats=repeats)
    if progress:
        progress("depth 1 vs 8")
    depth_rows = bench_depth(ctx, size=size, repeats=repeats)
    return format_trilinear(rows, depth_rows, machine_line(ctx), size=size, repeats=repeats)


def main(argv: list[str] | None = None) -> int:
    """``python -m studies.trilinear_speed``: linear vs trilinear frames/s of the paper's set-ups."""
    from studies.common import gl_context, parse, parser

    args = parse(parser("trilinear_speed", "linear vs trilinear frames/s for the paper's three set-ups"), argv)
    with gl_context(args) as ctx:
        print(trilinear_bench_report(ctx))
    return 0


if __name__ == "__main__":
    from studies.common import run_main

    run_main(main)
