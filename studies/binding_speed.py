"""Benchmark of :func:`deformgl.mapping.binding.bind`: the res3 dragon (and a 50,000-vertex
version of it) bound to a grid of about 20,000 nodes (``python -m studies.binding_speed``)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import trimesh

from deformgl.data import asset
from deformgl.grid.meshio import load_mesh
from deformgl.grid.nodes import NodeGrid
from deformgl.grid.surface import grid_surface
from deformgl.grid.voxelize import voxelize
from deformgl.mapping.binding import bind
from deformgl.sim.normals import rest_normals

#: The mesh the benchmark binds (the shipped res3 dragon).
BENCH_MESH = "dragon_vrip_res3.ply.gz"
"""The shipped mesh the binding benchmark binds by default (:func:`deformgl.data.asset`)."""
#: nodes_along_longest giving the res3 dragon a grid of about 20,000 nodes (19,455).
BENCH_NODES_ALONG_LONGEST = 64
BENCH_LARGE = 50_000


def _jittered_copies(vertices: np.ndarray, faces: np.ndarray, count: int,
                     seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A mesh of exactly ``count`` vertices: copies of the mesh, each jittered by a tenth of the
    mean edge length, the last one cut (faces using only its kept vertices)."""
    rng = np.random.default_rng(seed)
    edge = float(np.linalg.norm(vertices[faces[:, 1]] - vertices[faces[:, 0]], axis=1).mean())
    copies = -(-count // len(vertices))
    verts = np.concatenate([vertices + (rng.normal(scale=0.1 * edge, size=vertices.shape) if k else 0.0)
                            for k in range(copies)])[:count]
    tris = np.concatenate([faces + k * len(vertices) for k in range(copies)])
    return verts, tris[(tris < count).all(axis=1)]


def bench_binding(repeats: int = 3, *, mesh_path: str | os.PathLike[str] | None = None) -> str:
    """Time :func:`bind` of the res3 dragon (and a 50,000-vertex version) to a ~20,000-node grid.

    Args:
        repeats: timings per case (the median is reported).
        mesh_path: the mesh to bind (default: the shipped :data:`BENCH_MESH`).

    Returns:
        One line: node and surface counts, then vertex count and median binding time of each case.
    """
    source = asset(BENCH_MESH) if mesh_path is None else Path(mesh_path)
    mesh = load_mesh(source)
    lo, hi = mesh.bounds
    mesh = trimesh.Trimesh(mesh.vertices - (lo + hi) / 2, mesh.faces, process=False)
    vox = voxelize(mesh, nodes_along_longest=BENCH_NODES_ALONG_LONGEST, source=str(source))
    grid = NodeGrid(np.asarray(vox.origin), float(vox.spacing), np.asarray(vox.occupied))
    surface = grid_surface(grid)
    n = grid.count
    normals = rest_normals(grid)
    cases = [(np.asarray(mesh.vertices), np.asarray(mesh.faces)),
             _jittered_copies(np.asarray(mesh.vertices), np.asarray(mesh.faces), BENCH_LARGE)]
    parts = []
    for verts, tris in cases:
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            bind(verts, tris, grid.rest_positions, normals, surface, spacing=grid.spacing)
            times.append(time.perf_counter() - t0)
        parts.append(f"{len(verts):,} vertices {sorted(times)[len(times) // 2]:.2f} s")
    return (f"bind {source.name} to {n:,} nodes ({len(surface.nodes):,} on the surface, "
            f"{len(surface.triangles):,} triangles), median of {repeats}, {os.cpu_count()} CPUs: "
            + ", ".join(parts))


def main(argv: list[str] | None = None) -> int:
    """``python -m studies.binding_speed [--quick]``: binding time of the shipped meshes."""
    from deformgl.bench.sim_speed import machine_line
    from studies.common import gl_context, parse, parser

    args = parse(parser("binding_speed", "binding time of 23k- and 50k-vertex meshes to a 20k-node grid "
                                          "(--quick: one timing per case instead of three)"), argv)
    with gl_context(args) as ctx:
        print(machine_line(ctx))
    print(bench_binding(repeats=1 if args.quick else 3))
    return 0


if __name__ == "__main__":
    from studies.common import run_main

    run_main(main)
