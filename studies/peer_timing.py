"""Each CPU peer of ``deformgl bench sim --peers`` (Taichi, Warp, Numba) timed alone on the 20k-
and 131k-node blocks: set-up, the first (compiling) step, ms per step, threads and the cores it
kept busy: ``python -m studies.peer_timing`` (the 'peers' extra)."""

import time
from dataclasses import dataclass

from deformgl.bench.peers import PEERS, available_peers, make_stepper
from deformgl.sim.springs import SpringSystem
from deformgl.sim.scripted import Load


@dataclass
class PeerTiming:
    """One peer on one system.

    Attributes:
        peer: name; version: package version; nodes: N.
        ms_per_step: best of ``repeats`` runs of ``steps`` steps, after warm-up, JIT excluded.
        nodes_per_s: N / (s per step).
        setup_s: building the stepper (first use: import, init) without the kernel compile.
        jit_s: the first step, which compiles (or loads from the peer's kernel cache) the kernel.
        threads: worker threads the peer uses for a step.
        cpu_per_wall: process CPU time / wall time during the timed runs (how many cores it kept busy).
    """

    peer: str
    version: str
    nodes: int
    ms_per_step: float
    nodes_per_s: float
    setup_s: float
    jit_s: float
    threads: int
    cpu_per_wall: float


def bench_peers(system: SpringSystem, dt: float, steps: int = 20, *, peers=None, repeats: int = 3,
                loads: tuple[Load, ...] = ()) -> dict[str, PeerTiming]:
    """Time each available peer's step on ``system``.

    Each peer: build, one step (JIT, timed apart), a warm-up of ``steps`` steps, then the best of
    ``repeats`` runs of ``steps`` steps. Peers that cannot be imported are left out.
    """
    versions = available_peers()
    out = {}
    for peer in peers or PEERS:
        version = versions.get(peer)
        if version is None:
            continue
        t0 = time.perf_counter()
        stepper = make_stepper(peer, system, dt, loads)
        t1 = time.perf_counter()
        stepper.step(1)
        t2 = time.perf_counter()
        stepper.step(steps)
        best, cpu, wall = float("inf"), 0.0, 0.0
        for _ in range(repeats):
            c0, w0 = time.process_time(), time.perf_counter()
            stepper.step(steps)
            w = time.perf_counter() - w0
            cpu += time.process_time() - c0
            wall += w
            best = min(best, w)
        ms = best / steps * 1e3
        out[peer] = PeerTiming(peer, version, system.count, ms, system.count / (ms * 1e-3),
                               t1 - t0, t2 - t1, stepper.threads, cpu / wall)
    return out


def main(argv: list[str] | None = None) -> int:
    from deformgl.bench.sim_speed import block_system, cpu_line, stable_dt
    from studies.common import parse, parser

    p = parser("peer_timing", "each CPU peer's set-up, JIT and step time on the benchmark blocks")
    p.add_argument("--steps", type=int, default=20, help="steps per timing (default 20)")
    args = parse(p, argv)
    print(cpu_line())
    for spec in ((27, 27, 27),) if args.quick else ((27, 27, 27), (64, 64, 32)):
        system = block_system(spec)
        for t in bench_peers(system, stable_dt(system, 0.2), args.steps).values():
            print(f"{'x'.join(map(str, spec))} ({t.nodes} nodes) {t.peer} {t.version}: {t.ms_per_step:.3f} ms/step "
                  f"({t.nodes_per_s / 1e6:.1f} M nodes/s), set-up {t.setup_s:.2f} s, first step {t.jit_s:.2f} s, "
                  f"{t.threads} thread(s), {t.cpu_per_wall:.2f} cores busy")
    return 0


if __name__ == "__main__":
    from studies.common import run_main

    run_main(main)
