"""``python -m studies.step_profile``: where the foundation's step pass spends its time.

The pass of ``shaders/sim/verlet.frag`` is rebuilt stage by stage
(``studies/shaders/step_ablation.frag``, this study's own shader, not in the package): one fetch of the node's own position, then its
previous position and node data, the neighbour indices (or the offsets of a dense grid), the 18
neighbours' positions, the spring sums; each stage's ms/pass and its increment over the one
before show what the step is made of on this renderer. The full step (normals, damping,
gravity, pulls, fixed nodes) is measured alongside, with the index texture and with offsets.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import moderngl

from deformgl.bench.sim_speed import block_system, machine_line, stable_dt, timed
from deformgl.sim.backends.verlet_pass import FoundationVerlet
from deformgl.sim.backends.verlet_data import NodeTextures
from deformgl.grid.nodes import NEIGHBOUR_UNIT, CompactLayout
from deformgl.gl.programs import Program

__all__ = ["STAGES", "ProfileRow", "format_profile", "profile_step"]

#: The ablation shader's name (given to the preprocessor as text: it is not in the package).
ABLATION = "studies/step_ablation.frag"


def ablation_source() -> str:
    """The text of ``studies/shaders/step_ablation.frag``."""
    return (Path(__file__).parent / "shaders" / "step_ablation.frag").read_text(encoding="utf-8")


#: What each ablation stage adds (``STAGE`` define of step_ablation.frag).
STAGES = ("own position (pass floor)", "+ previous position, node data", "+ neighbour indices",
          "+ 18 neighbour positions", "+ spring sums")


@dataclass(frozen=True)
class ProfileRow:
    """One measured pass: grid name, nodes, neighbour lookup ("index" or "offsets"), what was
    run (a stage of :data:`STAGES` or "full step"), median ms per pass."""

    grid: str
    nodes: int
    lookup: str
    what: str
    ms: float


def _median_ms(ctx: moderngl.Context, run, passes: int, repeats: int) -> float:
    """Median ms per pass of ``run(passes)`` (finished), after a warm-up of 3 passes."""
    run(3)
    ctx.finish()

    def batch() -> None:
        run(passes)
        ctx.finish()
    return timed(batch, repeats) / passes * 1e3


def profile_step(ctx: moderngl.Context, *, grids=((27, 27, 27), (64, 64, 32)), passes: int = 30,
                 repeats: int = 7) -> list[ProfileRow]:
    """Ablation stages and the full step, with the index texture and with offsets, per grid."""
    rows = []
    for spec in grids:
        system = block_system(spec)
        name = "x".join(map(str, spec))
        for layout, lookup in (("indexed", "index"), ("compact", "offsets")):
            sim = FoundationVerlet.for_system(ctx, system, stable_dt(system, 0.2), layout=layout)
            try:
                full = ProfileRow(name, system.count, lookup, "full step",
                                  _median_ms(ctx, sim.step, passes, repeats))
                # the stages overwrite the state with what they compute: measured after the step
                textures = sim.textures
                if not isinstance(textures, NodeTextures):
                    raise TypeError(f"profile: layout {layout!r} gave {type(textures).__name__}")
                rows.extend(_stages(ctx, textures, name, system.count, lookup, passes, repeats))
                rows.append(full)
            finally:
                sim.release()
    return rows


def _stages(ctx: moderngl.Context, textures: NodeTextures, name: str, nodes: int, lookup: str,
            passes: int, repeats: int) -> list[ProfileRow]:
    layout = textures.layout
    if not isinstance(layout, CompactLayout):  # profile_step builds compact and indexed only
        raise TypeError(f"_stages needs a compact layout, got {type(layout).__name__}")
    dense = lookup == "offsets"
    rows = []
    for stage, what in enumerate(STAGES):
        if stage == 2 and dense:
            what = "+ neighbour offsets"
        program = Program(ctx, "sim/fullscreen.vert", ABLATION, defines={"STAGE": stage, "DENSE": dense},
                          chunks={ABLATION: ablation_source()})
        vao = ctx.vertex_array(program.gl, [])
        try:
            uniforms: dict[str, object] = {"u_position": 0, "u_previous": 1, "u_node": 2,
                                           "u_width_log2": int(layout.width).bit_length() - 1}
            if dense:
                uniforms.update(u_strides=layout.strides)
            else:
                uniforms["u_neighbours"] = NEIGHBOUR_UNIT
            members = program.members
            program.set(**{k: v for k, v in uniforms.items() if k in members})

            def run(n: int, vao=vao) -> None:
                # rotate the three state textures as the step does: each pass reads what the
                # one before wrote (llvmpipe then cannot overlap passes or keep a tile in cache
                # across them, which a pass drawn again into the same target would let it do)
                textures.bind_static(2)
                order = [0, 1, 2]
                for _ in range(n):
                    current, previous, spare = order
                    textures.state[current].use(0)
                    textures.state[previous].use(1)
                    textures.framebuffers[spare].use()
                    vao.render(moderngl.TRIANGLES, vertices=3)
                    order = [spare, current, previous]
            rows.append(ProfileRow(name, nodes, lookup, what, _median_ms(ctx, run, passes, repeats)))
        finally:
            vao.release()
            program.release()
    return rows


def format_profile(rows: list[ProfileRow], machine: str) -> str:
    """The table: ms/pass, increment over the stage before, share of the full step."""
    lines = [machine, "foundation step pass rebuilt stage by stage (studies/shaders/step_ablation.frag; spring "
             "sums: Mosegaard & Sørensen 2005, eq. 1/2); "
             "median ms per pass; share = increment / full step of the same lookup"]
    for grid in dict.fromkeys(r.grid for r in rows):
        for lookup in ("index", "offsets"):
            group = [r for r in rows if r.grid == grid and r.lookup == lookup]
            if not group:
                continue
            full = next(r.ms for r in group if r.what == "full step")
            lines.append(f"{grid} ({group[0].nodes} nodes), neighbours by {lookup}: full step {full:.3f} ms "
                         f"= {group[0].nodes / full / 1e3:.1f} M nodes/s")
            previous = 0.0
            for r in group:
                if r.what == "full step":
                    lines.append(f"  {'rest of the step (normals, forces, flags)':44s} {r.ms:8.3f} ms  "
                                 f"{r.ms - previous:+8.3f}  {(r.ms - previous) / full:6.1%}")
                    continue
                lines.append(f"  {r.what:44s} {r.ms:8.3f} ms  {r.ms - previous:+8.3f}  {(r.ms - previous) / full:6.1%}")
                previous = r.ms
    return "\n".join(lines)


def lattice_weights(ctx: moderngl.Context, *, grids=((27, 27, 27), (64, 64, 32)), steps: int = 30,
                    rounds: int = 7) -> list[tuple[str, int, float, float]]:
    """The full step of a material's calibrated lattice (per-spring weights, Young's modulus
    and density of gelatin; :func:`deformgl.sim.materials.lattice_system`), its weights fetched
    from the weight texture (5 RGBA32F fetches per node) or decoded from the node texture's
    levels code (``SPRING_WEIGHT_LEVELS``, the default): (grid, nodes, texture ms, levels ms),
    medians of ``rounds`` alternating rounds of ``steps`` steps."""
    import statistics
    import time

    import numpy as np

    from deformgl.grid.nodes import NodeGrid
    from deformgl.sim.materials import PRESETS, critical_dt, lattice_system

    out = []
    for spec in grids:
        grid = NodeGrid(np.zeros(3), 0.002, np.ones(spec, bool))
        system, _ = lattice_system(grid, PRESETS["gelatin"], fixed=grid.ijk[:, 1] == grid.ijk[:, 1].max())
        dt = 0.5 * critical_dt(PRESETS["gelatin"], grid.spacing, barrier=False)
        sims = {t: FoundationVerlet.for_system(ctx, system, dt, weight_texture=t) for t in (True, False)}
        times: dict[bool, list[float]] = {t: [] for t in sims}
        try:
            for sim in sims.values():
                sim.step(3)
            ctx.finish()
            for r in range(rounds):
                for t in ((True, False) if r % 2 == 0 else (False, True)):
                    t0 = time.perf_counter()
                    sims[t].step(steps)
                    ctx.finish()
                    times[t].append((time.perf_counter() - t0) / steps * 1e3)
        finally:
            for sim in sims.values():
                sim.release()
        out.append(("x".join(map(str, spec)), grid.count, statistics.median(times[True]),
                    statistics.median(times[False])))
    return out


def format_lattice_weights(rows: list[tuple[str, int, float, float]]) -> list[str]:
    lines = ["material lattice (per-spring weights of the calibrated lattice, gelatin), full step, median ms of "
             "alternating rounds: weights from the weight texture vs from the node texture's levels code "
             "(SPRING_WEIGHT_LEVELS)"]
    for name, nodes, texture_ms, levels_ms in rows:
        lines.append(f"  {name} ({nodes} nodes): texture {texture_ms:.3f} ms, levels {levels_ms:.3f} ms "
                     f"-> levels {texture_ms / levels_ms:.2f}x as fast")
    return lines


def profile_report(ctx: moderngl.Context) -> str:
    """``studies.step_profile``: the table for the 20k and 131k-node blocks, and the material lattice's
    weight texture against its levels code."""
    return "\n".join([format_profile(profile_step(ctx), machine_line(ctx)),
                      *format_lattice_weights(lattice_weights(ctx))])


def main(argv: list[str] | None = None) -> int:
    """``python -m studies.step_profile``: the step pass rebuilt stage by stage."""
    from studies.common import gl_context, parse, parser

    args = parse(parser("step_profile", "the step pass rebuilt stage by stage (own texels, neighbour lookup, "
                                         "18 neighbour fetches, spring sums), what each costs"), argv)
    with gl_context(args) as ctx:
        print(profile_report(ctx))
    return 0


if __name__ == "__main__":
    from studies.common import run_main

    run_main(main)
