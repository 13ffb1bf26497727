"""Physical materials and the calibrated spring lattice: Young's modulus and density instead of
per-spring constants, so a scene means the same body at any grid resolution and length scale.

The lattice is the node grid's 18-neighbour spring set (6 edges of length h and 12 face
diagonals of length h sqrt(2), Mosegaard & Sørensen 2005, section 3.1), assembled cell by cell
like a finite-element mesh: every cube cell whose 8 corner nodes exist contributes its 12 edge
springs and its 12 face-diagonal springs, and an eighth of its mass to each corner.

Calibration (derived in docs/ACCURACY.md, tested in tests/test_materials.py). A spring of
constant k along unit vector n with rest length L stores ``k L^2 (n . eps . n)^2 / 2`` under a
uniform small strain eps. Summed over the infinite lattice per node volume h^3 (3 edges and
6 face diagonals per node, all of constant k) this is the energy of the elasticity tensor

    C11 = 3k/h,   C12 = C44 = k/h,

which is isotropic (C11 - C12 = 2 C44) with Lamé constants lambda = mu = k/h: Poisson's ratio
1/4 and Young's modulus E = 5k/(2h). So ``k = mu h`` (``= 2 E h / 5`` at nu = 1/4; at a larger
nu the springs carry the shear modulus mu = E / (2 (1 + nu)) and each full cell adds the missing
``kappa = lambda - mu`` as a volumetric term, :mod:`deformgl.sim.terms.volume.energy`,
``system.cells``). One cell alone reproduces the same tensor when each of its edges carries k/4
and each face diagonal k/2 (an interior edge is shared by 4 cells, a diagonal by 2), so a body
of full cells has exactly the continuum's energy under any uniform strain: the lattice passes the
patch test, and its boundary springs get the right share without special cases. A cell gives ``rho h^3 / 8`` of mass to each of its 8 corners.

Thin features: a spring that belongs to no full cell (a one-node-thick wall of the
voxelization) is given the share of one cell (edge k/4, diagonal k/2), and a node in no full cell
the mass of one cell corner (rho h^3/8), so every node stays connected and massive;
:class:`LatticeReport` counts them.

Cells that carry the mesh: on a grid with a fill (:mod:`deformgl.grid.fill`, every solid mesh
scene) each cell carries its fraction f of the mesh's material instead: its springs f of a full
cell's shares in all (:func:`fill_shares`: half evenly, half where the material lies), a spring
in no cell with material nothing, and each node the mass ``rho h^3 (sum of its springs) / 18 k``,
which is ``rho h^3`` at an interior node of full cells and sums to rho times the fill's volume.
A node's springs and mass then scale together, so its Gershgorin bound ``sum_j |K_ij| / m_i`` is
a full cell's whatever its fill: nearly empty cells neither stiffen the body nor lower the stable
dt. The volumetric term (``system.cells``) has no per-cell weight on the GPU, so a cell carries it
whole where the mesh fills at least half of it and not at all below (docs/EQUATIONS.md).

Damping is Rayleigh damping, independent of the resolution: ``mass_damping`` alpha (1/s) gives
each node the force ``-alpha m v`` and ``stiffness_damping`` beta (s) gives each spring the damping
``c_s = beta k_s`` along it; a mode of angular frequency w then has the damping ratio
``alpha / (2 w) + beta w / 2``.

Cloth (one node thick, in a plane) uses the 2D lattice of 4 edges and 4 diagonals per node.
With edge constant k_e and diagonal constant k_d it is isotropic when ``k_e = 2 k_d``, with 2D
Lamé constants lambda = mu = k_d: Poisson's ratio 1/3 and the 2D (membrane) Young's modulus
``Y = 8 k_d / 3`` in N/m. Per square cell an edge carries k_e/2 (2 cells share it) and each
diagonal k_d; a cell gives ``rho_A h^2 / 4`` to each corner. Flexion springs (``flexion_ratio``
r) of r k_d, weighted by the cells of their two unit edges, take 4 r k_d of C11 from the edges.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from itertools import product

import numpy as np
from numpy.typing import ArrayLike

from deformgl.errors import ArgumentError
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.terms import bending as _bending
from deformgl.sim.terms.spline import term as _spline_term
from deformgl.sim.terms.volume import term as _volume_term
from deformgl.sim.terms.bending import sheet_bending
from deformgl.sim.terms.base import TermNeeds
from deformgl.sim.springs import FLEXION, STRUCTURAL, SpringSystem, from_grid
from deformgl.sim.terms.volume.energy import BARRIER_SCALE, CellVolumes, grid_cells

#: the Poisson's ratios the lattice offers: 1/4 (springs alone) up to nearly incompressible
#: The body models of an elastic solid (:attr:`ElasticMaterial.model`).
MODELS = ("lattice", "spline")
MIN_POISSON = 0.25
MAX_POISSON = 0.499

__all__ = ["MODELS", "MIN_POISSON", "MAX_POISSON", "ElasticMaterial", "SheetMaterial", "PRESETS", "LatticeReport", "lattice_system",
           "sheet_system", "lattice_stiffness", "critical_dt", "cell_counts", "cell_weights", "fill_shares",
           "EVEN_SHARE"]


def _check_numbers(material: object, name: str, bounds: dict[str, str]) -> None:
    """Each field in ``bounds`` a finite real number within its bound ("> 0 Pa": positive, ">= 0":
    not negative, "": any); else :class:`ArgumentError` naming the class and the argument (a
    scene's ``[material]`` is checked key by key before it reaches here)."""
    for key, bound in bounds.items():
        value = getattr(material, key)
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ArgumentError(f"{name}: {key} must be a real number, got {value!r}")
        ok = math.isfinite(value) and (value > 0 if bound.startswith(">") and not bound.startswith(">=")
                                       else value >= 0 if bound.startswith(">=") else True)
        if not ok:
            raise ArgumentError(f"{name}: {key} must be a finite number{' ' + bound if bound else ''}, got {value}")


@dataclass(frozen=True)
class ElasticMaterial:
    """An isotropic elastic solid.

    Attributes:
        youngs_modulus: E in Pa (> 0).
        density: rho in kg/m^3 (> 0).
        mass_damping: Rayleigh alpha in 1/s (force -alpha m v on every node).
        stiffness_damping: Rayleigh beta in s (spring damping beta k along each spring).
        name: a label (a preset's name).
        source: where the values come from.
        poissons_ratio: nu, dimensionless, in [1/4, 1/2) (default 1/4). The springs carry the
            shear modulus mu; a volumetric term per full cell (:mod:`deformgl.sim.terms.volume.energy`) adds
            the lambda - mu that central springs cannot give (0 at nu = 1/4). Below 1/4 a
            lattice would need lambda < mu, which central springs cannot give: refused.
        model: the body model (:data:`MODELS`): "lattice" (default), the calibrated spring lattice
            with its volumetric term; "spline", the quadratic B-spline finite-element body on the
            same nodes (:mod:`deformgl.sim.terms.spline`; docs/EQUATIONS.md "Spline cells").
    """

    youngs_modulus: float
    density: float
    mass_damping: float = 0.0
    stiffness_damping: float = 0.0
    name: str = ""
    source: str = ""
    poissons_ratio: float = 0.25
    model: str = "lattice"

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ArgumentError(f"ElasticMaterial: model must be one of {', '.join(MODELS)}, got {self.model!r}")
        _check_numbers(self, "ElasticMaterial", {"youngs_modulus": "> 0 Pa", "density": "> 0 kg/m^3",
                                                  "mass_damping": ">= 0 1/s", "stiffness_damping": ">= 0 s",
                                                  "poissons_ratio": ""})
        nu = self.poissons_ratio
        if not MIN_POISSON <= nu <= MAX_POISSON:
            raise ArgumentError(f"ElasticMaterial: poissons_ratio must be in [{MIN_POISSON}, {MAX_POISSON}], got {nu} "
                                f"(below 1/4 the spring lattice would need lambda < mu, which central "
                                f"springs cannot give)")

    @property
    def shear_modulus(self) -> float:
        """mu = E / (2 (1 + nu)) in Pa: what the springs carry (k = mu h)."""
        return self.youngs_modulus / (2.0 * (1.0 + self.poissons_ratio))

    @property
    def lame_lambda(self) -> float:
        """lambda = E nu / ((1 + nu)(1 - 2 nu)) in Pa."""
        nu = self.poissons_ratio
        return self.youngs_modulus * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))

    @property
    def volume_modulus(self) -> float:
        """kappa = lambda - mu = E (4 nu - 1) / (2 (1 + nu)(1 - 2 nu)) in Pa: the volumetric
        term's modulus (0 at nu = 1/4; docs/EQUATIONS.md)."""
        nu = self.poissons_ratio
        return self.youngs_modulus * (4.0 * nu - 1.0) / (2.0 * (1.0 + nu) * (1.0 - 2.0 * nu))

    @property
    def p_wave_modulus(self) -> float:
        """lambda + 2 mu in Pa (C11 of the lattice with its volumetric term)."""
        return self.lame_lambda + 2.0 * self.shear_modulus

    def wave_speed(self) -> float:
        """The P-wave speed sqrt((lambda + 2 mu) / rho) in m/s (sqrt(6 E / (5 rho)) at nu = 1/4)."""
        return math.sqrt(self.p_wave_modulus / self.density)

    @property
    def term_needs(self) -> tuple[TermNeeds, ...]:
        """What the terms its lattice holds besides the springs will need (the cells' volumetric
        term), known before the lattice is built."""
        return (_spline_term.NEEDS,) if self.model == "spline" else (_volume_term.NEEDS,)

    @property
    def summary(self) -> str:
        """``E = ... Pa, rho = ... kg/m^3`` for the render log."""
        return f"E = {self.youngs_modulus:.4g} Pa, rho = {self.density:.4g} kg/m^3"


@dataclass(frozen=True)
class SheetMaterial:
    """A membrane (cloth): 2D Young's modulus ``stretch_modulus`` in N/m (E times thickness),
    ``areal_density`` in kg/m^2, Rayleigh damping as :class:`ElasticMaterial` (its beta damps the
    springs, not the bending), and one of two ways to resist bending:

    * ``bending_stiffness`` D in N·m, the plate's ``E t^3 / (12 (1 - nu^2))`` (a fabric's bending
      rigidity per unit width, as a cantilever test measures it, is ``D (1 - nu^2)``, nu = 1/3):
      the calibrated plate term of :mod:`deformgl.sim.terms.bending`, linear in the positions
      (Bergou et al. 2006), checked against the analytic plate (docs/ACCURACY.md, "Cloth bending");
    * ``flexion_ratio`` r in [0, 0.5]: flexion springs (2h along an axis) of r k_d, the edges
      reduced to (2 - 4r) k_d so the membrane keeps its modulus (0: none). A flat sheet's flexion
      springs resist bending only through the geometry (at second order in the out-of-plane
      displacement), so r is a shape knob, not a calibrated bending modulus.

    Both 0 (the default): a membrane with no bending stiffness. Giving both is an error."""

    stretch_modulus: float
    areal_density: float
    mass_damping: float = 0.0
    stiffness_damping: float = 0.0
    flexion_ratio: float = 0.0
    name: str = ""
    source: str = ""
    bending_stiffness: float = 0.0

    def __post_init__(self) -> None:
        _check_numbers(self, "SheetMaterial", {"stretch_modulus": "> 0 N/m", "areal_density": "> 0 kg/m^2",
                                                "mass_damping": ">= 0 1/s", "stiffness_damping": ">= 0 s",
                                                "flexion_ratio": ">= 0", "bending_stiffness": ">= 0 N*m"})
        if self.flexion_ratio > 0.5:
            raise ArgumentError(f"SheetMaterial: flexion_ratio must be at most 0.5 (the edges keep (2 - 4 r) k_d), "
                                f"got {self.flexion_ratio}")
        if self.flexion_ratio > 0 and self.bending_stiffness > 0:
            raise ArgumentError("SheetMaterial: bending_stiffness and flexion_ratio: give one (the plate's D in "
                                "N·m is the calibrated bending; flexion springs would add to it)")

    @property
    def term_needs(self) -> tuple[TermNeeds, ...]:
        """What the terms its lattice holds besides the springs will need (the bending term where
        ``bending_stiffness`` is set), known before the lattice is built."""
        return (_bending.NEEDS,) if self.bending_stiffness > 0 else ()

    @property
    def summary(self) -> str:
        """``Y = ... N/m, rho_A = ... kg/m^2`` (and ``D = ... N*m``) for the render log."""
        what = f"Y = {self.stretch_modulus:.4g} N/m, rho_A = {self.areal_density:.4g} kg/m^2"
        return what + (f", D = {self.bending_stiffness:.4g} N*m" if self.bending_stiffness else "")


#: Named materials (E in Pa, rho in kg/m^3, Poisson's ratio) with the source of the values. Soft
#: tissues span a wide range in the literature; these are representative small-strain values.
PRESETS: dict[str, ElasticMaterial] = {
    "liver": ElasticMaterial(4.0e3, 1060.0, name="liver", poissons_ratio=0.45,
                             source="human liver, small-strain E ~ 1-10 kPa (Yeh et al. 2002, "
                                    "Ultrasound Med. Biol. 28(4)); density 1060 kg/m^3 (ICRP 89); "
                                    "nu 0.45: soft tissue is nearly incompressible (Fung 1993, "
                                    "Biomechanics, 2nd ed., ch. 7), FE liver models use 0.45-0.49"),
    "heart": ElasticMaterial(3.0e4, 1060.0, name="heart", poissons_ratio=0.45,
                             source="passive myocardium, E ~ 10-50 kPa (Sommer et al. 2015, "
                                    "Acta Biomater. 24); density 1060 kg/m^3 (ICRP 89); nu 0.45: "
                                    "nearly incompressible (Fung 1993, Biomechanics, 2nd ed., ch. 7)"),
    "brain": ElasticMaterial(1.0e3, 1040.0, name="brain", poissons_ratio=0.45,
                             source="brain tissue, E ~ 0.5-3 kPa (Budday et al. 2015, "
                                    "J. Mech. Behav. Biomed. Mater. 46); density 1040 kg/m^3; nu 0.45: "
                                    "nearly incompressible (Miller & Chinzei 1997, J. Biomech. 30(11))"),
    "gelatin": ElasticMaterial(1.0e4, 1030.0, name="gelatin", poissons_ratio=0.49,
                               source="10 % w/v gelatin gel, E ~ 10 kPa (Hall et al. 1997, IEEE "
                                      "TUFFC 44(6)); density ~ 1030 kg/m^3; nu 0.49: a water gel, "
                                      "taken as incompressible in elastography (Hall et al. 1997)"),
    "silicone": ElasticMaterial(1.0e5, 1070.0, name="silicone", poissons_ratio=0.49,
                                source="soft silicone elastomer (Ecoflex 00-30 class), E ~ "
                                       "70-125 kPa (manufacturer data); density 1070 kg/m^3; nu 0.49: "
                                       "elastomers are nearly incompressible (Gent, Engineering with "
                                       "Rubber, 3rd ed., ch. 1)"),
    "rubber": ElasticMaterial(1.0e6, 1100.0, name="rubber", poissons_ratio=0.49,
                              source="natural rubber, E ~ 1-10 MPa at small strain (Gent, "
                                     "Engineering with Rubber, 3rd ed.); density ~ 1100 kg/m^3; nu: "
                                     "0.4999 measured (bulk modulus ~ 2 GPa, ibid. ch. 1), 0.49 here "
                                     "(the nearly incompressible setting of FE practice; up to 0.499 "
                                     "can be set)"),
}


@dataclass(frozen=True)
class LatticeReport:
    """What the cell assembly found: full cells, and the thin features of the voxelization
    that belong to no full cell (each given one cell's share, see the module docstring)."""

    cells: int
    thin_nodes: int
    thin_springs: int
    spring_constant: float  # k = mu h (N/m) of an interior spring (2 E h / 5 at nu = 1/4); the sheet's k_d
    node_mass: float        # rho h^3 (kg) of an interior node; the sheet's rho_A h^2
    fill: float | None = None  # cells' fill fractions summed (full cells' worth of material), or None

    def summary(self) -> str:
        """One line for logs and the CLI."""
        if self.fill is not None:
            return (f"{self.cells} cells holding the mesh's material, {self.fill:.1f} full cells' worth "
                    f"(each carries its fill)")
        text = f"{self.cells} full cells"
        if self.thin_nodes or self.thin_springs:
            text += (f"; {self.thin_nodes} nodes and {self.thin_springs} springs in no full cell "
                     f"(given one cell's share)")
        return text


def lattice_stiffness(material: ElasticMaterial, spacing: float) -> float:
    """k = mu h in N/m (2 E h / 5 at nu = 1/4): the constant of an interior spring (edge or
    face diagonal)."""
    return material.shear_modulus * spacing


def critical_dt(material: ElasticMaterial, spacing: float, integrator: str = "verlet", *,
                barrier: bool = True) -> float:
    """The explicit stability limit of the lattice in s, a multiple of ``h sqrt(rho / E)``.

    Interior node of mass ``rho h^3``: the springs give ``w^2 <= 2 * 18 k / m = 36 mu / (rho h^2)``
    (k = mu h), the volumetric term of its 8 cells at most ``8 * 1.5 kappa h / m = 12 kappa /
    (rho h^2)`` (Cauchy-Schwarz on ``V kappa (sum_c G_c . x_c)^2`` with ``sum_c |G_c|^2 = 3 / (2 h^2)``);
    and the inversion barrier's envelope of its 8 cells (every corner active, the stiffest it gets
    in compression: :func:`deformgl.sim.terms.volume.energy.frequency_terms`) ``8 (sqrt(3) + 3)^2 / 8 kappa_b h
    / m = 22.4 kappa_b / (rho h^2)``, ``kappa_b = 12 mu``. Verlet and semi-implicit Euler are
    stable for ``dt < 2 / w_max`` (a Gershgorin bound, the same as :mod:`deformgl.sim.limits`
    computes on a built system of full cells; the run's check may accept more, on the exact
    spectrum). Explicit Euler has no undamped limit (it is unstable at every dt without damping);
    RK4's limit is about 2.83 / w_max, midpoint's 0 undamped (see deformgl.sim.limits).
    ``barrier=False``: the rest stiffness alone, ``2 h sqrt(rho / (36 mu + 12 kappa))`` (the scale
    the time-stepping and float32 errors of ``bench trade --resolution`` were measured on).
    """
    envelope = (math.sqrt(3.0) + 3.0) ** 2 * BARRIER_SCALE * material.shear_modulus if barrier else 0.0
    omega = math.sqrt((36.0 * material.shear_modulus + 12.0 * material.volume_modulus + envelope)
                      / material.density) / spacing
    factor = {"verlet": 2.0, "semi-implicit": 2.0, "rk4": 2.0 * math.sqrt(2.0)}.get(integrator, 2.0)
    return factor / omega


def cell_weights(grid: NodeGrid) -> np.ndarray:
    """(nx-1, ny-1, nz-1) float64 share of a full cell that each cell carries: the mesh's fill
    fraction where the grid has one (:mod:`deformgl.grid.fill`), else 1 for every cell whose 8
    corners exist and 0 for the others."""
    if grid.fill is not None:
        return np.asarray(grid.fill.fraction, np.float64)
    occ = grid.occupied
    nx, ny, nz = occ.shape
    full = np.ones((max(nx - 1, 0), max(ny - 1, 0), max(nz - 1, 0)), bool)
    for dx, dy, dz in product((0, 1), repeat=3):
        full &= occ[dx:nx - 1 + dx, dy:ny - 1 + dy, dz:nz - 1 + dz]
    return full.astype(np.float64)


def _spans(grid: NodeGrid, system: SpringSystem) -> np.ndarray:
    """(S, 3) bool: the axes each spring spans."""
    ijk = grid.ijk.astype(np.int64)
    return ijk[system.i] != ijk[system.j]


def _spring_cells(grid: NodeGrid, system: SpringSystem):
    """The up to 4 cells that hold each spring (edge or face diagonal), one offset at a time:
    yields ``(o, valid, idx)``, the (3,) offset in {-1, 0} of the cell from the spring's lower
    end along the axes it does not span, (S,) whether that cell holds the spring, and (S, 3) the
    cell's index + 1 (into an array padded by one cell)."""
    ijk = grid.ijk.astype(np.int64)
    lo = np.minimum(ijk[system.i], ijk[system.j])
    differs = _spans(grid, system)
    for off in product((-1, 0), repeat=3):
        # along a spanned axis the cell index is lo (offset 0 only); along the others lo - 1 or lo
        o = np.array(off)
        yield o, ~(differs & (o != 0)).any(axis=1), lo + np.where(differs, 0, o) + 1


def cell_counts(grid: NodeGrid, system: SpringSystem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per spring of a :func:`from_grid` system (structural and shear only): the full cells that
    contain it, each counted by its :func:`cell_weights` (a count of full cells without a fill);
    per node: the same sum over the cells it is a corner of; and the (nx-1, ny-1, nz-1) cell
    weights."""
    weights = cell_weights(grid)
    padded = np.pad(weights, 1)  # cell (a, b, c) is padded[a + 1, b + 1, c + 1]
    ijk = grid.ijk.astype(np.int64)
    counts = np.zeros(system.spring_count, np.float64)
    for _, valid, idx in _spring_cells(grid, system):
        counts += valid * padded[idx[:, 0], idx[:, 1], idx[:, 2]]
    node_cells = np.zeros(grid.count, np.float64)
    for off in product((-1, 0), repeat=3):
        idx = ijk + np.array(off) + 1
        node_cells += padded[idx[:, 0], idx[:, 1], idx[:, 2]]
    return counts, node_cells, weights


#: the part of a filled cell's share its springs get evenly; the rest goes where its material
#: lies (:func:`fill_shares`; docs/ACCURACY.md section 9 measures 0, 0.2, 0.5 and 1)
EVEN_SHARE = 0.5


def fill_shares(grid: NodeGrid, system: SpringSystem) -> np.ndarray:
    """Per spring of a :func:`from_grid` system on a grid with a fill: its share of the cells that
    hold it, in full cells (a count of full cells where the mesh fills them).

    A cell of fill fraction f gives each of its springs :data:`EVEN_SHARE` f, and the rest by
    where its material lies: an edge stands for the quarter of the cell nearest to it, a face
    diagonal for the half on its face's side (the octants of
    :attr:`~deformgl.grid.fill.CellFill.octants`), and gets that part's fill. A cell's 12 edges
    cover its 8 octants evenly (each 3 times), as do its 12 diagonals (each 6 times), so the
    cell's springs carry f of a full cell's in all either way; the even part keeps every cell
    with material braced on all its faces (a cell braced on some faces only is a mechanism)."""
    if grid.fill is None:
        raise ValueError("fill_shares: the grid has no fill")
    octants = np.pad(grid.fill.octants.reshape(*grid.fill.cells, 8), ((1, 1), (1, 1), (1, 1), (0, 0)))
    bits = np.array(list(product((0, 1), repeat=3)))  # (8, 3) octant (ox, oy, oz) in C order
    shares = np.zeros(system.spring_count, np.float64)
    differs = _spans(grid, system)
    for o, valid, idx in _spring_cells(grid, system):
        cell = octants[idx[:, 0], idx[:, 1], idx[:, 2]]                       # (S, 8)
        side = np.where(o == -1, 1, 0)                                         # the spring's side where it does not span
        chosen = ((bits[None, :, :] == side[None, None, :]) | differs[:, None, :]).all(axis=2)  # (S, 8)
        placed = (cell * chosen).sum(axis=1) / chosen.sum(axis=1)
        shares += valid * ((1.0 - EVEN_SHARE) * placed + EVEN_SHARE * cell.mean(axis=1))
    return shares


def lattice_system(grid: NodeGrid, material: ElasticMaterial, *, fixed: ArrayLike | None = None,
                   gravity: ArrayLike = (0.0, -9.81, 0.0), wind: ArrayLike = (0.0, 0.0, 0.0),
                   wind_drag: float = 0.0) -> tuple[SpringSystem, LatticeReport]:
    """The calibrated spring system of a solid ``material`` on ``grid`` (world units: metres).

    Edge and face-diagonal springs of the grid with ``k = mu h`` (``2 E h / 5`` at nu = 1/4) times
    (full cells containing the spring) / (4 for an edge, 2 for a diagonal); node masses
    ``rho h^3 / 8`` per full cell at the node; Rayleigh damping from the material; the full cells'
    volumetric term (``kappa = lambda - mu`` and the corner barrier) as ``system.cells``. See the
    module docstring.

    Returns:
        The system and the :class:`LatticeReport`.
    """
    h = float(grid.spacing)
    k = lattice_stiffness(material, h)
    base = from_grid(grid, k_structural=1.0, k_shear=1.0, fixed=fixed, gravity=gravity,
                     wind=wind, wind_drag=wind_drag)
    counts, node_cells, weights = cell_counts(grid, base)
    share = np.where(base.spring_class == STRUCTURAL, 4.0, 2.0)
    thin_springs = counts == 0
    thin_nodes = node_cells == 0
    if grid.fill is None:  # the voxeliser's thin features: one cell's share each
        stiffness = k * np.maximum(counts, 1.0) / share
        mass = material.density * h ** 3 / 8.0 * np.maximum(node_cells, 1.0)
        volumetric = grid_cells(grid.occupied, grid.index)
    else:  # cells carry their fill where it lies: a spring in no cell with material carries nothing
        stiffness = k * fill_shares(grid, base) / share
        # a node's mass in proportion to its springs: rho h^3 at an interior node of full cells
        # (18 k of springs), the cell's fill in all, and every node's k / m that of a full cell
        row = np.bincount(base.i, stiffness, grid.count) + np.bincount(base.j, stiffness, grid.count)
        mass = material.density * h ** 3 * row / (18.0 * k)
        # the volumetric term has no per-cell weight on the GPU: a cell carries it whole when the
        # mesh fills at least half of it (docs/EQUATIONS.md, "Cells that carry the mesh")
        volumetric = grid_cells(grid.occupied, grid.index, weights >= 0.5)
    cells = CellVolumes(volumetric, h, material.volume_modulus, BARRIER_SCALE * material.shear_modulus)
    system = dataclasses.replace(base, stiffness=stiffness, damping=material.stiffness_damping * stiffness,
                                 mass=mass, mass_damping=material.mass_damping,
                                 material=material, cells=cells)
    report = LatticeReport(int((weights > 0).sum()), int(thin_nodes.sum()), int(thin_springs.sum()), k,
                           material.density * h ** 3,
                           fill=None if grid.fill is None else float(weights.sum()))
    return system, report


def sheet_system(grid: NodeGrid, material: SheetMaterial, *, fixed: ArrayLike | None = None,
                 gravity: ArrayLike = (0.0, -9.81, 0.0), wind: ArrayLike = (0.0, 0.0, 0.0),
                 wind_drag: float = 0.0) -> tuple[SpringSystem, LatticeReport]:
    """The calibrated system of a membrane on a one-node-thick grid (a cloth): edges
    ``k_e = 2 k_d`` and diagonals ``k_d = 3 Y / 8`` times their share of full square cells,
    node masses ``rho_A h^2 / 4`` per cell at the node (see the module docstring), and with
    ``bending_stiffness`` the plate term of :func:`deformgl.sim.terms.bending.sheet_bending`."""
    shape = grid.shape
    thin_axes = [a for a in range(3) if shape[a] == 1]
    if not thin_axes:
        raise ValueError("sheet material: the grid is not one node thick (a cloth); use an "
                         "ElasticMaterial (youngs_modulus, density)")
    h = float(grid.spacing)
    k_d = 3.0 * material.stretch_modulus / 8.0
    k_e = 2.0 * k_d
    base = from_grid(grid, k_structural=1.0, k_shear=1.0, k_flexion=1.0 if material.flexion_ratio else 0.0,
                     fixed=fixed, gravity=gravity, wind=wind, wind_drag=wind_drag)
    # a 2D cell of the sheet is a 3D "cell" of a grid doubled along the thin axis: count in 2D
    axis = thin_axes[0]
    occ = np.squeeze(grid.occupied, axis=axis)
    n0, n1 = occ.shape
    full = occ[:-1, :-1] & occ[1:, :-1] & occ[:-1, 1:] & occ[1:, 1:]
    padded = np.pad(full, 1)
    ijk = np.delete(grid.ijk.astype(np.int64), axis, axis=1)
    a, b = ijk[base.i], ijk[base.j]
    lo = np.minimum(a, b)
    differs = a != b
    def cells_of_edge(start: np.ndarray, along: np.ndarray) -> np.ndarray:
        """Full cells that hold the unit edge from ``start`` along the axes ``along`` spans."""
        found = np.zeros(len(start), np.int64)
        for off in product((-1, 0), repeat=2):
            o = np.array(off)
            valid = ~(along & (o != 0)).any(axis=1)
            idx = start + np.where(along, 0, o) + 1
            found += valid & padded[idx[:, 0], idx[:, 1]]
        return found

    counts = cells_of_edge(lo, differs)
    flex = base.spring_class == FLEXION
    # a flexion spring (2h along an axis) is weighted by the cells of its two unit edges
    unit = differs.astype(np.int64)
    halves = cells_of_edge(lo, differs) + cells_of_edge(lo + unit, differs)
    node_cells = np.zeros(grid.count, np.int64)
    for off in product((-1, 0), repeat=2):
        idx = ijk + np.array(off) + 1
        node_cells += padded[idx[:, 0], idx[:, 1]]
    edge = base.spring_class == STRUCTURAL
    # flexion springs of r k_d add 4 r k_d to C11 (length 2h): the edges give that up, k_e = (2 - 4r) k_d,
    # so the membrane keeps Y and nu = 1/3 (exactly in the interior and along straight borders)
    r = material.flexion_ratio
    stiffness = np.where(edge, (k_e - 4.0 * r * k_d) * np.maximum(counts, 1) / 2.0, k_d * np.maximum(counts, 1))
    stiffness = np.where(flex, r * k_d * np.maximum(halves, 1) / 4.0, stiffness)
    mass = material.areal_density * h ** 2 / 4.0 * np.maximum(node_cells, 1)
    bending = sheet_bending(grid, material.bending_stiffness) if material.bending_stiffness > 0 else None
    system = dataclasses.replace(base, stiffness=stiffness, damping=material.stiffness_damping * stiffness,
                                 mass=mass, mass_damping=material.mass_damping,
                                 material=material, bending=bending)
    thin_springs = int(((counts == 0) & ~flex).sum())
    report = LatticeReport(int(full.sum()), int((node_cells == 0).sum()), thin_springs, k_d,
                           material.areal_density * h ** 2)
    return system, report
