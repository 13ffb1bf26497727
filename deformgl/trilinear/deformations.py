"""Deformations to approximate with trilinear grids (Knuth, Kohlhammer & Kuijper, section 3.3
examples): torus wrap, twist, taper, bend and helix, and the tangent affine map of any of them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deformgl.trilinear.cuboid import Function
from deformgl.trilinear.normal_transform import finite_difference_jacobian

@dataclass(frozen=True)
class TorusWrap:
    """Wraps the box ``[0, length] x [0, width] x z`` around a torus (figures 1 and 9): x goes
    around the major circle (radius ``major``), y around the tube, z outwards from the surface
    of minor radius ``minor``; the torus axis is z."""

    length: float
    width: float
    major: float
    minor: float

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        theta = 2.0 * np.pi * p[:, 0] / self.length
        phi = 2.0 * np.pi * p[:, 1] / self.width
        r = self.minor + p[:, 2]
        ring = self.major + r * np.cos(phi)
        return np.stack([ring * np.cos(theta), ring * np.sin(theta), r * np.sin(phi)], 1)


@dataclass(frozen=True)
class Twist:
    """Rotation about the z axis by ``rate * z`` radians (Barr 1984)."""

    rate: float

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        a = self.rate * p[:, 2]
        c, s = np.cos(a), np.sin(a)
        return np.stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1], p[:, 2]], 1)


@dataclass(frozen=True)
class Taper:
    """Scales x and y by ``1 + rate * z``."""

    rate: float

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        s = 1.0 + self.rate * p[:, 2]
        return np.stack([s * p[:, 0], s * p[:, 1], p[:, 2]], 1)


@dataclass(frozen=True)
class Bend:
    """Bends the x axis around a circle of ``radius`` in the x-z plane (centre at z = radius):
    a point at height z keeps its distance ``radius - z`` from the centre."""

    radius: float

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        a = p[:, 0] / self.radius
        r = self.radius - p[:, 2]
        return np.stack([r * np.sin(a), p[:, 1], self.radius - r * np.cos(a)], 1)


@dataclass(frozen=True)
class Helix:
    """Carries the x axis along a helix of ``radius`` and ``pitch`` (rise per turn), x being
    the arc length; y and z follow the principal normal and binormal of the curve."""

    radius: float
    pitch: float

    def frame(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centre, normal and binormal at arc lengths ``s`` (N,)."""
        b = self.pitch / (2.0 * np.pi)
        c = np.hypot(self.radius, b)
        t = s / c
        centre = np.stack([self.radius * np.cos(t), self.radius * np.sin(t), b * t], 1)
        normal = np.stack([-np.cos(t), -np.sin(t), np.zeros_like(t)], 1)
        binormal = np.stack([b * np.sin(t), -b * np.cos(t), np.full_like(t, self.radius)], 1) / c
        return centre, normal, binormal

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        centre, normal, binormal = self.frame(p[:, 0])
        return centre + p[:, 1:2] * normal + p[:, 2:3] * binormal


def tangent_affine(f: Function, point: np.ndarray, step: float = 1e-5) -> np.ndarray:
    """First-order (linear) approximation of ``f`` at ``point``: the 4x4 affine matrix a linear
    scene graph would use to place an object there."""
    p = np.asarray(point, dtype=np.float64).reshape(1, 3)
    m = np.identity(4)
    m[:3, :3] = finite_difference_jacobian(f, p, step)[0]
    m[:3, 3] = f(p)[0] - m[:3, :3] @ p[0]
    return m
