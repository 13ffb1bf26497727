"""Scene overrides from the command line and sweep files: ``KEY=VALUE`` (``--set``), camera views
``AZIMUTH,ELEVATION,DISTANCE`` (``--camera``, ``--views``) and mapping-mode lists (``--compare``).

Values are TOML values (``physics.dt=1e-3``, ``render.size=[320,240]``,
``physics.integrator=rk4``: a bare word that is not TOML is taken as a string); the scene's schema
checks them as it checks the file's own (:func:`deformgl.scene.schema.apply_overrides`).
"""

from __future__ import annotations

import argparse
import tomllib
from typing import Any

from deformgl.errors import InputError, SceneError

__all__ = ["add_render_flags", "blame_flag", "camera_overrides", "flag_keys", "parse_modes", "parse_set", "parse_view",
           "parse_views"]


def parse_value(text: str) -> Any:
    """A TOML value, or the text itself when it is not one (a bare word)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def parse_set(items: list[str] | None) -> dict[str, Any]:
    """``["physics.dt=1e-3", "mapping.mode=auto"]`` -> ``{"physics.dt": 0.001, "mapping.mode": "auto"}``."""
    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InputError(f"--set {item}: expected KEY=VALUE, e.g. physics.dt=1e-3")
        out[key.strip()] = parse_value(value.strip())
    return out


def flag_keys(items: list[str] | None, camera: str | None = None) -> dict[str, str]:
    """The scene key each ``--set`` item (and ``--camera``) sets -> the flag as given
    (``{"physics.dtt": "--set physics.dtt=1e-3"}``), for :func:`blame_flag`."""
    flags = {item.partition("=")[0].strip(): f"--set {item}" for item in items or []}
    if camera is not None:
        flags |= {key: f"--camera {camera}" for key in camera_overrides((0.0, 0.0, 0.0))}
    return flags


def _key_parts(key: str) -> list[str]:
    """``physics.pull[0].force`` and ``physics.pull.0.force`` -> ``["physics", "pull", "0", "force"]``."""
    return key.replace("[", ".").replace("]", "").split(".")


def blame_flag(exc: SceneError, flags: dict[str, str]) -> InputError | None:
    """The scene's error as the flag's own when the key at fault (or a table above it) is one a
    flag set: ``--set physics.dtt=1e-3: unknown key 'dtt' (did you mean 'dt'?)``, not the scene
    file's; None when no flag set it."""
    if exc.key is None or exc.reason is None:
        return None
    bad = _key_parts(exc.key)
    for key, flag in flags.items():
        parts = _key_parts(key)
        if bad[:len(parts)] == parts:
            reason = exc.reason
            if reason.startswith("unknown key"):
                reason = f"unknown key {bad[-1]!r}{reason[len('unknown key'):]}"
            where = "" if bad == parts else f"{exc.key}: "
            return InputError(f"{flag}: {where}{reason}")
    return None


def parse_view(text: str, flag: str = "--camera") -> tuple[float, float, float]:
    """``"30,15,1.4"`` -> (azimuth degrees, elevation degrees, distance in box diagonals)."""
    parts = [p.strip() for p in text.split(",")]
    try:
        az, el, dist = (float(p) for p in parts)
    except ValueError:
        raise InputError(f"{flag}: expected AZIMUTH,ELEVATION,DISTANCE (degrees, degrees, box diagonals), "
                         f"e.g. 30,15,1.4; got {text!r}") from None
    if not (-360 <= az <= 360 and -89 <= el <= 89 and 1e-3 <= dist <= 1e3):
        raise InputError(f"{flag}: azimuth must be in [-360, 360], elevation in [-89, 89] and distance in "
                         f"[0.001, 1000] box diagonals; got {text!r}")
    return az, el, dist


def parse_views(text: str | None) -> list[tuple[float, float, float]] | None:
    """``"0,15,1.3;90,15,1.3"`` -> two views (``--views``), or None."""
    if text is None:
        return None
    return [parse_view(v, "--views") for v in text.split(";") if v.strip()]


def parse_modes(text: str | None) -> list[str] | None:
    """``"one-to-one,constant,curvature"`` -> the mapping modes of ``--compare``, or None."""
    from deformgl.scene.spec import MAPPING_MODES  # (not at import: the CLI's parser stays light)

    if text is None:
        return None
    modes = [m.strip() for m in text.split(",") if m.strip()]
    for m in modes:
        if m not in MAPPING_MODES:
            raise InputError(f"--compare: {m!r} is not a mapping mode ({', '.join(MAPPING_MODES)})")
    return modes


def camera_overrides(view: tuple[float, float, float] | None) -> dict[str, Any]:
    """The scene keys ``--camera`` sets."""
    if view is None:
        return {}
    az, el, dist = view
    return {"render.camera.azimuth": az, "render.camera.elevation": el, "render.camera.distance": dist}


def add_render_flags(r: argparse.ArgumentParser) -> None:
    """``deformgl render``'s flags of animations, cameras, panels, overrides and the run record
    (parsed by the functions above; wired by :mod:`deformgl.cli`)."""
    a = r.add_argument_group("animation, camera and record (an animation output: -o out.mp4|out.gif|out.webp|"
                             "frames/%04d.png)")
    a.add_argument("--frames", type=int, default=None, help="frames of one simulation run (default: the scene's "
                   "[animation] frames, else 1: a still)")
    a.add_argument("--fps", type=float, default=None, help="frames per second (default: animation.fps, 24)")
    a.add_argument("--steps-per-frame", type=int, default=None, metavar="N",
                   help="scene steps between frames (0: simulate physics.steps, then every frame of that state, "
                        "e.g. a turntable; default: physics.steps spread over the frames)")
    a.add_argument("--seconds-per-frame", type=float, default=None, metavar="S",
                   help="simulated seconds between frames (rounded to whole steps of physics.dt)")
    a.add_argument("--turntable", type=float, default=None, metavar="DEG",
                   help="degrees of azimuth the camera turns over the animation (e.g. 360)")
    a.add_argument("--camera", default=None, metavar="AZ,EL,DIST",
                   help="camera azimuth and elevation (degrees) and distance (box diagonals), e.g. 30,15,1.4")
    a.add_argument("--views", default=None, metavar="AZ,EL,DIST;...",
                   help="several camera views side by side in one image, e.g. '0,15,1.3;90,15,1.3'")
    a.add_argument("--compare", default=None, metavar="MODE,MODE,...",
                   help="the mapping modes side by side on the same frame (with --views: one row each), "
                        "e.g. one-to-one,constant,curvature")
    a.add_argument("--set", action="append", default=None, metavar="KEY=VALUE",
                   help="set any scene key (TOML value), e.g. --set physics.dt=1e-3 --set render.size=[320,240]; "
                        "repeatable")
    a.add_argument("--json", nargs="?", const="", default=None, metavar="PATH",
                   help="also write the run record as JSON (default path: next to the output, NAME.json)")
