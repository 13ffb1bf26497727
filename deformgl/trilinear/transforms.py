"""Trilinear transformations and grids of them, float64 NumPy (Knuth, Kohlhammer & Kuijper):
one import site for the pieces, which live in

* :mod:`deformgl.trilinear.cuboid`: one trilinear cell (their eq. 1-4, sections 3.1-3.2), the
  linearity test, :class:`Box` and unit lattices;
* :mod:`deformgl.trilinear.grid`: :class:`Trilinear`, a grid of cells (section 3.3), and
  composition (section 4.1) with the bound of its error;
* :mod:`deformgl.trilinear.errorbound`: that bound explained, and composition refined until a
  requested error is met;
* :mod:`deformgl.trilinear.normal_transform`: normals under a transformation (section 4.2);
* :mod:`deformgl.trilinear.deformations`: the deformations the paper approximates (section 3.3).
"""

from __future__ import annotations

from deformgl.trilinear.cuboid import (
    CORNERS, EQ2, LINEAR_RTOL, MAX_COMPOSED_CELLS, Box, Function, apply_coefficients, coefficient_matrix,
    corner_weight_gradients, corner_weights, grid_corners, is_linear_coefficients, parameter_vector,
    trilinear_corners, unit_lattice,
)
from deformgl.trilinear.deformations import Bend, Helix, Taper, TorusWrap, Twist, tangent_affine
from deformgl.trilinear.grid import (
    Trilinear, approximation_error, check_affine, compose, composition_cells, composition_error,
    crossed_cells, lattice_matches, sample_lattice,
)
from deformgl.trilinear.errorbound import compose_within, composition_bound, lipschitz_bound
from deformgl.trilinear.normal_transform import NORMAL_MODES, finite_difference_jacobian, tangent_frame, transform_normals

__all__ = [
    "CORNERS", "EQ2", "LINEAR_RTOL", "MAX_COMPOSED_CELLS", "NORMAL_MODES", "Bend", "Box", "Function", "Helix",
    "Taper", "TorusWrap", "Trilinear", "Twist", "apply_coefficients", "approximation_error", "check_affine",
    "coefficient_matrix", "compose", "compose_within", "composition_bound", "composition_cells", "composition_error", "corner_weight_gradients",
    "corner_weights", "crossed_cells", "finite_difference_jacobian", "grid_corners", "is_linear_coefficients",
    "lattice_matches", "lipschitz_bound", "parameter_vector", "sample_lattice", "tangent_affine", "tangent_frame",
    "transform_normals", "trilinear_corners", "unit_lattice",
]
