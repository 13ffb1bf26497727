"""The lattice on a real mesh against finite elements of the mesh itself:
``python -m studies.mesh_accuracy`` (the 'fem' extra: scikit-fem, PyAMG, tetgen, pymeshfix,
manifold3d; tetgen and pymeshfix wrap AGPL code, TetGen and MeshFix, which is why they stay in
an optional extra).

`python -m studies.accuracy` measures boxes, whose grids it builds directly. A real mesh goes through the
cells' fill (:mod:`deformgl.grid.fill`: each cell carries the part of the mesh inside it, issue
28). This measures what the lattice then gives, as the issue defines it: the mesh made one
watertight solid once (pymeshfix; the finned bar's intersecting shells merged by manifold3d's
union), E = 1 MPa (the sag stays linear), rho = 1000 kg/m^3, nu = 1/4, its lowest 5 % in y held,
gravity along -y.

* **FEM of the mesh**: tetgen's quality tetrahedralisation of the repaired surface (the surface
  kept, ``nobisect``: the mesh's vertices are the first nodes), refined inside by a maximum
  volume, quadratic (P2) tetrahedra in scikit-fem, conjugate gradients preconditioned by PyAMG to
  a relative residual of 1e-10 (the rigid modes as its near null space; a sparse direct solve
  where that misses, as on the finned bar's thin fin); the dofs (at the nodes and the edge
  midpoints) with y at most 5 % of the height above the lowest vertex held. Read at the mesh's
  vertices.
* **The lattice**: the product's scene path (:func:`deformgl.scene.pipeline.build_scene_model`:
  the cells' fill at ``nodes_along_longest``, the calibrated lattice of
  :func:`deformgl.sim.materials.lattice_system` carrying it, ``[[physics.fixed]] below y 0.05``
  selecting the material below the plane), its static rest under its weight
  (:func:`settled_displacement`: implicit Euler damped to rest, what a settled run reaches),
  read at the mesh's vertices through the "auto" mapping
  (:func:`deformgl.mapping.bases.map_vertices` on the product's binding: Mosegaard & Sørensen
  2005, eq. 9, the curvature-corrected basis where it is reliable, the constant one elsewhere).

Figures: the mean over the vertices of the vertical sag, its largest, the topmost vertex's, and
the lattice's mass over the mesh's (rho times its volume).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from deformgl.data import scenes_dir
from deformgl.errors import DeformglError
from deformgl.grid.meshio import load_mesh

__all__ = ["MeshSag", "fem_sag", "lattice_sag", "repaired_mesh", "require_mesh_fem"]

YOUNGS_MODULUS = 1.0e6   # Pa
DENSITY = 1000.0         # kg/m^3
POISSON = 0.25
HOLD = 0.05              # the held part of the height, from the lowest vertex
G = 9.81
#: the most free dofs the FEM solves directly where PyAMG's CG misses its tolerance
DIRECT_DOFS = 400_000
#: the meshes measured (files in the scenes' assets): the dragon, and the finned bar (a 10 cm
#: bar with a fin 2 mm thick, two closed shells that intersect, merged by a boolean union).
MESHES = {"dragon": "dragon_vrip_res4.ply.gz", "finned_bar": "finned_bar.obj"}
_MODULES = ("skfem", "pyamg", "tetgen", "pymeshfix", "manifold3d")


def require_mesh_fem() -> None:
    """DeformglError naming the extra unless scikit-fem, PyAMG, tetgen, pymeshfix and manifold3d
    import."""
    missing = []
    for module in _MODULES:
        try:
            __import__(module)
        except ImportError:
            missing.append(module)
    if missing:
        raise DeformglError(f"the FEM of a mesh needs {', '.join(missing)}: pip install 'deformgl[fem]'")


@dataclass(frozen=True)
class MeshSag:
    """Vertical sag (m, down positive) of a mesh's vertices: mean, largest, the topmost vertex's;
    with the size of the model (tetrahedra or nodes), its mass over the mesh's, and seconds."""

    mean: float
    largest: float
    top: float
    size: int
    mass_ratio: float
    seconds: float
    #: (V,) each vertex's sag, m, where the model gives it (the FEM), else None
    vertex_sag: np.ndarray | None = None


def repaired_mesh(name: str) -> trimesh.Trimesh:
    """The mesh ``name`` (:data:`MESHES`) made one watertight solid: closed shells that intersect
    merged by manifold3d's boolean union, a leaky surface closed by pymeshfix (as it is, if it
    already is one closed shell)."""
    require_mesh_fem()
    import pymeshfix  # type: ignore[import-untyped,import-not-found,unused-ignore]

    mesh = load_mesh(scenes_dir() / "assets" / MESHES[name])
    if mesh.is_watertight and mesh.body_count > 1:
        return _union(mesh, MESHES[name])
    if mesh.is_watertight:
        return trimesh.Trimesh(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces), process=False)
    v, f = pymeshfix.clean_from_arrays(np.ascontiguousarray(mesh.vertices, dtype=np.float64),
                                       np.ascontiguousarray(mesh.faces, dtype=np.int32))
    fixed = trimesh.Trimesh(v, f, process=False)
    if not fixed.is_watertight:
        raise DeformglError(f"{MESHES[name]}: pymeshfix did not make it watertight")
    return fixed


def _union(mesh: trimesh.Trimesh, name: str) -> trimesh.Trimesh:
    """The boolean union of a mesh's closed shells (manifold3d), one closed shell."""
    import manifold3d  # type: ignore[import-untyped,import-not-found,unused-ignore]

    solid = None
    for part in mesh.split(only_watertight=False):
        shell = manifold3d.Manifold(manifold3d.Mesh(vert_properties=np.asarray(part.vertices, np.float32),
                                                    tri_verts=np.asarray(part.faces, np.uint32)))
        solid = shell if solid is None else solid + shell
    out = solid.to_mesh()  # type: ignore[union-attr]  # a watertight mesh has a part
    merged = trimesh.Trimesh(np.asarray(out.vert_properties)[:, :3].astype(np.float64), np.asarray(out.tri_verts),
                             process=False)
    if not merged.is_watertight or merged.body_count != 1:
        raise DeformglError(f"{name}: the union of its shells is not one closed shell")
    return merged


def _held(y: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    lo, hi = float(vertices[:, 1].min()), float(vertices[:, 1].max())
    return y <= lo + HOLD * (hi - lo)


def _figures(vertices: np.ndarray, sag: np.ndarray) -> tuple[float, float, float]:
    return float(sag.mean()), float(sag.max()), float(sag[int(np.argmax(vertices[:, 1]))])


def fem_sag(mesh: trimesh.Trimesh, *, refine: int = 0) -> MeshSag:
    """The mesh's P2 tetrahedral FEM (module docstring). ``refine`` 0: tetgen's quality mesh of
    the surface as it is; k > 0: tetrahedra of at most ``3^-k`` of the volume / 25,000 inside."""
    require_mesh_fem()
    import pyamg  # type: ignore[import-untyped,import-not-found,unused-ignore]
    import tetgen  # type: ignore[import-untyped,import-not-found,unused-ignore]
    from skfem import (Basis, BilinearForm, ElementTetP2, ElementVector,  # type: ignore[import-untyped,import-not-found,unused-ignore]
                       LinearForm, MeshTet, asm, condense)
    from skfem.helpers import ddot, sym_grad, trace  # type: ignore[import-untyped,import-not-found,unused-ignore]

    start = time.perf_counter()
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int32)
    options = {"order": 1, "mindihedral": 10.0, "minratio": 1.5, "nobisect": True, "quiet": True}
    if refine:
        options.update(maxvolume=float(mesh.volume) / 25000.0 / 3.0 ** refine, fixedvolume=True)
    nodes, elems = tetgen.TetGen(v, f).tetrahedralize(**options)[:2]
    if not np.allclose(nodes[:len(v)], v):
        raise DeformglError("tetgen moved the mesh's vertices (the surface must be kept)")
    tets = MeshTet(np.ascontiguousarray(nodes.T, np.float64), np.ascontiguousarray(elems.T, np.int64))
    basis = Basis(tets, ElementVector(ElementTetP2()), intorder=4)
    lam = YOUNGS_MODULUS * POISSON / ((1.0 + POISSON) * (1.0 - 2.0 * POISSON))
    mu = YOUNGS_MODULUS / (2.0 * (1.0 + POISSON))

    @BilinearForm
    def elasticity(u, w, _):
        eu, ew = sym_grad(u), sym_grad(w)
        return 2.0 * mu * ddot(eu, ew) + lam * trace(eu) * trace(ew)

    @LinearForm
    def weight(w, _):
        return -DENSITY * G * w[1]

    stiffness, load = asm(elasticity, basis), asm(weight, basis)
    held = np.flatnonzero(_held(basis.doflocs[1], v))  # each dof by its own location (nodes and edge midpoints)
    k_free, f_free, _, free = condense(stiffness, load, D=held)
    # the near null space of elasticity (translations, rotations) per dof: x y z interleaved
    component = np.arange(stiffness.shape[0]) % 3
    if not all(np.all(component[basis.nodal_dofs[c]] == c) for c in range(3)):
        raise DeformglError("mesh FEM: the vector dofs are not interleaved x, y, z")
    x = basis.doflocs
    modes = np.zeros((stiffness.shape[0], 6))
    for c in range(3):
        modes[component == c, c] = 1.0
    for mode, (a, b) in enumerate(((0, 1), (1, 2), (2, 0)), start=3):  # rotation in the (a, b) plane
        modes[component == a, mode] = -x[b, component == a]
        modes[component == b, mode] = x[a, component == b]
    solver = pyamg.smoothed_aggregation_solver(k_free.tocsr(), B=modes[free])
    residuals: list[float] = []
    u_free = solver.solve(f_free, tol=1e-10, accel="cg", maxiter=2000, residuals=residuals)
    if residuals and residuals[-1] > 2e-10 * float(np.linalg.norm(f_free)):
        # a thin plate (the finned bar's fin, one or two tetrahedra thick) defeats the aggregation:
        # a sparse direct solve where it fits
        if len(f_free) > DIRECT_DOFS:
            raise DeformglError(f"mesh FEM: CG stopped at a relative residual of "
                                f"{residuals[-1] / float(np.linalg.norm(f_free)):.1e} (1e-10 asked)")
        from scipy.sparse.linalg import spsolve

        u_free = spsolve(k_free.tocsc(), f_free)
        residual = float(np.linalg.norm(k_free @ u_free - f_free)) / float(np.linalg.norm(f_free))
        if residual > 1e-8:  # round-off of a thin plate's condition number, not a stopped iteration
            raise DeformglError(f"mesh FEM: the direct solve's relative residual is {residual:.1e} (1e-8 allowed)")
    u = np.zeros(stiffness.shape[0])
    u[free] = u_free
    sag = -u[basis.nodal_dofs[1, :len(v)]]
    mean, largest, top = _figures(v, sag)
    return MeshSag(mean, largest, top, int(elems.shape[0]), 1.0, time.perf_counter() - start, sag)


def settled_displacement(system, *, dt: float = 0.05, steps: int = 1000, tolerance: float = 1e-9) -> np.ndarray:
    """(N, 3) displacement in m where the lattice comes to rest under its weight: implicit Euler
    (NumPy, float64) at a step far beyond the body's lowest period, so it is damped to rest in a
    few steps, until no node moves more than ``tolerance`` times the largest displacement in a
    step. (A linear static solve does not do: a node in no full cell can be a mechanism, which
    only its mass holds in a step, and the geometry at rest.)"""
    from deformgl.sim.implicit import ImplicitNumpySimulation

    sim = ImplicitNumpySimulation(system, dt, cg_iterations=2000, cg_tolerance=1e-10)
    previous = system.rest_positions
    for _ in range(steps):
        sim.step(1)
        if sim.unconverged:
            raise DeformglError(f"settling the lattice: CG missed its tolerance (worst residual {sim.worst_residual:.1e})")
        x = sim.positions()
        moved = float(np.abs(x - previous).max())
        previous = x
        if moved <= tolerance * max(float(np.abs(x - system.rest_positions).max()), 1e-300):
            return x - system.rest_positions
    raise DeformglError(f"the lattice did not come to rest in {steps} steps of {dt} s (last step moved {moved:.2e} m)")


def scene_model(mesh: trimesh.Trimesh, nodes_along: int, *, material: str = "", physics: str = "",
                with_scene: bool = False):
    """The product's scene model of the workload (module docstring) at ``nodes_along`` nodes along
    the longest side; ``material`` and ``physics``: further lines of those tables. ``with_scene``:
    the pair (model, the loaded scene)."""
    from deformgl.scene.pipeline import build_scene_model
    from deformgl.scene.schema import load_scene

    with tempfile.TemporaryDirectory() as folder:
        mesh.export(Path(folder) / "mesh.ply")
        scene_file = Path(folder) / "scene.toml"
        scene_file.write_text(
            f'[mesh]\npath = "mesh.ply"\n[grid]\nnodes_along_longest = {int(nodes_along)}\n'
            f"[material]\nyoungs_modulus = {YOUNGS_MODULUS}\ndensity = {DENSITY}\npoissons_ratio = {POISSON}\n{material}"
            f'[physics]\n{physics}gravity = [0.0, {-G}, 0.0]\n[[physics.fixed]]\nregion = "below"\naxis = "y"\n'
            f"at = {HOLD}\n")
        scene = load_scene(scene_file)
        model = build_scene_model(scene)
        return (model, scene) if with_scene else model


def lattice_sag(mesh: trimesh.Trimesh, nodes_along: int) -> MeshSag:
    """The lattice of the product's scene path at ``nodes_along`` nodes along the longest side
    (module docstring), read at the mesh's vertices through the auto mapping."""
    from deformgl.grid.surface import grid_surface
    from deformgl.mapping.bases import map_vertices
    from deformgl.render.mapped_setup import get_binding
    from deformgl.sim.normals import unit_sums

    start = time.perf_counter()
    model = scene_model(mesh, nodes_along)
    system, grid = model.system, model.grid
    u = settled_displacement(system)
    binding = get_binding(model.mesh, grid, grid_surface(grid), use_cache=False, uv=None)
    offset = np.where(binding.curvature_ok[:, None], binding.offset_curvature, binding.offset_constant)

    def mapped(x: np.ndarray) -> np.ndarray:
        sums = unit_sums(grid, x)
        length = np.linalg.norm(sums, axis=1, keepdims=True)
        normals = np.where(length > 1e-6, sums / np.where(length > 0, length, 1.0), 0.0)
        return map_vertices(x, normals, binding.tri_nodes, binding.weights, offset, binding.offset_world,
                            binding.curvature_ok)[0]

    rest = grid.rest_positions
    sag = -(mapped(rest + u)[:, 1] - mapped(rest)[:, 1])
    mean, largest, top = _figures(np.asarray(model.mesh.vertices), sag)
    mass_ratio = float(system.mass.sum() / (DENSITY * mesh.volume))
    return MeshSag(mean, largest, top, grid.count, mass_ratio, time.perf_counter() - start)


#: The FEM references (``python -m studies.mesh_accuracy`` prints them): mean, largest
#: and topmost vertex's sag in m of each mesh at its finer level (the dragon: 115,807 tetrahedra;
#: the coarse level's 25,206 are within 0.32 %, 0.51 % and 0.48 % of it; the finned bar: 10,858
#: tetrahedra, the mean and largest within 0.34 % of 4,292's, 2026-12-05).
FEM_REFERENCE: dict[str, tuple[float, float, float]] = {
    "dragon": (9.95106e-05, 1.4291260e-03, 1.403315e-04),
    "finned_bar": (3.060924e-03, 1.3999702e-02, 1.139277e-06),
}
#: The lattice against them (mean, largest, top over the FEM's; lattice mass over the mesh's) at
#: 12, 16, 24 and 32 nodes along, the cells carrying the mesh (issue 28; docs/ACCURACY.md §9).
LATTICE_FIGURES: dict[str, dict[int, tuple[float, float, float, float]]] = {
    "dragon": {12: (0.6735, 0.1156, 0.8455, 0.9999), 16: (0.5069, 0.2172, 0.7089, 1.0000),
               24: (0.6697, 0.2047, 0.7845, 1.0001), 32: (0.7512, 0.6394, 0.7459, 0.9998)},
    "finned_bar": {12: (0.0282, 0.0229, 9.5846, 0.9760), 16: (0.0412, 0.0391, 2.9905, 1.0038),
                   24: (0.1221, 0.1227, 1.0302, 0.9887), 32: (0.1776, 0.1799, 0.8908, 0.9913)},
}


def main(argv: list[str] | None = None) -> int:
    """Print the FEM's refinement study and the lattice's table for each mesh."""
    parser = argparse.ArgumentParser(prog="python -m studies.mesh_accuracy",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--mesh", choices=sorted(MESHES), action="append", help="the meshes (default: all)")
    parser.add_argument("--nodes", default="12,16,24,32", help="nodes along the longest side, comma separated")
    parser.add_argument("--refine", type=int, default=1, help="FEM refinement levels beyond the coarse one")
    args = parser.parse_args(argv)
    require_mesh_fem()
    along = [int(n) for n in args.nodes.split(",")]
    for name in args.mesh or sorted(MESHES):
        mesh = repaired_mesh(name)
        print(f"\n{name}: {len(mesh.vertices)} vertices, watertight, {mesh.volume * 1e6:.2f} cm^3; E = "
              f"{YOUNGS_MODULUS:.0e} Pa, rho = {DENSITY:.0f} kg/m^3, nu = {POISSON}, lowest {HOLD:.0%} in y held")
        ref = None
        for level in range(args.refine + 1):
            r = fem_sag(mesh, refine=level)
            ref = r
            print(f"  FEM P2, {r.size:>7} tets: mean {r.mean * 1e6:9.4f} um, largest {r.largest * 1e6:9.4f} um, "
                  f"top {r.top * 1e6:9.4f} um  [{r.seconds:.0f} s]", flush=True)
        assert ref is not None
        for n in along:
            r = lattice_sag(mesh, n)
            print(f"  lattice {n:>3} along ({r.size:>6} nodes): mean / FEM {r.mean / ref.mean:.3f}, largest / FEM "
                  f"{r.largest / ref.largest:.3f}, top / FEM {r.top / ref.top:.3f}, mass / mesh {r.mass_ratio:.3f}"
                  f"  [{r.seconds:.0f} s]", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
