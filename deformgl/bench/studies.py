"""``deformgl bench``: speed as ratios against a baseline measured in the same process.

Timings include a ``ctx.finish()`` so the GPU work is really done; each figure is the median
of several repeats. Every report names the machine and the renderer.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass

import moderngl
import numpy as np

from deformgl.bench.accuracy import cpu_line
from deformgl.gl.context import context_info
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.backends.fragment import FragmentIntegrator
from deformgl.sim.simulation import NumpySimulation, Simulation
from deformgl.sim.springs import SpringSystem, from_grid, max_angular_frequency

#: The benchmark volumes: about 4k, 20k and 131k nodes in full blocks, and a ball of about 20k
#: nodes filling 52 % of its box (where drawing only around existing nodes matters).
SIM_GRIDS = ((16, 16, 16), (27, 27, 27), (64, 64, 32), "ball34")


def bench_occupancy(spec: tuple[int, int, int] | str) -> np.ndarray:
    """Occupancy of a benchmark grid: a full block of that shape, or ``"ballN"``: a ball in N^3."""
    if isinstance(spec, str):
        n = int(spec.removeprefix("ball"))
        c = (n - 1) / 2.0
        i, j, k = np.indices((n, n, n))
        return (i - c) ** 2 + (j - c) ** 2 + (k - c) ** 2 <= (n / 2.0) ** 2
    return np.ones(spec, bool)


def machine_line(ctx: moderngl.Context) -> str:
    """One line naming the CPU, core count and GL renderer."""
    info = context_info(ctx)
    return f"{cpu_line()}; renderer: {info.renderer}; GL {info.version}"


def timed(fn: Callable[[], None], repeats: int = 5) -> float:
    """Median wall time of ``fn`` in seconds."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def block_system(spec: tuple[int, int, int] | str, spacing: float = 0.01, *, k_flexion: float = 0.0,
                 damping: float = 1e-3) -> SpringSystem:
    """Benchmark body: a block or ball of nodes, top layer fixed, structural and shear springs of
    10 N/m (and flexion springs of ``k_flexion``), 1 g per node, velocity damping ``damping``."""
    grid = NodeGrid(np.zeros(3), spacing, bench_occupancy(spec))
    top = grid.ijk[:, 1] == grid.ijk[:, 1].max()
    return from_grid(grid, k_structural=10.0, k_shear=10.0, k_flexion=k_flexion, mass=1e-3, fixed=top,
                     velocity_damping=damping)


def fragment_verlet(ctx: moderngl.Context, system: SpringSystem, dt: float, **variant) -> FragmentIntegrator:
    """The fragment backend's Verlet fast path (Mosegaard & Sørensen 2005, section 3.1) of ``system``
    in a pass variant (``draw``, ``branch``, ``layout``)."""
    return FragmentIntegrator(ctx, system, None, "verlet", dt, path="foundation", **variant)


def stable_dt(system: SpringSystem, fraction: float) -> float:
    """``fraction`` of 1 / w_max (the bound of :func:`deformgl.sim.springs.max_angular_frequency`)."""
    return fraction / max_angular_frequency(system).omega


@dataclass
class SimRow:
    """One grid of ``bench sim``."""

    name: str
    nodes: int
    variant_ms: dict[str, float]
    numpy_ms: float


def bench_sim(ctx: moderngl.Context, *, steps: int = 40, grids=SIM_GRIDS, variants=None) -> list[SimRow]:
    """Fragment-pass Verlet step against the float64 NumPy reference on the same grids."""
    variants = variants or {
        "compact": dict(layout="compact"), "compact indexed": dict(layout="indexed"),
        "compact+branch": dict(layout="compact", branch=True), "blocked 1x2x2": dict(block=(1, 2, 2)),
        "atlas rects": dict(layout="atlas", draw="rects"), "atlas quad": dict(layout="atlas", draw="quad"),
        "atlas points": dict(layout="atlas", draw="points")}
    rows = []
    for spec in grids:
        system = block_system(spec)
        dt = stable_dt(system, 0.2)
        per_variant = {}
        for name, kw in variants.items():
            sim = fragment_verlet(ctx, system, dt, **kw)
            sim.step(3)
            ctx.finish()

            def run(sim: Simulation = sim) -> None:
                sim.step(steps)
                ctx.finish()

            per_variant[name] = timed(run) / steps * 1e3
            sim.release()
        ref = NumpySimulation(system, "verlet", dt)
        ref_steps = max(1, min(steps, int(2e5 // system.count)))
        numpy_ms = timed(lambda: ref.step(ref_steps), repeats=3) / ref_steps * 1e3
        name = spec if isinstance(spec, str) else "x".join(map(str, spec))
        rows.append(SimRow(name, system.count, per_variant, numpy_ms))
    return rows


def format_sim(rows: list[SimRow], machine: str) -> str:
    """The ``bench sim`` table."""
    names = list(rows[0].variant_ms)
    head = f"{'grid':>9} {'nodes':>7} | " + " | ".join(f"{n + ' ms/step':>20} {'Mnode/s':>8}" for n in names)
    head += f" | {'numpy ms/step':>13} | {'speed-up vs numpy':>17}"
    lines = [machine, "fragment pass, position Verlet, 18 neighbours (Mosegaard & Sørensen 2005, eq. 1-3); baseline: float64 "
             "NumPy reference in this process", head, "-" * len(head)]
    for r in rows:
        cells = " | ".join(f"{ms:>20.3f} {r.nodes / ms / 1e3:>8.1f}" for ms in r.variant_ms.values())
        best = min(r.variant_ms.values())
        lines.append(f"{r.name:>9} {r.nodes:>7} | {cells} | {r.numpy_ms:>13.2f} | {r.numpy_ms / best:>16.1f}x")
    return "\n".join(lines)


@dataclass
class RenderRow:
    """One draw path of ``bench render``."""

    name: str
    ms: float


def bench_render(ctx: moderngl.Context, scene_path, *, size: int = 1024, samples: int = 4,
                 repeats: int = 7, frame_size: int = 512, frame_steps: int = 15):
    """Draw paths of a mapped scene against the static mesh, and a simulate+draw frame.

    Returns:
        (rows, frame_ms, info): ms/frame of each draw path at ``size``² with ``samples``x MSAA;
        {MSAA samples: ms} of ``frame_steps`` simulation steps plus one curvature-corrected draw
        at ``frame_size``², with ``samples``x MSAA and without; and a dict of scene sizes, with "budgets": the frame split per AA mode
        (:func:`deformgl.bench.aa.frame_budgets`).
    """
    from deformgl.render.mapped import MappedMeshPass, StaticMeshPass, closed_front_face
    from deformgl.render.mapped_setup import get_binding, mapped_vertices
    from deformgl.scene.pipeline import RENDER_MAPPING_PASS, build_scene_model, scene_lighting, scene_view
    from deformgl.sim.normals import rest_normals
    from deformgl.render.passes import GridSurfacePass, RenderTarget
    from deformgl.scene.schema import load_scene
    from deformgl.grid.surface import grid_surface

    scene = load_scene(scene_path)
    built = build_scene_model(scene)
    sim = FragmentIntegrator(ctx, built.system, built.grid, "verlet", scene.physics.dt, loads=built.loads,
                             path="foundation")
    sim.step(50)
    surface = grid_surface(built.grid)
    binding = get_binding(built.mesh, built.grid, surface, use_cache=True, uv=None)
    node_normals = rest_normals(built.grid)
    mesh = built.mesh
    # back faces culled as [render] cull = true does, where the mesh is closed (render.mapped.closed_front_face)
    front = closed_front_face(mesh.vertices, mesh.faces)
    passes: dict[str, StaticMeshPass | GridSurfacePass | MappedMeshPass] = {
        "static mesh": StaticMeshPass(ctx, mesh.vertices, mesh.vertex_normals, mesh.faces),
        "one-to-one": GridSurfacePass(ctx, built.grid, sim.textures.layout),
    }
    for mode in ("constant", "curvature"):
        data = mapped_vertices(binding, mode, built.grid.rest_positions, node_normals)
        for mapping_pass, suffix in (("vertex", ""), ("feedback", " 2-stage"), ("fragment", " fragment")):
            passes[mode + suffix] = MappedMeshPass(ctx, built.grid, sim.textures.layout, mesh.faces, data,
                                                   mapping_pass=mapping_pass)
        if mode == "curvature" and front is not None:  # what culling the back faces saves
            passes["curvature, culled"] = MappedMeshPass(ctx, built.grid, sim.textures.layout, mesh.faces, data,
                                                         front_face=front, mapping_pass=RENDER_MAPPING_PASS)
    view = scene_view(dataclasses.replace(scene, render=dataclasses.replace(scene.render, size=(size, size))),
                      built.bbox)
    lighting = scene_lighting(scene)
    target = RenderTarget(ctx, (size, size), samples)
    rows = []
    try:
        for name, p in passes.items():
            def draw(p=p) -> None:
                target.begin((1.0, 1.0, 1.0))
                if name == "static mesh":
                    p.draw(view, lighting)
                else:
                    p.draw(sim.position_texture, view, lighting)
                ctx.finish()
            draw()
            rows.append(RenderRow(name, timed(draw, repeats) * 1e3))
        frame_ms = {}
        # the frame as `deformgl render` draws it (its mapping pass)
        curvature = passes["curvature" + {"vertex": "", "feedback": " 2-stage", "fragment": " fragment"}[RENDER_MAPPING_PASS]]
        if not isinstance(curvature, MappedMeshPass):
            raise TypeError("bench_render: the curvature pass is not a MappedMeshPass")
        for frame_samples in (samples, 0):
            small = RenderTarget(ctx, (frame_size, frame_size), frame_samples)
            try:
                def frame() -> None:
                    sim.step(frame_steps)
                    small.begin((1.0, 1.0, 1.0))
                    curvature.draw(sim.position_texture, view, lighting)
                    ctx.finish()
                frame()
                frame_ms[frame_samples] = timed(frame, repeats) * 1e3
            finally:
                small.release()
        from deformgl.bench.aa import frame_budgets, reference_name

        culled = passes.get("curvature, culled")
        budgets = frame_budgets(ctx, lambda: sim.step(frame_steps),
                                lambda: curvature.draw(sim.position_texture, view, lighting), frame_size,
                                _rgb(scene.render.background), repeats,
                                culled=None if not isinstance(culled, MappedMeshPass) else
                                lambda: culled.draw(sim.position_texture, view, lighting))
    finally:
        target.release()
        for p in passes.values():
            p.release()
        sim.release()
    info = {"faces": len(mesh.faces), "vertices": len(mesh.vertices), "nodes": built.grid.count,
            "size": size, "samples": samples, "frame_size": frame_size, "frame_steps": frame_steps,
            "budgets": budgets, "reference": reference_name(ctx), "culled": front is not None,
            "mapping_pass": RENDER_MAPPING_PASS,
            "layout": "compact" if sim.block is None else "blocks of " + "x".join(map(str, sim.block))}
    return rows, frame_ms, info


def _rgb(c) -> tuple[float, float, float]:
    return float(c[0]), float(c[1]), float(c[2])


def format_render(rows: list[RenderRow], frame_ms: dict[int, float], info: dict, machine: str) -> str:
    """The ``bench render`` table."""
    base = rows[0].ms
    lines = [machine,
             f"{info['vertices']} vertices / {info['faces']} faces on {info['nodes']} nodes; "
             f"{info['size']}x{info['size']}, {info['samples']}x MSAA; baseline: the static mesh; "
             "mappings in the drawing vertex shader (the paper's way); 2-stage: mapped once per vertex by "
             "transform feedback, then drawn; fragment: mapped once per vertex in a fragment pass, then drawn "
             f"(the frame below: {info.get('mapping_pass', 'vertex')}, as `deformgl render` draws); culled: back faces culled ([render] cull = true"
             f"{'' if info.get('culled') else '; not offered: the mesh is not closed'})",
             f"{'draw path':>20} | {'ms/frame':>9} | {'frames/s':>8} | {'rate vs static':>14}",
             "-" * 62]
    for r in rows:
        lines.append(f"{r.name:>20} | {r.ms:>9.2f} | {1e3 / r.ms:>8.1f} | {base / r.ms:>13.2f}x")
    for samples, ms in frame_ms.items():
        msaa = f"{samples}x MSAA" if samples else "no MSAA"
        lines.append(f"frame = {info['frame_steps']} simulation steps ({info.get('layout', 'compact')}) + one curvature-corrected draw at "
                     f"{info['frame_size']}x{info['frame_size']}, {msaa}: {ms:.1f} ms = {1e3 / ms:.1f} frames/s "
                     f"(the paper's 2005 GPU: 25 frames/s)")
    if "budgets" in info:
        from deformgl.bench.aa import format_budgets

        lines += format_budgets(info["budgets"], info)
    return "\n".join(lines)


#: ``bench integrators`` workloads: the paper's cloths (Movania & Feng 2012, section 5) and the
#: 20k / 131k-node volumes of ``bench sim``.
INTEGRATOR_CLOTHS = (64, 256, 1024, 2048)
INTEGRATOR_VOLUMES = ((27, 27, 27), (64, 64, 32))


@dataclass
class IntegratorRow:
    """One workload of ``bench integrators``: ms/step and bytes/node per (backend, integrator)."""

    name: str
    nodes: int
    steps: int
    baseline_ms: float
    ms: dict[tuple[str, str], float]
    bytes_per_node: dict[tuple[str, str], float]


def cloth_system(n: int, spacing: float = 0.01):
    """The benchmark cloth: n x n nodes, two corners fixed, structural, shear and flexion springs."""
    from deformgl.sim.springs import cloth

    fixed = np.zeros(n * n, bool)
    fixed[[0, (n - 1) * n]] = True  # corners (0, 0) and (n-1, 0)
    return cloth(n, n, spacing, k_structural=10.0, k_shear=10.0, k_flexion=2.0, mass=np.full(n * n, 1e-3),
                 fixed=fixed, gravity=(0.0, -9.81, 0.0), velocity_damping=1e-4)


def _integrator_workloads(cloths, volumes):
    """(name, grid, system, baseline system: the same without flexion springs) of each workload."""
    for n in cloths:
        system = cloth_system(n)
        grid = system.grid
        base = from_grid(grid, k_structural=10.0, k_shear=10.0, mass=1e-3, fixed=system.fixed,
                         velocity_damping=1e-4)
        yield f"{n}x{n} cloth", grid, system, base
    for spec in volumes:
        system = block_system(spec, k_flexion=2.0)
        yield "x".join(map(str, spec)) + " volume", system.grid, system, block_system(spec)


def bench_integrators(ctx: moderngl.Context, *, cloths=INTEGRATOR_CLOTHS, volumes=INTEGRATOR_VOLUMES,
                      steps: int = 20, backends=("fragment", "feedback", "numpy"),
                      node_steps: float = 2e6, progress: Callable[[str], None] | None = None) -> list[IntegratorRow]:
    """Every integrator on every backend on each workload, against the foundation's fragment-pass
    Verlet of the same grid (the baseline, measured in the same run).

    Steps per timing: ``steps``, fewer on big grids (about ``node_steps`` node-steps, at least 2)
    so that 2048^2 finishes; the NumPy reference gets a tenth of that.
    """
    from deformgl.sim.backends.feedback import FeedbackSimulation
    from deformgl.sim.backends.fragment import FragmentIntegrator
    from deformgl.sim.integrators import EXPLICIT_INTEGRATORS, initial_state, step as numpy_step
    from deformgl.sim.springs import max_angular_frequency

    rows = []
    for name, grid, system, base_system in _integrator_workloads(cloths, volumes):
        if progress is not None:
            progress(name)
        n_steps = max(2, min(steps, int(node_steps // grid.count)))
        dt = 0.5 / max_angular_frequency(system).omega
        base = fragment_verlet(ctx, base_system, dt, layout="compact")  # (one node per fragment, as the stages)
        try:
            base.step(2)
            ctx.finish()

            def run_base() -> None:
                base.step(n_steps)
                ctx.finish()
            baseline = timed(run_base, 3) / n_steps * 1e3
        finally:
            base.release()
        ms, per_node = {}, {}
        state = initial_state(system, dt)
        for backend in backends:
            for integrator in EXPLICIT_INTEGRATORS:
                if backend == "numpy":
                    k = max(1, n_steps // 10)
                    holder = [state]

                    def run_numpy() -> None:
                        for i in range(k):
                            holder[0] = numpy_step(system, integrator, holder[0], dt, i * dt)
                    ms[backend, integrator] = timed(run_numpy, 1 if grid.count > 3e5 else 3) / k * 1e3
                    continue
                sim: FragmentIntegrator | FeedbackSimulation
                if backend == "fragment":
                    sim = FragmentIntegrator(ctx, system, grid, integrator, dt, state=state)
                else:
                    sim = FeedbackSimulation(ctx, system, integrator, dt, state=state)
                try:
                    sim.step(2)
                    ctx.finish()

                    def run_gl() -> None:
                        sim.step(n_steps)
                        ctx.finish()
                    ms[backend, integrator] = timed(run_gl, 3) / n_steps * 1e3
                    per_node[backend, integrator] = sim.bytes_per_node
                finally:
                    sim.release()
        rows.append(IntegratorRow(name, grid.count, n_steps, baseline, ms, per_node))
    return rows


def format_integrators(rows: list[IntegratorRow], machine: str) -> str:
    """The ``bench integrators`` table: ms/step, ratio to the baseline, GPU bytes per node."""
    lines = [machine, "structural + shear + flexion springs (k 10/10/2 N/m), velocity damping; cloths with two "
             "corners fixed, volumes with the top layer fixed; baseline: the foundation's fragment-pass "
             "position Verlet of the same grid (structural + shear), same run; ratio = baseline / ms "
             "(> 1: faster than the baseline)"]
    for r in rows:
        lines.append(f"{r.name} ({r.nodes} nodes, {r.steps} steps per timing): baseline fragment Verlet "
                     f"{r.baseline_ms:.3f} ms/step")
        lines.append(f"  {'backend':>9} {'integrator':>14} | {'ms/step':>9} | {'vs baseline':>11} | {'bytes/node':>10}")
        for (backend, name), ms in r.ms.items():
            per_node = r.bytes_per_node.get((backend, name))
            lines.append(f"  {backend:>9} {name:>14} | {ms:>9.3f} | {r.baseline_ms / ms:>10.3f}x | "
                         f"{'-' if per_node is None else f'{per_node:.0f}':>10}")
    return "\n".join(lines)


def peers_report(ctx: moderngl.Context, *, steps: int = 40, grids=((27, 27, 27), (64, 64, 32)),
                 rounds: int = 7) -> str:
    """``bench sim --peers``: the foundation's fragment Verlet step, on the compact layout and on the
    blocked layout it picks by itself (several nodes per fragment), against the same step in Taichi
    (CPU), NVIDIA Warp (CPU) and Numba (``parallel=True``) on the same grids, in the same process. All steppers of a grid
    are built and warmed up first; then ``rounds`` rounds time ``steps`` steps of each in turn,
    so load from other processes hits all alike. Best and median of the rounds; ratios are
    fragment throughput / peer throughput, of the medians."""
    from deformgl.bench.peers import PeerStepper, available_peers, make_stepper, peer_import_errors

    def peer_run(st: PeerStepper) -> Callable[[], None]:
        def run() -> None:
            st.step(steps)
        return run

    lines = [machine_line(ctx), "same 18-neighbour position-Verlet step (Mosegaard & Sørensen 2005, eq. 1/2, damping, gravity, fixed "
             f"nodes) in float32; {rounds} alternating rounds of {steps} steps, best / median ms per step; "
             "ratio = fragment nodes/s / peer nodes/s of the medians (> 1: the fragment pass is faster)"]
    for peer, reason in peer_import_errors().items():
        lines.append(f"{peer}: not installed ({reason}); pip install 'deformgl[peers]'")
    versions = {p: v for p, v in available_peers().items() if v is not None}
    if not versions:
        return "\n".join(lines)
    for spec in grids:
        system = block_system(spec)
        dt = stable_dt(system, 0.2)
        sims = {"fragment": fragment_verlet(ctx, system, dt, layout="compact"),
                "blocked": fragment_verlet(ctx, system, dt)}
        steppers: dict[str, PeerStepper] = {}
        try:
            for peer in versions:
                steppers[peer] = make_stepper(peer, system, dt)

            def run_fragment(sim: FragmentIntegrator) -> Callable[[], None]:
                def run() -> None:
                    sim.step(steps)
                    ctx.finish()
                return run
            runs: dict[str, Callable[[], None]] = {name: run_fragment(sim) for name, sim in sims.items()}
            runs.update({peer: peer_run(st) for peer, st in steppers.items()})
            for run in runs.values():  # JIT and warm-up
                run()
            times: dict[str, list[float]] = {name: [] for name in runs}
            for r in range(rounds):
                for name in (list(runs) if r % 2 == 0 else list(reversed(runs))):
                    t0 = time.perf_counter()
                    runs[name]()
                    times[name].append((time.perf_counter() - t0) / steps * 1e3)
            block = sims["blocked"].block
        finally:
            for sim in sims.values():
                sim.release()
            for st in steppers.values():
                st.release()
        best = {name: min(t) for name, t in times.items()}
        median = {name: statistics.median(t) for name, t in times.items()}
        name = "x".join(map(str, spec))
        shape = "compact" if block is None else "x".join(map(str, block))
        lines.append(f"{name} ({system.count} nodes): fragment (compact) {best['fragment']:.3f} / "
                     f"{median['fragment']:.3f} ms/step ({system.count / median['fragment'] / 1e3:.1f} M nodes/s); "
                     f"blocked ({shape}, the default) {best['blocked']:.3f} / {median['blocked']:.3f} ms/step "
                     f"({system.count / median['blocked'] / 1e3:.1f} M nodes/s) -> blocked / compact = "
                     f"{median['fragment'] / median['blocked']:.2f}x")
        for peer, st in steppers.items():
            layer = f" ({st.threading_layer} layer)" if hasattr(st, "threading_layer") else ""
            lines.append(f"  {peer} {versions[peer]} CPU, {st.threads} thread(s){layer}: {best[peer]:.3f} / "
                         f"{median[peer]:.3f} ms/step ({system.count / median[peer] / 1e3:.1f} M nodes/s) "
                         f"-> fragment / {peer} = {median[peer] / median['fragment']:.2f}x, "
                         f"blocked / {peer} = {median[peer] / median['blocked']:.2f}x")
    return "\n".join(lines)