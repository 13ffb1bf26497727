"""The generator of ``scenes/assets/heart_organ.ply.gz``, the mesh of ``scenes/heart_organ.toml``.

A heart-like closed surface, 12 cm from its base to its apex: the classic implicit heart surface,
the sextic (x^2 + 9/4 y^2 + z^2 - 1)^3 - x^2 z^3 - 9/80 y^2 z^3 = 0 (usually credited to G. Taubin),
narrowed across its lobes so that it reads as the ventricles under the two atria rather than a
symbol, tilted 20 degrees like a heart in the chest, apex down. The surface is star-shaped about the origin (every ray from it crosses the
surface once), so an icosphere's vertices moved along their rays onto it (bisection on the sextic)
give a closed, consistently wound mesh with the sphere's triangles: 2,562 vertices, 5,120 faces.

Run:  python examples/heart_mesh.py [OUT.ply.gz]   (default: scenes/assets/heart_organ.ply.gz)
"""

from __future__ import annotations

import gzip
import sys
from pathlib import Path

import numpy as np
import trimesh

#: Base to apex, metres.
HEIGHT_M = 0.12
#: Icosphere subdivisions: 10 * 4^n + 2 vertices.
SUBDIVISIONS = 4
#: Width of the lobes (x) against the sextic's, and the tilt about the depth axis, degrees.
NARROW = 0.8
TILT_DEG = 20.0
DEFAULT_OUT = Path(__file__).resolve().parent.parent / "scenes" / "assets" / "heart_organ.ply.gz"


def sextic(p: np.ndarray) -> np.ndarray:
    """The heart sextic at points (..., 3), z up: negative inside."""
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    return (x * x + 2.25 * y * y + z * z - 1.0) ** 3 - x * x * z ** 3 - 0.1125 * y * y * z ** 3


def ray_radii(directions: np.ndarray, *, iterations: int = 60) -> np.ndarray:
    """(N,) distance from the origin to the surface along each unit direction (N, 3), by
    bisection between 0 (inside) and 2 (outside: the surface lies within radius 1.6)."""
    lo = np.zeros(len(directions))
    hi = np.full(len(directions), 2.0)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        inside = sextic(directions * mid[:, None]) < 0.0
        lo = np.where(inside, mid, lo)
        hi = np.where(inside, hi, mid)
    return 0.5 * (lo + hi)


def heart_mesh() -> trimesh.Trimesh:
    """The heart-like mesh in metres, y up, apex down, its base's centre near the origin."""
    sphere = trimesh.creation.icosphere(subdivisions=SUBDIVISIONS)
    directions = np.asarray(sphere.vertices, np.float64)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    points = directions * ray_radii(directions)[:, None]
    points[:, 0] *= NARROW
    # the sextic's z (lobes up, apex down) becomes y; its y (the thin side) becomes z
    points = points[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0])
    tilt = np.radians(TILT_DEG)
    c, s = np.cos(tilt), np.sin(tilt)
    points = points @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]).T
    points *= HEIGHT_M / np.ptp(points[:, 1])
    points -= np.array([points[:, 0].mean(), points[:, 1].max(), points[:, 2].mean()])
    # (x, y, z) -> (x, z, -y) is a rotation: the winding stays outward
    return trimesh.Trimesh(points, np.asarray(sphere.faces), process=False)


def write(path: Path) -> Path:
    """Write the mesh as gzipped binary PLY (no time stamp: the same bytes run to run)."""
    mesh = heart_mesh()
    data = trimesh.exchange.ply.export_ply(mesh, encoding="binary")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(gzip.compress(data, mtime=0))
    return path


if __name__ == "__main__":
    out = write(Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT_OUT)
    mesh = heart_mesh()
    print(f"wrote {out}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces, "
          f"watertight {mesh.is_watertight}, volume {mesh.volume * 1e6:.0f} cm^3")
