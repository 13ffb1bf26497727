"""The spline body of a real mesh against the mesh's own FEM (issue 44, item 6; docs/ACCURACY.md
section 9's workload): ``python -m studies.spline_mesh_accuracy``.

The same workload as :mod:`studies.mesh_accuracy` (the mesh made one watertight solid, E = 1 MPa,
rho = 1000 kg/m^3, nu = 1/4, its lowest 5 % in y held, gravity along -y; the FEM references its
refined P2 level gave, :data:`studies.mesh_accuracy.FEM_REFERENCE`), on the product's scene path
with ``[material] model = "spline"`` (the fill's material, cut spans moment-fitted, the held region
a penalty of 10^3 E / h^2 on the material in it): the linear static solve ``K u = f`` of its rest
stiffness in float64 (the FEM is linear too), read at the mesh's vertices through the B-spline
field (what the renderer draws).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse.linalg as spl
import trimesh

from studies.mesh_accuracy import (DENSITY, FEM_REFERENCE, G, LATTICE_FIGURES, MESHES, POISSON, YOUNGS_MODULUS, MeshSag,
                                   _figures, repaired_mesh, scene_model)


def spline_sag(mesh: trimesh.Trimesh, nodes_along: int) -> tuple[MeshSag, int]:
    """The spline body's static sag at the mesh's vertices at ``nodes_along`` nodes along the
    longest side, and its knot spans."""
    start = time.perf_counter()
    model = scene_model(mesh, nodes_along, material='model = "spline"\n', physics='integrator = "semi-implicit"\n')
    assert model.spline is not None
    return _static(model.mesh, model.system, model.spline, start), len(model.spline.span_nodes)


#: the grid shifts of ``--shift``, in cells
SHIFTS = ((0.0, 0.0, 0.0), (0.5, 0.0, 0.0), (0.0, 0.5, 0.0), (0.0, 0.0, 0.5), (0.5, 0.5, 0.5))


def shifted_sags(mesh: trimesh.Trimesh, nodes_along: int) -> list[tuple[tuple[float, float, float], MeshSag]]:
    """The spline body's static sag (as :func:`spline_sag`) with its grid shifted against the mesh
    by each of :data:`SHIFTS` (the scene's body: its fill, measured surface boxes and held band
    built by :func:`deformgl.scene.spline_model.spline_scene` on the shifted grid)."""
    from deformgl.grid.fill import fill_cells
    from deformgl.grid.nodes import NodeGrid
    from deformgl.scene.spline_model import spline_scene

    model, scene = scene_model(mesh, nodes_along, material='model = "spline"\n',
                               physics='integrator = "semi-implicit"\n', with_scene=True)
    out = []
    for shift in SHIFTS:
        start = time.perf_counter()
        vox, fill = fill_cells(model.mesh, nodes_along_longest=nodes_along, offset=shift)
        grid = NodeGrid(origin=np.asarray(vox.origin, np.float64), spacing=float(vox.spacing),
                        occupied=np.asarray(vox.occupied, bool), fill=fill)
        system, body = spline_scene(grid, scene.physics, model.bbox, mesh=model.mesh)
        out.append((shift, _static(model.mesh, system, body, start)))
    return out


def _static(mesh: trimesh.Trimesh, system, body, start: float) -> MeshSag:
    """The static sag of a spline body's system at the mesh's vertices (:func:`spline_sag`)."""
    from deformgl.render.bspline_premap import vertex_spans
    from deformgl.sim.terms.spline.basis import span_basis

    k = None
    for term in system.terms:
        part = term.dt_stiffness(body.rest_positions) if term.name == "spline cells" else term.stiffness(body.rest_positions)
        k = part if k is None else k + part
    f = np.zeros((body.count, 3))
    f[:, 1] = -body.lumped_mass * G
    u = spl.spsolve(k.tocsc(), f.ravel()).reshape(-1, 3)
    vertices = np.asarray(mesh.vertices, np.float64)
    nodes, s = vertex_spans(body, vertices)
    values = span_basis(s, body.spacing)[0]
    sag = -np.einsum("va,va->v", values, u[nodes, 1])
    mean, largest, top = _figures(vertices, sag)
    mass_ratio = float(body.lumped_mass.sum() / (DENSITY * mesh.volume))
    return MeshSag(mean, largest, top, body.count, mass_ratio, time.perf_counter() - start)


def diagnosis(mesh: trimesh.Trimesh, nodes_along: int) -> tuple[float, float]:
    """The spline body's explicit dt limit (semi-implicit, free, no anchor) over a full box's at the
    same spacing (issue 44: within 2x), and the share of control points whose support (the 3 x 3 x 3
    spans around the node) holds the fill's material in more than one connected piece (material
    a support may glue together; an upper bound: pieces may connect outside the support)."""
    from scipy import ndimage

    from deformgl.grid.fill import fill_cells
    from deformgl.sim.limits import dt_limit
    from deformgl.sim.terms.spline.body import SplineBody
    from deformgl.sim.terms.spline.cut import sample_body
    from deformgl.sim.terms.spline.term import spline_system

    vox, fill = fill_cells(mesh, nodes_along_longest=nodes_along)
    s, inside = fill.samples, fill.inside
    constants = {"youngs_modulus": YOUNGS_MODULUS, "poissons_ratio": POISSON, "density": DENSITY}
    body = sample_body(vox.origin, vox.spacing, s, inside, **constants)
    cube = SplineBody.from_box([0.0] * 3, [8 * vox.spacing] * 3, vox.spacing, **constants)
    ratio = (dt_limit(spline_system(body, gravity=(0.0, 0.0, 0.0)), "semi-implicit").dt
             / dt_limit(spline_system(cube, gravity=(0.0, 0.0, 0.0)), "semi-implicit").dt)
    held = pieces = 0
    for ijk in np.argwhere(np.ones(tuple(np.array(inside.shape) // s + 1), bool)):
        lo = np.maximum(((ijk - 1.5) * s).astype(int), 0)
        hi = np.minimum(((ijk + 1.5) * s).astype(int), inside.shape)
        block = inside[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
        if block.any():
            held += 1
            pieces += ndimage.label(block)[1] > 1
    return ratio, pieces / held


def main(argv: list[str] | None = None) -> int:
    """Print the spline body's table against the FEM references, with the lattice's beside it."""
    parser = argparse.ArgumentParser(prog="python -m studies.spline_mesh_accuracy", description=__doc__.split("\n\n")[0])
    parser.add_argument("--mesh", choices=sorted(MESHES), action="append", help="the meshes (default: all)")
    parser.add_argument("--nodes", default="12,16,24,32", help="nodes along the longest side, comma separated")
    parser.add_argument("--diagnose", action="store_true",
                        help="also the dt limit against a full box's and the supports holding several pieces")
    parser.add_argument("--shift", action="store_true",
                        help="also the sag with the grid shifted by half a cell against the mesh (issue 44: < 1 %%)")
    args = parser.parse_args(argv)
    for name in args.mesh or sorted(MESHES):
        mesh = repaired_mesh(name)
        fem = FEM_REFERENCE[name]
        print(f"\n{name}: FEM (P2, the refined level) mean {fem[0] * 1e6:.2f} um, largest {fem[1] * 1e6:.2f} um, "
              f"top {fem[2] * 1e6:.4g} um; ratios to it, spline (lattice)")
        for n in (int(v) for v in args.nodes.split(",")):
            r, spans = spline_sag(mesh, n)
            lattice = LATTICE_FIGURES[name].get(n)
            beside = "" if lattice is None else f"  (lattice {lattice[0]:.3f} / {lattice[1]:.3f})"
            print(f"  {n:>3} along: {r.size:>6} control points, {spans:>6} spans: mean {r.mean / fem[0]:.3f}, "
                  f"largest {r.largest / fem[1]:.3f}, top {r.top / fem[2]:.3f}, mass / mesh {r.mass_ratio:.4f}"
                  f"{beside}  [{r.seconds:.0f} s]", flush=True)
            if args.shift:
                for shift, s in shifted_sags(mesh, n)[1:]:
                    print(f"       grid shifted by {shift} cells: mean {s.mean / r.mean - 1.0:+.2%}, largest "
                          f"{s.largest / r.largest - 1.0:+.2%}, top {s.top / r.top - 1.0:+.2%} against the unshifted "
                          f"grid's, mass / mesh {s.mass_ratio:.4f}", flush=True)
            if args.diagnose:
                dt_ratio, glued = diagnosis(mesh, n)
                print(f"       dt limit / a full box's {dt_ratio:.3f}; control points whose support holds material in "
                      f"more than one piece: {glued:.1%}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
