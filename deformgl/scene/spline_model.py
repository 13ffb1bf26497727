"""A scene's body as spline cells (``[material] model = "spline"``; issue 44): the quadratic
B-spline body of the mesh's fill on the scene's grid (:func:`deformgl.sim.terms.spline.cut.sample_body`:
the lattice's material, its surface samples measured against the mesh along lines, its cut spans
moment-fitted), the ``[[physics.fixed]]`` regions as one
penalty on the material in them (:class:`~deformgl.sim.terms.spline.term.SplineAnchor` at the
body's Gauss points of positive weight in a region, ``k = HOLD_PENALTY E / h^2`` per unit
volume), gravity and the material's mass damping.

What the lattice's scenes have and a spline body does not yet: stiffness (Rayleigh beta) damping,
wind drag, drags and obstacles (which would act on the control points, not on the body) are
refused in one line naming the key; pulls act on the control points in their region, per
kilogram as on the lattice.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import trimesh

from deformgl.errors import SceneError
from deformgl.grid.line_fill import surface_samples
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.materials import ElasticMaterial
from deformgl.sim.springs import SpringSystem
from deformgl.sim.terms.spline.body import SplineBody
from deformgl.sim.terms.spline.cut import fit_boxes, sample_body, span_samples
from deformgl.sim.terms.spline.term import SplineAnchor, spline_system

__all__ = ["HOLD_PENALTY", "spline_refusal", "spline_scene"]

#: A held region's penalty, k = HOLD_PENALTY E / h^2 (N/m^4): issue 44's probe moved the result by
#: at most 1.4 % at 16 nodes along when it grew ten times.
HOLD_PENALTY = 1.0e3


def spline_refusal(physics: Any) -> tuple[str, str] | None:
    """(key, why) for the first option of ``physics`` (a :class:`deformgl.scene.spec.Physics`) a
    spline body does not run, or None."""
    material = physics.material
    if physics.backend == "feedback":
        return "physics.backend", 'model = "spline" has no transform-feedback form yet (the fragment and numpy backends run it)'
    if physics.layout != "auto":
        return "physics.layout", 'model = "spline" runs on the fragment backend\'s stages (layout "auto")'
    if isinstance(material, ElasticMaterial) and material.stiffness_damping > 0:
        return "material.stiffness_damping", 'not used by model = "spline" yet (its mass_damping is)'
    if physics.wind_drag > 0:
        return "physics.wind_drag", 'not used by model = "spline" yet'
    if physics.drag:
        return "physics.drag", 'not used by model = "spline" yet (a drag holds a control point, not the body)'
    if physics.ground is not None:
        return "physics.ground", 'not used by model = "spline" yet (it would stop the control points, not the body)'
    if physics.sphere:
        return "physics.sphere", 'not used by model = "spline" yet (it would stop the control points, not the body)'
    return None


def spline_scene(grid: NodeGrid, physics: Any, bbox: np.ndarray, *, mesh: trimesh.Trimesh | None = None,
                 source: str = "scene") -> tuple[SpringSystem, SplineBody]:
    """The spline body of the mesh's fill on ``grid`` and its system (the module docstring).
    With ``mesh`` (in the grid's coordinates) the fill's surface samples are measured against it
    (:func:`deformgl.grid.line_fill.surface_samples`, out to the knot planes beyond the outermost
    nodes), so thin features and the body's mass are integrated exactly along lines.

    Raises:
        SceneError: the grid has no fill (the body needs the mesh's material), an option a spline
            body does not run, or a fixed region that holds none of the material.
    """
    material = physics.material
    if not isinstance(material, ElasticMaterial) or grid.fill is None:
        raise SceneError(f'{source}: material.model: "spline" needs a solid material and a mesh filled into the grid')
    refused = spline_refusal(physics)
    if refused is not None:
        raise SceneError(f"{source}: {refused[0]}: {refused[1]}")
    fill = grid.fill
    surface = None
    if mesh is not None:
        triangles = (np.asarray(mesh.triangles, np.float64) - grid.origin) / grid.spacing * fill.samples - 0.5
        surface = surface_samples(triangles, fill.inside, fill.samples / 2.0)
    boxes = span_samples(fill.samples, fill.inside, surface)  # (the body's and the held regions')
    body = sample_body(grid.origin, grid.spacing, fill.samples, fill.inside, youngs_modulus=material.youngs_modulus,
                       poissons_ratio=material.poissons_ratio, density=material.density, boxes=boxes)
    h = body.spacing
    points, weights = _held(grid, boxes, physics.fixed, bbox, source)
    anchors = (SplineAnchor(body, points, weights, HOLD_PENALTY * material.youngs_modulus / h ** 2),
               ) if len(points) else ()
    system = spline_system(body, anchors=anchors, gravity=tuple(physics.gravity), mass_damping=material.mass_damping)
    return system, body


def _region_box(region: Any, bbox: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A region's space as a world box [lo, hi] (m; unbounded sides infinite)."""
    lo, hi = np.asarray(bbox[0], np.float64), np.asarray(bbox[1], np.float64)
    extent = np.where(hi - lo > 0, hi - lo, 1.0)  # (as NodeGrid.bbox_fraction)
    if region.kind == "box":
        return lo + np.asarray(region.lo) * extent, lo + np.asarray(region.hi) * extent
    low, high = np.full(3, -np.inf), np.full(3, np.inf)
    plane = lo[region.axis] + region.at * extent[region.axis]
    if region.kind == "below":
        high[region.axis] = plane
    else:
        low[region.axis] = plane
    return low, high


def _held(grid: NodeGrid, boxes: tuple, regions: tuple, bbox: np.ndarray, source: str) -> tuple[np.ndarray, np.ndarray]:
    """The quadrature of the material in the fixed ``regions``: the fill's material boxes
    (:func:`~deformgl.sim.terms.spline.cut.span_samples`) cut on every region's faces, the pieces
    inside a region kept, and each knot span's pieces integrated by one moment-fitted grid of 27
    points (as the body's cut spans): world points (P, 3), m, and weights (P,), m^3, of the held
    material itself, wherever the grid lies against the region's faces.

    Raises:
        SceneError: a region that holds none of the material.
    """
    centre, s, widths, _ = boxes
    h = grid.spacing
    lo = grid.origin + (centre + s - widths / 2.0) * h
    hi = grid.origin + (centre + s + widths / 2.0) * h
    spans = centre
    faces = [_region_box(region, bbox) for region in regions]
    for box_lo, box_hi in faces:  # cut every box on every finite face of every region
        for d in range(3):
            for plane in (box_lo[d], box_hi[d]):
                if not np.isfinite(plane):
                    continue
                cut = (lo[:, d] < plane) & (plane < hi[:, d])
                if cut.any():
                    upper_lo = lo[cut].copy()
                    upper_lo[:, d] = plane
                    lo = np.concatenate([lo, upper_lo])
                    hi = np.concatenate([hi, hi[cut]])
                    spans = np.concatenate([spans, spans[cut]])
                    hi[np.nonzero(cut)[0], d] = plane
    middle = (lo + hi) / 2.0
    held = np.zeros(len(lo), bool)
    for i, (box_lo, box_hi) in enumerate(faces):
        inside = np.all((middle >= box_lo) & (middle <= box_hi), axis=1)
        if not inside.any():
            raise SceneError(f"{source}: physics.fixed[{i}]: the region holds none of the mesh's material "
                             f"(spacing {h:.4g}); widen it or refine the grid")
        held |= inside
    if not held.any():
        return np.zeros((0, 3)), np.zeros(0)
    spans, local = np.unique(spans[held], axis=0, return_inverse=True)
    local = local.ravel()
    centres = grid.origin + spans * h
    box_s = (middle[held] - centres[local]) / h
    box_w = (hi[held] - lo[held]) / h
    span_lo = np.full((len(spans), 3), np.inf)
    span_hi = np.full((len(spans), 3), -np.inf)
    np.minimum.at(span_lo, local, box_s - box_w / 2.0)
    np.maximum.at(span_hi, local, box_s + box_w / 2.0)
    points, weights = fit_boxes(local, box_s, np.prod(box_w, axis=1), np.maximum(span_lo, -0.5),
                                 np.minimum(span_hi, 0.5), box_w)
    world = centres[:, None, :] + points * h
    keep = weights.ravel() > 0
    return world.reshape(-1, 3)[keep], weights.ravel()[keep] * h ** 3
