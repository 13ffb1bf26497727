"""One sweep variant, run where a Dask worker (or the calling process) is: load the scene with the
variant's overrides, render it, write its files atomically, return its record.

Each worker thread keeps one EGL context for all the variants it runs (``DEFORMGL_DEVICE`` picks
the GPU, set per worker by the runner when several are given). A variant that fails (a bad value,
a blow-up) returns a record with ``status`` and ``error``; only an interruption propagates. A
variant's files are committed together (:class:`~deformgl.files.OutputSet`), so a worker killed
mid-variant leaves at most temporary files (``.NAME.deformgl-PID-HEX.tmp``, removed by the runner
at the end) and the retried task writes the whole set again.
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from typing import Any

from deformgl.errors import DeformglError, InputError

__all__ = ["run_variant", "variant_paths"]

_LOCAL = threading.local()


def _context():
    ctx = getattr(_LOCAL, "ctx", None)
    if ctx is None:
        from deformgl.gl.context import create_context

        ctx = _LOCAL.ctx = create_context(None)  # DEFORMGL_DEVICE, else EGL's default
    return ctx


def _pin(devices: tuple[int, ...]) -> None:
    from distributed import get_worker

    name = get_worker().name
    index = int(name) if isinstance(name, int) or str(name).isdigit() else sum(str(name).encode())
    os.environ["DEFORMGL_DEVICE"] = str(devices[index % len(devices)])


def variant_paths(out_dir: str | Path, name: str, outputs: tuple[str, ...]) -> dict[str, Path]:
    """The files a variant writes: ``png``, ``mesh`` (.ply), ``record`` (.json)."""
    folder = Path(out_dir)
    suffix = {"png": ".png", "mesh": ".ply", "record": ".json"}
    return {kind: folder / f"{name}{suffix[kind]}" for kind in outputs}


def run_variant(scene_path: str, overrides: dict[str, Any], out_dir: str, name: str,
                outputs: tuple[str, ...] = ("png", "record"), ctx=None,
                devices: tuple[int, ...] | None = None) -> dict[str, Any]:
    """Render one variant; returns its record (``variant``, ``status``: ok, input error or failed,
    ``error``, the run record's keys, ``worker_pid``, ``task_wall_time_s``).

    Args:
        ctx: the GL context to use (default: this thread's own, made on first use).
        devices: pin this Dask worker to ``devices[NAME % len(devices)]`` (``DEFORMGL_DEVICE``,
            set before its context is made; NAME is the worker's name, a number on a LocalCluster,
            else hashed).
    """
    if devices:
        _pin(devices)
    from deformgl.scene.outputs import Job, render_job
    from deformgl.scene.schema import load_scene

    started = time.perf_counter()
    base: dict[str, Any] = {"variant": name, "status": "ok", "error": "", "overrides": dict(overrides),
                            "worker_pid": os.getpid(), "device": os.environ.get("DEFORMGL_DEVICE")}
    paths = variant_paths(out_dir, name, outputs)
    try:
        scene = load_scene(scene_path, overrides)
        png = paths.get("png") or Path(out_dir) / f".{name}.unused.png"
        from deformgl.scene.animation import frame_plan

        # a variant is a still: physics.steps simulated, then drawn (an animated scene too)
        job = Job(png, plan=frame_plan(scene, frames=1, steps_per_frame=0), export=paths.get("mesh"),
                  record=paths.get("record"))
        record = render_job(ctx if ctx is not None else _context(), scene, job)
        if "png" not in paths:  # measured only: the image was rendered, not kept
            png.unlink(missing_ok=True)
            record["outputs"] = [p for p in record.get("outputs", []) if p != str(png)]
            if "record" in paths:  # the record as kept, without the image
                from deformgl.scene.record import write_record

                write_record(paths["record"], record)
        base.update(record)
    except InputError as exc:
        base.update(status="input error", error=str(exc))
    except DeformglError as exc:
        base.update(status="failed", error=str(exc))
    except MemoryError:
        base.update(status="failed", error="out of memory")
    except OSError as exc:
        base.update(status="failed", error=f"{exc.filename or ''}: {exc.strerror or exc}")
    except Exception as exc:  # a bug, reported in the table with its type
        base.update(status="failed", error=f"internal error: {type(exc).__name__}: {exc}")
    base["task_wall_time_s"] = round(time.perf_counter() - started, 4)
    return base
