"""Stability limits of the five integrators: analytic bounds, exact frequency, measured limit.

Movania & Feng 2012 (section 3) compare explicit Euler, semi-implicit ("implicit") Euler,
midpoint, RK4 and Verlet; their step-size limits follow from the highest angular frequency w of
the linearised system (docs/EQUATIONS.md, "Stability"):

* semi-implicit Euler and position Verlet: ``dt <= 2/w``;
* RK4: ``dt <= 2 sqrt(2)/w`` (2.83/w; ``|R(iy)|^2 = 1 - y^6/72 + y^8/576 <= 1 <=> y^2 <= 8``);
* forward Euler (``|1 + iy| > 1``) and midpoint (``|1 + iy - y^2/2|^2 = 1 + y^4/4 > 1``): no dt
  at all without damping. With damping they have a finite limit (forward Euler with
  ``x'' = -w^2 x - g x'``, g < 2w: ``dt <= g / w^2``).

Three numbers per integrator:

1. *Gershgorin limit*: from ``w_max^2 <= max_i 2 sum_j k_ij / m_i``
   (:func:`deformgl.sim.springs.max_angular_frequency`). Costs one pass over the springs and is
   conservative (never above the exact limit under the modal-damping model below), so it is what
   :func:`check_dt` uses for large systems.
2. *Exact limit*: from the spectrum of ``M^-1 K`` at rest (``K`` the 3N x 3N stiffness matrix,
   one block ``k u u^T`` per spring, fixed nodes removed). Dense ``eigh`` up to
   :data:`DENSE_MAX_NODES` free nodes; above, Lanczos on the sparse product (NumPy only).
3. *Measured limit*: bisection on dt of long float64 runs of :func:`deformgl.sim.integrators.step`
   (:func:`measured_limit`).

Damping model. Each mode is the scalar test equation ``x'' = -w^2 x - g(w) x'`` with
``g(w) = alpha + beta w^2``: ``alpha = (velocity_damping + wind_drag)/m + mass_damping`` (mass-proportional),
``beta = c_s/k_s`` (spring damping, stiffness-proportional). That is exact (Rayleigh damping)
when the free masses are equal and ``c_s/k_s`` is the same for every spring; otherwise the limit
is the smallest over the corners of the (alpha, beta) ranges and flagged ``proportional=False``.
The one-step map of each mode is the integrator's amplification: ``R(z)`` at the eigenvalues
``z = dt lambda``, ``lambda = (-g +- sqrt(g^2 - 4 w^2))/2``, for the Runge-Kutta family
(``1 + z``, ``1 + z + z^2/2``, ``1 + z + z^2/2 + z^3/6 + z^4/24``), and the 2x2 matrix with
trace ``2 - w^2 dt^2 - g dt`` and determinant ``1 - g dt`` for semi-implicit Euler and for
Verlet (whose damping sees the backward-difference velocity, as ``integrators.py``). A mode's
limit is the smallest dt at which the spectral radius exceeds 1 (islands of stability at larger
dt are ignored); limits below 1e-3 / max(w, g) are reported as 0 (unusable).
"""

from __future__ import annotations

# The analysis is split by what it does (spectrum.py, limits.py, growth.py); every name stays
# importable from here.
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS  # noqa: F401
from deformgl.sim.spectrum import (  # noqa: F401
    DENSE_MAX_NODES,
    ExactFrequency,
    ModalDamping,
    _BLOW_UP,
    _FORMULA,
    _RADIUS_TOL,
    _RK_POLY,
    _Y_MAX,
    _Y_MIN,
    _describe,
    _free_scaling,
    _lanczos_top,
    _mass_normalised,
    _rest_directions,
    _to_mode,
    exact_frequency,
    modal_damping,
    modal_frequencies,
    stiffness_matrix,
    stiffness_product,
)
from deformgl.sim.limits import (  # noqa: F401
    AnalyticLimit,
    DtLimit,
    DtRefusal,
    LANCZOS_MARGIN,
    LANCZOS_TOL,
    _dt_limit,
    _formula,
    analytic_limit,
    check_dt,
    dt_limit,
    exact_limit,
    gershgorin_limit,
    mode_limit,
    require_stable_dt,
    spectral_radius,
)
from deformgl.sim.growth import (  # noqa: F401
    GrowthFit,
    MeasuredLimit,
    StabilityRow,
    _energies,
    _envelope_rate,
    _fmt,
    _recurrence_rate,
    _row,
    format_stability,
    growth_rate,
    measured_limit,
    stability_table,
    standard_systems,
)

__all__ = ["DENSE_MAX_NODES", "ExactFrequency", "ModalDamping", "AnalyticLimit", "DtLimit",
           "DtRefusal", "GrowthFit", "MeasuredLimit", "StabilityRow", "stiffness_product",
           "stiffness_matrix", "exact_frequency", "modal_frequencies", "modal_damping",
           "spectral_radius", "mode_limit", "analytic_limit", "gershgorin_limit", "exact_limit",
           "dt_limit", "check_dt", "require_stable_dt", "growth_rate", "measured_limit",
           "standard_systems", "stability_table", "format_stability"]


if __name__ == "__main__":  # python -m deformgl.sim.stability
    print(format_stability(stability_table()))
