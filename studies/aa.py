"""Anti-aliasing in ``studies.render_speed``: the heart frame's budget split (steps, mapping draw, AA,
read-back) without AA, with MSAA and with the FXAA pass (:class:`deformgl.render.fxaa.FxaaPass`),
and each one's image against a reference as a pixel difference: 8x MSAA where the renderer has it;
llvmpipe stops at 4x (``GL_MAX_SAMPLES``), and there the reference is 4x MSAA at twice the size in
each direction averaged 2x2, 16 samples per pixel (:func:`reference_image`)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass

import moderngl
import numpy as np

from deformgl.render.passes import RenderTarget

#: The modes compared: name -> (MSAA samples, FXAA).
AA_MODES: dict[str, tuple[int, bool]] = {"no AA": (0, False), "4x MSAA": (4, False), "FXAA": (0, True)}
#: MSAA samples of the reference image where the renderer has them.
REFERENCE_SAMPLES = 8
#: A pixel "differs" when a channel is off by more than this (of 255).
DIFF_THRESHOLD = 16


@dataclass
class FrameBudget:
    """One AA mode's frame, ms per stage (medians of ``repeats`` frames, each stage timed with
    a ``ctx.finish()`` after it), and its image against 8x MSAA.

    Attributes:
        steps_ms: the simulation steps; draw_ms: clear + the mapped-mesh draw (rasterised at the
            MSAA sample count); aa_ms: the MSAA resolve or the FXAA pass; read_ms: glReadPixels.
        mean_diff: mean |image - reference| per channel (of 255); differing: fraction of pixels
            with a channel off by more than :data:`DIFF_THRESHOLD`.
    """

    steps_ms: float
    draw_ms: float
    aa_ms: float
    read_ms: float
    mean_diff: float
    differing: float

    @property
    def frame_ms(self) -> float:
        return self.steps_ms + self.draw_ms + self.aa_ms + self.read_ms


def image_difference(image: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """(mean |difference| per channel, fraction of pixels with a channel off by > DIFF_THRESHOLD)."""
    d = np.abs(image.astype(np.int16) - reference.astype(np.int16))
    return float(d.mean()), float((d.max(axis=2) > DIFF_THRESHOLD).mean())


def reference_name(ctx: moderngl.Context) -> str:
    """What :func:`reference_image` renders on this context."""
    if int(ctx.info.get("GL_MAX_SAMPLES", 1)) >= REFERENCE_SAMPLES:
        return f"{REFERENCE_SAMPLES}x MSAA"
    return "4x MSAA at 2x2 the size, averaged (16 samples/pixel)"


def reference_image(ctx: moderngl.Context, draw: Callable[[], None], size: int,
                    background: tuple[float, float, float]) -> np.ndarray:
    """The anti-aliased reference of ``draw`` at ``size``² (see :func:`reference_name`);
    (size, size, 3) uint8. ``draw`` must fill the viewport alike at any size (a square view)."""
    if int(ctx.info.get("GL_MAX_SAMPLES", 1)) >= REFERENCE_SAMPLES:
        scale, samples = 1, REFERENCE_SAMPLES
    else:
        scale, samples = 2, 4
    target = RenderTarget(ctx, (size * scale, size * scale), samples)
    try:
        target.begin(background)
        draw()
        image = target.read_rgb().astype(np.float64)
    finally:
        target.release()
    image = image.reshape(size, scale, size, scale, 3).mean(axis=(1, 3))
    return np.rint(image).astype(np.uint8)


def frame_budgets(ctx: moderngl.Context, step: Callable[[], None], draw: Callable[[], None], size: int,
                  background: tuple[float, float, float], repeats: int = 5,
                  culled: Callable[[], None] | None = None) -> dict[str, FrameBudget]:
    """Time ``step`` (the frame's simulation steps) and ``draw`` (one draw of the scene into the
    bound target) per stage for each of :data:`AA_MODES` at ``size``², and compare the images
    of one and the same state (no step in between) with :func:`reference_image`'s (of ``draw``).
    ``culled``: the same draw with back faces culled ([render] cull), timed and compared too,
    as the modes "<mode> + cull"."""
    draws = {name: draw for name in AA_MODES}
    if culled is not None:
        draws.update({f"{name} + cull": culled for name in AA_MODES})
    modes = {name: AA_MODES[name.removesuffix(" + cull")] for name in draws}
    targets: dict[str, RenderTarget] = {}
    try:
        for name, (samples, fxaa) in modes.items():
            targets[name] = RenderTarget(ctx, (size, size), samples, fxaa=fxaa)

        def image(name: str) -> np.ndarray:
            t = targets[name]
            t.begin(background)
            draws[name]()
            return t.read_rgb()

        reference = reference_image(ctx, draw, size, background)
        quality = {name: image_difference(image(name), reference) for name in draws}
        stages: dict[str, list[list[float]]] = {name: [[], [], [], []] for name in draws}
        for r in range(repeats):  # the modes alternate within each round
            for name in (list(draws) if r % 2 == 0 else list(reversed(draws))):
                t = targets[name]
                t0 = time.perf_counter()
                step()
                ctx.finish()
                t1 = time.perf_counter()
                t.begin(background)
                draws[name]()
                ctx.finish()
                t2 = time.perf_counter()
                source = t.resolve()
                ctx.finish()
                t3 = time.perf_counter()
                t.read_rgb(source)
                t4 = time.perf_counter()
                for i, dt in enumerate((t1 - t0, t2 - t1, t3 - t2, t4 - t3)):
                    stages[name][i].append(dt * 1e3)
    finally:
        for t in targets.values():
            t.release()
    out = {}
    for name in draws:
        steps_ms, draw_ms, aa_ms, read_ms = (statistics.median(s) for s in stages[name])
        out[name] = FrameBudget(steps_ms, draw_ms, aa_ms, read_ms, *quality[name])
    return out


def format_budgets(budgets: dict[str, FrameBudget], info: dict) -> list[str]:
    """The ``studies.render_speed`` lines of the frame budget split and the AA image differences
    (``info["reference"]``: :func:`reference_name`)."""
    lines = [f"frame budget at {info['frame_size']}x{info['frame_size']}, {info['frame_steps']} steps + one "
             "curvature-corrected draw + AA + read-back (median ms per stage); image of the same state against "
             f"{info.get('reference', 'the reference')}: mean |difference| of 255, pixels off by > {DIFF_THRESHOLD}",
             f"{'AA':>14} | {'steps':>7} | {'draw':>7} | {'AA':>6} | {'read':>6} | {'frame':>7} | {'frames/s':>8} | "
             f"{'mean diff':>9} | {'pixels off':>10}"]
    for name, b in budgets.items():
        lines.append(f"{name:>14} | {b.steps_ms:>7.1f} | {b.draw_ms:>7.1f} | {b.aa_ms:>6.2f} | {b.read_ms:>6.2f} | "
                     f"{b.frame_ms:>7.1f} | {1e3 / b.frame_ms:>8.1f} | {b.mean_diff:>9.3f} | {b.differing:>9.2%}")
    return lines
