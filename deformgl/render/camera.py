"""Cameras: view and projection matrices framing a bounding box (float32, row-major NumPy;
pass ``.T`` bytes to GL, which reads column-major)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """World-to-view matrix (4, 4)."""
    f = target - eye
    f = f / np.linalg.norm(f)
    s = np.cross(f, up)
    if np.linalg.norm(s) < 1e-9:  # looking along up: pick another up
        s = np.cross(f, np.array([0.0, 0.0, 1.0]))
    s = s / np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.identity(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def perspective(fov_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    """OpenGL perspective projection (4, 4)."""
    f = 1.0 / np.tan(np.radians(fov_deg) / 2.0)
    m = np.zeros((4, 4))
    m[0, 0], m[1, 1] = f / aspect, f
    m[2, 2], m[2, 3] = (far + near) / (near - far), 2.0 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


def orthographic(half_height: float, aspect: float, near: float, far: float) -> np.ndarray:
    """OpenGL orthographic projection (4, 4) of a view half_height tall (half)."""
    m = np.identity(4)
    m[0, 0], m[1, 1] = 1.0 / (half_height * aspect), 1.0 / half_height
    m[2, 2], m[2, 3] = -2.0 / (far - near), -(far + near) / (far - near)
    return m


@dataclass(frozen=True)
class View:
    """A placed camera: eye position and the two matrices."""

    eye: np.ndarray
    view: np.ndarray
    projection: np.ndarray

    @property
    def view_projection(self) -> np.ndarray:
        """projection @ view."""
        return self.projection @ self.view


def frame_box(lo: np.ndarray, hi: np.ndarray, *, projection: str, azimuth: float, elevation: float,
              fov: float, distance: float, target: np.ndarray, aspect: float) -> View:
    """Place a camera looking at ``target`` (a fraction of the box) from azimuth/elevation.

    Args:
        lo, hi: the box to frame (world).
        projection: "perspective" or "orthographic".
        azimuth: degrees around +y; 0 looks along -z from +z.
        elevation: degrees above the horizontal.
        fov: vertical field of view, degrees (perspective).
        distance: eye distance in box diagonals (perspective; orthographic frames the box).
        target: (3,) fraction of the box the camera looks at.
        aspect: width / height.
    """
    diag = float(np.linalg.norm(hi - lo)) or 1.0
    centre = lo + np.asarray(target) * (hi - lo)
    az, el = np.radians(azimuth), np.radians(elevation)
    direction = np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    dist = distance * diag
    eye = centre + direction * dist
    view = look_at(eye, centre, np.array([0.0, 1.0, 0.0]))
    near, far = max(dist - 2.0 * diag, dist * 1e-3), dist + 2.0 * diag
    if projection == "orthographic":
        proj = orthographic(0.55 * diag, aspect, near, far)
    else:
        proj = perspective(fov, aspect, near, far)
    return View(eye=eye, view=view, projection=proj)
