"""Continuum references for the soft-tissue lattice (springs plus a per-cell volumetric term, any
Poisson's ratio nu from 0.25 to 0.49): what the lattice's sag, bulge and large deflection are
checked against. Boxes in metres, x the beam axis, y up (gravity -y), clamped face at x = 0.

* :func:`mixed_cantilever_sag` (linear, locking-free): a ``length x width x width`` cantilever
  clamped (u = 0) at x = 0 under its own weight ``rho g`` (-y); the area mean of -u_y over the
  free end face x = length (the measure of :mod:`deformgl.bench.fem`'s cantilever). Linear
  elasticity in mixed displacement/pressure form, ``int 2 mu eps(u):eps(v) + p div v = int f.v``,
  ``int (div u - p/lambda) q = 0`` (p = lambda div u, so it stays well posed as lambda -> inf,
  nu -> 1/2), on Taylor-Hood (Taylor & Hood 1973) hexahedra: scikit-fem's
  ``ElementVector(ElementHex2())`` for u and ``ElementHex1()`` for p, assembled with scikit-fem
  forms, the saddle-point system solved by SciPy's SuperLU (with iterative refinement).
  Half the body is meshed (u_z = 0 on the symmetry plane z = width/2). Linear, so
  ``sag / (rho g L^4 / (E w^2))`` depends only on nu and L/w (Euler-Bernoulli: 3/2).
  :func:`mixed_cantilever_study` refines by halving and extrapolates (Richardson, as
  :func:`deformgl.bench.fem.fem_reference`).
* :func:`column_strain_ratio`: a square column ``side x side x height`` (axis y), bottom y = 0
  clamped (or frictionless: only u_y = 0), a uniform downward pressure on the top face; same
  mixed FEM on a quarter of the column (symmetry planes x = 0 and z = 0 of the centred column).
  Axial strain = mean top-face -u_y / height; lateral strain = mean u_x over the face
  x = +side/2 in the band 0.4 to 0.6 of the height, over side/2; and their ratio. Frictionless
  ends give uniaxial stress, whose exact solution (linear in x) the elements contain: ratio = nu.
* :func:`elastica_tip`: the inextensible Euler-Bernoulli elastica of the clamped horizontal
  cantilever under its distributed weight q = rho g w^2 (the "heavy elastica", e.g.
  Frisch-Fay 1962, *Flexible Bars*): ``EI theta''(s) = -q (L - s) cos theta(s)``,
  theta(0) = 0, theta'(L) = 0 (theta the downward slope angle, s the arc length, I = w^4/12),
  with x' = cos theta, y' = -sin theta; solved by
  ``scipy.integrate.solve_bvp`` with continuation in the load. Returns the tip's (u_x, u_y).
* :func:`studies.fem_nonlinear.neo_hookean_cantilever_tip`: the same cantilever,
  compressible neo-Hookean, large deflection (its module says how).

Verified (``tests/test_fem_tissue.py``): the mixed cantilever at nu = 1/4 equals
:func:`deformgl.bench.fem.fem_value` (displacement Q2 forms) within its discretisation error,
and Timoshenko's beam (:func:`deformgl.bench.fem.beam_theory`) to ~1 %; it is the same number for
0.2 x 0.02 x 0.02 m and 1 x 0.1 x 0.1 m; the frictionless column gives ratio = nu and axial
strain p/E to round-off; the elastica matches q L^4/(8 EI) at small load and an independent
shooting solution (``solve_ivp`` + root finding) to 1e-6 at large load; the neo-Hookean tip
equals the linear FEM at a tiny load and is within 1 % (sag) of the elastica at E = 500 kPa.

``python -m studies.fem_tissue`` prints the reference tables with each solve's wall time.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from deformgl.bench.fem import require_skfem
from studies.fem_nonlinear import cantilever_coordinates, lame, neo_hookean_cantilever_tip, sparse_solve

__all__ = ["mixed_cantilever_sag", "mixed_cantilever_study", "Study", "ColumnStrains",
           "column_strain_ratio", "column_study", "elastica_tip", "richardson", "sag_scale", "timoshenko_sag", "main"]

G = 9.81


def sag_scale(length: float, width: float, E: float, rho: float, g: float = G) -> float:
    """``rho g L^4 / (E w^2)`` in m: Euler-Bernoulli's tip sag of the cantilever is 3/2 of it."""
    return rho * g * length ** 4 / (E * width ** 2)


def timoshenko_sag(aspect: float, nu: float) -> float:
    """Timoshenko's tip sag of the cantilever under its weight over ``rho g L^4 / (E w^2)``:
    ``3/2 + (1 + nu) / (kappa aspect^2)``, aspect = L / w, Cowper's shear coefficient of a
    rectangle ``kappa = 10 (1 + nu) / (12 + 11 nu)`` (as :func:`deformgl.bench.fem.beam_theory`)."""
    kappa = 10.0 * (1.0 + nu) / (12.0 + 11.0 * nu)
    return 1.5 + (1.0 + nu) / (kappa * aspect ** 2)


def _mixed_solve(xs: np.ndarray, ys: np.ndarray, zs: np.ndarray, E: float, nu: float,
                 held: Sequence[tuple[int, float, tuple[int, ...]]], body: float = 0.0,
                 top_pressure: float = 0.0):
    """Linear Taylor-Hood (Q2 u / Q1 p) solve on the tensor mesh xs x ys x zs.

    ``held``: (axis, coordinate, components): those displacement components are 0 on the plane
    ``x[axis] = coordinate``. ``body``: force per volume along -y (N/m^3). ``top_pressure``: a
    downward traction (Pa) on the face y = ys[-1]. Returns (mesh, u basis, u, unknowns)."""
    require_skfem()
    from skfem import (Basis, BilinearForm, ElementHex1, ElementHex2, ElementVector,  # type: ignore[import-untyped,import-not-found,unused-ignore]
                       FacetBasis, LinearForm, MeshHex, asm)
    from skfem.helpers import ddot, div, sym_grad  # type: ignore[import-untyped,import-not-found,unused-ignore]

    mesh = MeshHex.init_tensor(xs, ys, zs)
    ub = Basis(mesh, ElementVector(ElementHex2()), intorder=4)
    pb = ub.with_element(ElementHex1())
    mu, lam = lame(E, nu)

    @BilinearForm
    def deviatoric(u, v, _):
        return 2.0 * mu * ddot(sym_grad(u), sym_grad(v))

    @BilinearForm
    def divergence(u, q, _):
        return div(u) * q

    @BilinearForm
    def compliance(p, q, _):
        return p * q / lam

    @LinearForm
    def weight(v, _):
        return -body * v[1]

    b = asm(divergence, ub, pb)
    k = sp.bmat([[asm(deviatoric, ub), b.T], [b, -asm(compliance, pb)]], format="csr")
    f = np.concatenate([asm(weight, ub), np.zeros(pb.N)])
    if top_pressure:
        top = FacetBasis(mesh, ub.elem, facets=mesh.facets_satisfying(lambda c: np.isclose(c[1], ys[-1])),
                         intorder=4)

        @LinearForm
        def traction(v, _):
            return -top_pressure * v[1]
        f[:ub.N] += asm(traction, top)
    dofs = [ub.get_dofs(lambda c, a=axis, x0=value: np.isclose(c[a], x0)).all([f"u^{i + 1}" for i in comps])
            for axis, value, comps in held]
    free = np.ones(k.shape[0], bool)
    free[np.concatenate(dofs)] = False
    x = np.zeros(k.shape[0])
    x[free] = sparse_solve(k[free][:, free], f[free], "mixed FEM")
    return mesh, ub, x[:ub.N], int(free.sum())


def _face_mean(mesh, ub, u: np.ndarray, component: int,
               where: Callable[[np.ndarray], np.ndarray]) -> float:
    """Area mean of u[component] over the boundary facets whose midpoints satisfy ``where``."""
    from skfem import FacetBasis  # type: ignore[import-untyped,import-not-found,unused-ignore]

    fb = FacetBasis(mesh, ub.elem, facets=mesh.facets_satisfying(where, boundaries_only=True), intorder=4)
    dx = np.asarray(fb.dx)
    return float((np.asarray(fb.interpolate(u))[component] * dx).sum() / dx.sum())


@dataclass(frozen=True)
class Study:
    """Values on meshes refined by halving: ``cells`` (elements across the width), ``values``
    (one float or tuple of floats per mesh), ``dofs`` and ``seconds`` per solve; ``best`` the
    extrapolated value(s) and ``error`` the estimated relative discretisation error(s) of best."""

    cells: tuple[int, ...]
    values: tuple
    dofs: tuple[int, ...]
    seconds: tuple[float, ...]
    best: tuple[float, ...]
    error: tuple[float, ...]


def richardson(values: Sequence[float]) -> tuple[float, float]:
    """(best value, its estimated relative error) from values on meshes refined by halving, the
    rule of :func:`deformgl.bench.fem.fem_reference`: with three converging monotonically,
    Richardson's extrapolation of the last three (observed order) and its distance to the finest
    value; otherwise the finest value and the last change."""
    v = list(values)
    if len(v) >= 3:
        d1, d2 = v[-2] - v[-3], v[-1] - v[-2]
        if d1 != 0 and 0 < d2 / d1 < 1:
            best = v[-1] + d2 * (d2 / d1) / (1 - d2 / d1)
            return best, abs(best - v[-1]) / abs(best)
    return v[-1], (abs(v[-1] - v[-2]) / abs(v[-1]) if len(v) > 1 else math.nan)


def _study(solve: Callable[[int], tuple[tuple[float, ...], int]], meshes: Sequence[int]) -> Study:
    values, dofs, seconds = [], [], []
    for n in meshes:
        start = time.perf_counter()
        value, unknowns = solve(n)
        seconds.append(time.perf_counter() - start)
        values.append(value)
        dofs.append(unknowns)
    fits = [richardson([v[i] for v in values]) for i in range(len(values[0]))]
    return Study(tuple(meshes), tuple(values), tuple(dofs), tuple(seconds),
                 tuple(f[0] for f in fits), tuple(f[1] for f in fits))


def _cantilever(length: float, width: float, E: float, nu: float, rho: float, g: float, cells_across: int,
                cells_along: int | None) -> tuple[float, int]:
    xs, ys, zs = cantilever_coordinates(length, width, cells_across, cells_along)
    mesh, ub, u, dofs = _mixed_solve(xs, ys, zs, E, nu, [(0, 0.0, (0, 1, 2)), (2, width / 2, (2,))],
                                     body=rho * g)
    return -_face_mean(mesh, ub, u, 1, lambda c: np.isclose(c[0], length)), dofs


def mixed_cantilever_sag(length: float, width: float, E: float, nu: float, rho: float, g: float = G,
                         cells_across: int = 2, cells_along: int | None = None) -> float:
    """The mean sag (m) of the free end face of the clamped cantilever under its weight, by the
    linear mixed FEM (see the module docstring); ``cells_across`` elements across the width,
    ``cells_along`` along the length (default: cubes)."""
    return _cantilever(length, width, E, nu, rho, g, cells_across, cells_along)[0]


def mixed_cantilever_study(length: float, width: float, E: float, nu: float, rho: float, g: float = G,
                           meshes: Sequence[int] = (1, 2, 4)) -> Study:
    """:func:`mixed_cantilever_sag` on cube meshes of ``meshes`` elements across, extrapolated."""
    def solve(n: int) -> tuple[tuple[float, ...], int]:
        sag, dofs = _cantilever(length, width, E, nu, rho, g, n, None)
        return (sag,), dofs
    return _study(solve, meshes)


class ColumnStrains(NamedTuple):
    """The column's axial strain (compression positive), lateral strain (bulge positive) and
    lateral / axial."""

    axial: float
    lateral: float
    ratio: float


def _column(side: float, height: float, E: float, nu: float, pressure: float, cells_across: int,
            ends: str) -> tuple[ColumnStrains, int]:
    if ends not in ("clamped", "frictionless"):
        raise ValueError(f"ends must be 'clamped' or 'frictionless', got {ends!r}")
    half = max(1, cells_across // 2)
    ny = 5 * max(1, round(cells_across * height / (4 * side)))  # nodes at 0.4 H and 0.6 H
    xs = zs = np.linspace(0.0, side / 2, half + 1)
    ys = np.linspace(0.0, height, ny + 1)
    bottom = (0, 1, 2) if ends == "clamped" else (1,)
    mesh, ub, u, dofs = _mixed_solve(xs, ys, zs, E, nu, [(1, 0.0, bottom), (0, 0.0, (0,)), (2, 0.0, (2,))],
                                     top_pressure=pressure)
    axial = -_face_mean(mesh, ub, u, 1, lambda c: np.isclose(c[1], height)) / height
    band = (lambda c: np.isclose(c[0], side / 2) & (c[1] > 0.4 * height - 1e-12 * height)
            & (c[1] < 0.6 * height + 1e-12 * height))
    lateral = _face_mean(mesh, ub, u, 0, band) / (side / 2)
    return ColumnStrains(axial, lateral, lateral / axial), dofs


def column_strain_ratio(side: float, height: float, E: float, nu: float, pressure: float = 1.0e3,
                        cells_across: int = 4, ends: str = "clamped") -> ColumnStrains:
    """Strains of the square column under a top pressure (Pa) by the linear mixed FEM (see the
    module docstring): ``cells_across`` elements across the side (even; a quarter is meshed),
    ``5 round(cells_across height / (4 side))`` along the height (a multiple of 5, so that the
    band's edges are nodes; halving when cells_across doubles from a multiple of 4 for the cube,
    of 2 for the 2:1 column); ``ends`` "clamped" (bottom u = 0) or
    "frictionless" (bottom u_y = 0 only)."""
    return _column(side, height, E, nu, pressure, cells_across, ends)[0]


def column_study(side: float, height: float, E: float, nu: float, pressure: float = 1.0e3,
                 meshes: Sequence[int] = (2, 4, 8), ends: str = "clamped") -> Study:
    """:func:`column_strain_ratio` on ``meshes``, each of (axial, lateral, ratio) extrapolated."""
    def solve(n: int) -> tuple[tuple[float, ...], int]:
        strains, dofs = _column(side, height, E, nu, pressure, n, ends)
        return tuple(strains), dofs
    return _study(solve, meshes)


def elastica_tip(length: float, width: float, E: float, rho: float, g: float = G) -> tuple[float, float]:
    """Tip displacement (u_x, u_y) in m of the inextensible elastica of the clamped horizontal
    cantilever under its own weight (see the module docstring); u_y < 0 is down."""
    from scipy.integrate import solve_bvp

    alpha = rho * g * width ** 2 * length ** 3 / (E * width ** 4 / 12.0)  # q L^3 / (E I)
    s = np.linspace(0.0, 1.0, 201)

    def bc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.array([a[0], b[1], a[2], a[3]])

    def bc_jac(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ja, jb = np.zeros((4, 4)), np.zeros((4, 4))
        ja[0, 0] = ja[2, 2] = ja[3, 3] = jb[1, 1] = 1.0
        return ja, jb

    y = np.zeros((4, s.size))
    y[2] = s
    loads = np.geomspace(min(alpha, 0.5), alpha, max(2, int(math.ceil(4 * math.log10(max(alpha / 0.5, 1.0)))) + 1))
    for a in loads:
        def rhs(t: np.ndarray, z: np.ndarray, a: float = float(a)) -> np.ndarray:
            return np.vstack([z[1], -a * (1.0 - t) * np.cos(z[0]), np.cos(z[0]), -np.sin(z[0])])

        def jac(t: np.ndarray, z: np.ndarray, a: float = float(a)) -> np.ndarray:
            j = np.zeros((4, 4, t.size))
            j[0, 1] = 1.0
            j[1, 0] = a * (1.0 - t) * np.sin(z[0])
            j[2, 0] = -np.sin(z[0])
            j[3, 0] = -np.cos(z[0])
            return j

        sol = solve_bvp(rhs, bc, s, y, fun_jac=jac, bc_jac=bc_jac, tol=1e-8, max_nodes=200_000)
        if not sol.success:
            raise RuntimeError(f"elastica: solve_bvp failed at load {a:.3g}: {sol.message}")
        s, y = sol.x, sol.y
    return float(length * (y[2, -1] - 1.0)), float(length * y[3, -1])


# ---- the reference tables ---------------------------------------------------------------------

NU_CANTILEVER = (0.25, 0.3, 0.45, 0.49)
NU_COLUMN = (0.3, 0.45, 0.49)


def _row(study: Study, i: int = 0, scale: float = 1.0) -> str:
    values = " ".join(f"{v[i] / scale:.6f}" for v in study.values)
    times = " ".join(f"{t:.1f}" for t in study.seconds)
    return f"{values} -> {study.best[i] / scale:.6f} (+-{100 * study.error[i]:.3f} %)  [{times} s]"


def main(quick: bool = False) -> None:
    """Print the tables (``quick``: the coarser meshes only)."""
    from deformgl.bench.fem import WORKLOADS, fem_value

    c_meshes = (1, 2) if quick else (2, 4, 8)
    print("1. Linear mixed cantilever: end-face mean sag / (rho g L^4 / (E w^2)), E = 5 kPa, rho = 1000;"
          " elements across: values -> extrapolated (error) [wall s per solve]")
    for size, meshes in (((0.2, 0.02), c_meshes), ((1.0, 0.1), (1, 2) if quick else (1, 2, 4))):
        for nu in NU_CANTILEVER:
            st = mixed_cantilever_study(*size, 5.0e3, nu, 1000.0, meshes=meshes)
            print(f"  {size[0]} x {size[1]} m nu={nu:<4} n={meshes}: {_row(st, 0, sag_scale(*size, 5.0e3, 1000.0))}"
                  f"  Timoshenko {timoshenko_sag(size[0] / size[1], nu):.5f}")
    ref = [fem_value(WORKLOADS["cantilever"], n) for n in ((1, 2) if quick else (1, 2, 4))]
    scale = sag_scale(1.0, 0.1, 1.0e8, 1000.0)
    best, err = richardson([r.value for r in ref])
    print("  fem.fem_value (displacement Q2, nu=0.25, 1 m):",
          " ".join(f"{r.value / scale:.6f} [{r.seconds:.1f}]" for r in ref), f"-> {best / scale:.6f} (+-{100 * err:.3f} %)")
    print("\n2. Column, top pressure p, bottom clamped: axial, lateral strain over p/E, lateral/axial")
    for height, meshes in ((0.02, (4, 8) if quick else (4, 8, 16)), (0.04, (2, 4) if quick else (2, 4, 8))):
        for nu in NU_COLUMN:
            st = column_study(0.02, height, 1.0e3, nu, pressure=1.0, meshes=meshes)
            fr = column_strain_ratio(0.02, height, 1.0e3, nu, pressure=1.0, cells_across=2, ends="frictionless")
            print(f"  0.02 x {height} m nu={nu} n={meshes}\n    axial   {_row(st, 0, 1e-3)}\n    lateral {_row(st, 1, 1e-3)}"
                  f"\n    ratio   {_row(st, 2)}\n    frictionless ends: axial {fr.axial / 1e-3:.9f} ratio {fr.ratio:.9f}")
    print("\n3. Elastica, 0.2 x 0.02 x 0.02 m, rho = 1000 kg/m^3: tip (u_x, u_y) in m; linear q L^4/(8 EI)")
    elastica = {}
    for E in (5.0e5, 5.0e4):
        start = time.perf_counter()
        elastica[E] = elastica_tip(0.2, 0.02, E, 1000.0)
        print(f"  E={E:.0f} Pa  ({elastica[E][0]:.6f}, {elastica[E][1]:.6f})  linear -{1.5 * sag_scale(0.2, 0.02, E, 1000.0):.6f}"
              f"  [{time.perf_counter() - start:.2f} s]")
    n_meshes = (1, 2) if quick else (1, 2, 4)
    print("\n4. Neo-Hookean cantilever 0.2 x 0.02 x 0.02 m, rho = 1000: end-face centre and mean (u_x, u_y) in m")
    for E in (5.0e5, 5.0e4):
        for nu in (0.25, 0.45):
            tips = [neo_hookean_cantilever_tip(0.2, 0.02, E, nu, 1000.0, cells_across=n) for n in n_meshes]
            for t in tips:
                print(f"  E={E:.0f} nu={nu} n={t.cells_across}: centre ({t.centre[0]:.6f}, {t.centre[1]:.6f})"
                      f" mean ({t.mean[0]:.6f}, {t.mean[1]:.6f})  dofs {t.dofs} steps {t.steps} newton {t.newton}"
                      f"  [{t.seconds:.1f} s]")
            for name, i in (("u_x", 0), ("u_y", 1)):
                best, err = richardson([t.centre[i] for t in tips])
                print(f"    centre {name} -> {best:.6f} (+-{100 * err:.3f} %), elastica {elastica[E][i]:.6f}"
                      f" ({100 * (best / elastica[E][i] - 1):+.2f} %)")


if __name__ == "__main__":
    import sys

    main(quick="--quick" in sys.argv)
