"""``deformgl bench profile``: where the foundation's step pass spends its time.

The pass of ``shaders/sim/verlet.frag`` is rebuilt stage by stage
(``shaders/profile/step_ablation.frag``): one fetch of the node's own position, then its
previous position and node data, the neighbour indices (or the offsets of a dense grid), the 18
neighbours' positions, the spring sums; each stage's ms/pass and its increment over the one
before show what the step is made of on this renderer. The full step (normals, damping,
gravity, pulls, fixed nodes) is measured alongside, with the index texture and with offsets.
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl

from deformgl.bench.studies import block_system, fragment_verlet, machine_line, stable_dt, timed
from deformgl.sim.backends.foundation import NodeTextures
from deformgl.grid.nodes import NEIGHBOUR_UNIT, CompactLayout
from deformgl.gl.programs import Program

__all__ = ["STAGES", "ProfileRow", "format_profile", "profile_step"]

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
            sim = fragment_verlet(ctx, system, stable_dt(system, 0.2), layout=layout)
            try:
                full = ProfileRow(name, system.count, lookup, "full step",
                                  _median_ms(ctx, sim.step, passes, repeats))
                # the stages overwrite the state with what they compute: measured after the step
                rows.extend(_stages(ctx, sim.foundation.textures, name, system.count, lookup, passes, repeats))
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
        program = Program(ctx, "sim/fullscreen.vert", "profile/step_ablation.frag",
                          defines={"STAGE": stage, "DENSE": dense})
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
    lines = [machine, "foundation step pass rebuilt stage by stage (shaders/profile/step_ablation.frag; spring "
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


def profile_report(ctx: moderngl.Context) -> str:
    """``bench profile``: the table for the 20k and 131k-node blocks."""
    return format_profile(profile_step(ctx), machine_line(ctx))
