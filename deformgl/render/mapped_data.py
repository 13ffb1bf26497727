"""Per-vertex mapping data of a detailed mesh (Mosegaard & Sørensen 2005, section 3.3), as the
drawing passes upload it (:mod:`deformgl.render.mapped`, :mod:`deformgl.render.premap`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MappedVertices"]


@dataclass(frozen=True, eq=False)
class MappedVertices:
    """Per-vertex mapping data of one mode, ready for the GPU (all float64/int64 arrays, V rows).

    Attributes:
        tri_nodes: (V, 3) node numbers; weights: (V, 3); offset: (V, 3) in the chosen basis;
        offset_world: (V, 3); normal, normal_world: (V, 3); use_curvature: (V,) bool;
        tangent: (V, 4) or None; tangent_world: (V, 3) or None; uv: (V, 2) or None.
    """

    tri_nodes: np.ndarray
    weights: np.ndarray
    offset: np.ndarray
    offset_world: np.ndarray
    normal: np.ndarray
    normal_world: np.ndarray
    use_curvature: np.ndarray
    tangent: np.ndarray | None = None
    tangent_world: np.ndarray | None = None
    uv: np.ndarray | None = None
