"""Every GLSL program deformgl builds, in every define variant it builds, enumerated from the code.

A :class:`Variant` is one program: its vertex and fragment files, its defines and its
transform-feedback varyings, as :class:`deformgl.gl.programs.Program` receives them. The spaces
come from the builders' own tables (the integrator specs of :mod:`deformgl.sim.stages`, the
layouts' defines, the census modes, the mapping passes, the
trilinear draw paths and normal modes), so a new stage or switch there adds
its variants here.

Two kinds of define are values rather than switches, and are reduced to classes in
:func:`variant_key` (the test that every built program is known uses the same key):

* counts (``DRAGS``, ``LOADS``, ``SPHERES``, ``PULLS``) size uniform arrays and bound loops:
  the classes are 0, 1 and "2 up to the limit", enumerated at 0, 1 and the limit
  (:data:`COUNT_LIMITS`: the scene file's limits, ``MAX_LOADS`` for loads and pulls);
* texture row widths of the feedback backend (``NODE_ROW``, ``SPRING_ROW``) are powers of two
  up to ``NODE_ROW_MAX`` / ``SPRING_ROW_MAX``, used only in ``%`` and ``/``: one class,
  enumerated at the largest width.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from deformgl.grid.blocks import BLOCK_SHAPES
from deformgl.scene.spec import MAX_DRAGS, MAX_SPHERES
from deformgl.sim.backends.feedback import NODE_ROW_MAX, SPRING_ROW_MAX, _varying
from deformgl.sim.backends.verlet_data import MAX_PULLS
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS
from deformgl.sim.scripted import MAX_LOADS
from deformgl.sim.stages import spec
from deformgl.trilinear.batches import PATHS
from deformgl.trilinear.normal_transform import NORMAL_MODES
from deformgl.trilinear.renderer import shader_defines as trilinear_defines

__all__ = ["COUNT_LIMITS", "ROW_LIMITS", "Variant", "all_variants", "covering_set", "held_tuples", "variant_key"]

#: Count defines and the largest value the code builds (the scene file's and the springs' limits).
COUNT_LIMITS: dict[str, int] = {"DRAGS": MAX_DRAGS, "LOADS": MAX_LOADS, "SPHERES": MAX_SPHERES,
                                "PULLS": MAX_PULLS}
#: Row-width defines of the feedback backend and their largest value.
ROW_LIMITS: dict[str, int] = {"NODE_ROW": NODE_ROW_MAX, "SPRING_ROW": SPRING_ROW_MAX}
#: Census pass modes (``NodeCensus``: snapshot copy, moved count, bad count).
CENSUS_MODES = ("COPY", "MOVED", "BAD")


@dataclass(frozen=True)
class Variant:
    """One program: shader files (fragment None for a vertex-only transform-feedback program),
    the defines both stages get, and the captured varyings."""

    vertex: str
    fragment: str | None
    defines: tuple[tuple[str, object], ...]
    varyings: tuple[str, ...] = ()

    @property
    def define_map(self) -> dict[str, object]:
        return dict(self.defines)

    @property
    def key(self) -> tuple:
        return variant_key(self.vertex, self.fragment, self.define_map, self.varyings)

    def label(self) -> str:
        """``vertex+fragment [DEFINES] -> varyings``, for messages."""
        names = " ".join(k if v is True else f"{k}={v}" for k, v in self.defines)
        files = f"{self.vertex}+{self.fragment}" if self.fragment else self.vertex
        return f"{files} [{names}]" + (f" -> {','.join(self.varyings)}" if self.varyings else "")


def _count_class(name: str, value: object) -> object:
    if isinstance(value, bool) or not isinstance(value, int):
        return value
    if value <= 1:
        return value
    return "many" if value <= COUNT_LIMITS[name] else value


def variant_key(vertex: str, fragment: str | None, defines: Mapping[str, object],
                varyings: tuple[str, ...] = ()) -> tuple:
    """The class of a program (see the module docstring): defines that are False or None are
    dropped (the preprocessor emits nothing for them), counts become 0, 1 or "many", row widths
    "pow2" when they are a power of two within the limit."""
    items = []
    for name, value in sorted(defines.items()):
        if value is False or value is None:
            continue
        if name in COUNT_LIMITS:
            value = _count_class(name, value)
        elif name in ROW_LIMITS and isinstance(value, int) and 0 < value <= ROW_LIMITS[name] \
                and value & (value - 1) == 0:
            value = "pow2"
        items.append((name, value))
    return (vertex, fragment, tuple(items), tuple(varyings))


def _counts(name: str) -> tuple[int, ...]:
    return (0, 1, COUNT_LIMITS[name])


def _v(vertex: str, fragment: str | None, defines: Mapping[str, object],
       varyings: tuple[str, ...] = ()) -> Variant:
    return Variant(vertex, fragment, tuple(sorted(defines.items())), tuple(varyings))


def _constraints() -> list[dict[str, object]]:
    """The constraint switches both integrator backends set: none, or a ground and/or spheres."""
    out: list[dict[str, object]] = [{"SPHERES": 0}]
    for ground, spheres in itertools.product((False, True), _counts("SPHERES")):
        if ground or spheres:
            out.append({"CONSTRAINTS": True, "GROUND": ground, "SPHERES": spheres})
    return out


def _forces() -> Iterator[dict[str, object]]:
    """Force switches shared by both backends: spring damping, wind, loads, drags."""
    for damping, wind, loads, drags in itertools.product(
            (False, True), (False, True), _counts("LOADS"), _counts("DRAGS")):
        d: dict[str, object] = {"SPRING_DAMPING": damping, "LOADS": loads, "DRAGS": drags}
        if wind:
            d["WIND"] = True
        yield d




def _term_sets(count: int, implicit: bool = False, *, neighbours: bool = True,
               hood: bool = True, prepass: bool = True) -> Iterator[dict[str, object]]:
    """The physics terms' defines (:meth:`deformgl.sim.terms.glsl.PassTerms.defines`): none, one
    shipped term in each of its forms (:data:`deformgl.sim.terms.registry.VARIANTS`) or a set of
    forms a system holds together (:data:`~deformgl.sim.terms.registry.TOGETHER`) whose grid
    neighbours the table of ``count`` neighbours holds; ``neighbours`` False: none that is called
    per neighbour (the foundation pass), ``hood`` False: none that reads the node's neighbourhood
    (a sheet), ``prepass`` False: none with passes of its own (the foundation pass refuses them)."""
    from deformgl.sim.terms.glsl import PassTerms
    from deformgl.sim.terms.registry import TOGETHER, VARIANTS

    yield {}
    for forms in (*((form,) for form in VARIANTS), *TOGETHER):
        if any(form.neighbours > count or (implicit and not form.implicit) or (form.neighbours and not neighbours)
               or (form.hood and not hood) or (form.passes and not prepass) for form in forms):
            continue
        defines = PassTerms(tuple(forms), implicit).defines()
        if implicit and any(form.hood for form in forms):
            defines["HOOD_NODES"] = True  # (implicit_passes.pass_defines)
        yield {k: v for k, v in defines.items() if v is not False}


def fragment_backend() -> Iterator[Variant]:
    """``FragmentIntegrator``: each integrator's stages (``_build``)."""
    shapes = [(layers, count, terms) for layers, count in ((5, 18), (6, 24)) for terms in _term_sets(count)]
    for name in EXPLICIT_INTEGRATORS:
        sp = spec(name)
        for (layers, count, terms), dense, weights, forces in itertools.product(
                shapes, (False, True), (False, True), list(_forces())):
            common: dict[str, object] = {"NB_LAYERS": layers, "NB_COUNT": count, "DENSE": dense,
                                         "SPRING_WEIGHTS": weights, "SPHERES": 0, **forces, **terms}
            if sp.velocity:
                common["VELOCITY"] = True
            for stage in sp.stages:
                for c in (_constraints() if stage.final else [{}]):
                    yield _v("sim/fullscreen.vert", "sim/integrators/step.frag",
                             {**common, **c, **stage.fragment_defines()})
    from deformgl.sim.terms.registry import VARIANTS

    # the terms' own passes (GlslTerm.passes: the pre-passes the stages run)
    for fragment in sorted({f for form in VARIANTS for f in form.passes}):
        yield _v("sim/fullscreen.vert", fragment, {})


def xpbd() -> Iterator[Variant]:
    """``XpbdFragment`` (deformgl/sim/backends/xpbd_gpu.py): prediction, Jacobi sweep, velocity."""
    for loads, wind in itertools.product(_counts("LOADS"), (False, True)):
        d: dict[str, object] = {"LOADS": loads}
        if wind:
            d["WIND"] = True
        yield _v("sim/fullscreen.vert", "sim/xpbd/predict.frag", d)
    from deformgl.sim.terms.constraints import XpbdChunk
    from deformgl.sim.terms.registry import XPBD_SHIPPED

    # the physics terms' chunks (XpbdFragment.term_passes): none, or one shipped chunk in each variant
    variants = [XpbdChunk(c.prefix, c.file, c.passes, defines) for c in XPBD_SHIPPED for defines in c.variants]
    sweeps: list[dict[str, object]] = [{}, *(v.sweep_defines() for v in variants)]
    for (layers, count), damping, drags, c, terms in itertools.product(((5, 18), (6, 24)), (False, True),
                                                                       _counts("DRAGS"), _constraints(), sweeps):
        yield _v("sim/fullscreen.vert", "sim/xpbd/iterate.frag",
                 {"NB_LAYERS": layers, "NB_COUNT": count, "SPRING_DAMPING": damping, "DRAGS": drags, **c, **terms})
    for v in variants:
        for fragment in v.passes:
            yield _v("sim/fullscreen.vert", fragment, dict(v.defines))
    yield _v("sim/fullscreen.vert", "sim/xpbd/finish.frag", {})


def feedback_backend() -> Iterator[Variant]:
    """``FeedbackSimulation``: one vertex-only program per stage (``_add_pass``)."""
    from deformgl.sim.terms.registry import FEEDBACK_SHIPPED

    # the physics terms' chunks (FeedbackSimulation.feedback_terms): none, or one shipped chunk
    term_sets: list[dict[str, object]] = [{}, *({"FEEDBACK_TERMS": True, f"TERM_{f.prefix.upper()}": True, **f.defines}
                                               for f in FEEDBACK_SHIPPED)]
    for name in EXPLICIT_INTEGRATORS:
        sp = spec(name)
        for forces, c, terms in itertools.product(list(_forces()), _constraints(), term_sets):
            common: dict[str, object] = {"NODE_ROW": NODE_ROW_MAX, "SPRING_ROW": SPRING_ROW_MAX, **forces, **c,
                                         **terms}
            if not common["SPRING_DAMPING"]:
                del common["SPRING_DAMPING"]
            if sp.velocity:
                common["VELOCITY"] = True
            for stage in sp.stages:
                yield _v(stage.vertex, None, {**common, **stage.feedback_defines()},
                         tuple(_varying(b) for b in stage.writes))


#: The compact layout's two lookups (deformgl/grid/nodes.py CompactLayout.shader_defines).
_LAYOUTS: tuple[dict[str, object], ...] = ({"COMPACT": True, "COMPACT_DENSE": False},
                                           {"COMPACT": True, "COMPACT_DENSE": True})


def foundation() -> Iterator[Variant]:
    """``VerletPass`` and ``NodeNormalsPass`` (``deformgl.mapping.node_drivers``), on both
    lookups of the compact layout."""
    # weights: none, the weight texture, the levels code (SPRING_WEIGHT_LEVELS)
    for pulls, layout, weights, terms in itertools.product(
            _counts("PULLS"), _LAYOUTS, (None, "texture", "levels"), list(_term_sets(18, neighbours=False, prepass=False))):
        yield _v("sim/fullscreen.vert", "sim/verlet.frag", {"PULLS": pulls, "SPRING_WEIGHTS": weights is not None,
                                                           "SPRING_WEIGHT_LEVELS": weights == "levels", **layout, **terms})
    for layout in _LAYOUTS:
        yield _v("sim/fullscreen.vert", "sim/node_normals.frag", layout)


def blocked() -> Iterator[Variant]:
    """``BlockedVerletPass`` and the compact view's copy (``deformgl.sim.backends.blocked``):
    every block shape, its blocks by strides or from the table, the foundation's switches."""
    for shape, dense, pulls, weights, terms, flat in itertools.product(
            BLOCK_SHAPES, (False, True), _counts("PULLS"), (None, "texture", "levels"),
            list(_term_sets(18, neighbours=False, prepass=False)), itertools.product((False, True), repeat=3)):
        # (flat: the axes a grid is one node thick along; it has no full cell, no term that reads the neighbourhood)
        if any(flat) and terms.get("TERMS_HOOD"):
            continue
        block = {"BLOCKED": True, "BLOCK_X": shape[0], "BLOCK_Y": shape[1], "BLOCK_Z": shape[2],
                 **{f"BLOCK_FLAT_{a}": f for a, f in zip("XYZ", flat)}}
        yield _v("sim/fullscreen.vert", "sim/verlet_block.frag", {
            **block, "BLOCKED_DENSE": dense, "PULLS": pulls,
            "SPRING_WEIGHTS": weights is not None, "SPRING_WEIGHT_LEVELS": weights == "levels", **terms})
    for shape in BLOCK_SHAPES:
        yield _v("sim/fullscreen.vert", "sim/unblock.frag", {"BLOCK_X": shape[0], "BLOCK_Y": shape[1], "BLOCK_Z": shape[2]})


def cells() -> Iterator[Variant]:
    """``NodeCellForces`` (``deformgl.sim.terms.volume.check_pass``): the volumetric term alone, per node."""
    from deformgl.sim.terms.volume.chunks import CELL_FORMS

    for dense, form in itertools.product((False, True), CELL_FORMS):
        yield _v("sim/fullscreen.vert", "terms/cell_alone.frag",
                 {"COMPACT_DENSE": dense, **{k: v for k, v in form.defines.items() if v}})


def census() -> Iterator[Variant]:
    for mode in CENSUS_MODES:
        yield _v("sim/fullscreen.vert", "census/census.frag", {mode: True})


def render() -> Iterator[Variant]:
    """Grid surface, overlay, mapped mesh (in the vertex shader, by transform feedback or a fragment
    pass first; capture), static mesh."""
    yield _v("render/grid_surface.vert", "render/lit_surface.frag", {})
    yield _v("render/grid_surface.vert", None, {}, ("v_world", "v_normal"))
    yield _v("render/grid_lines.vert", "render/flat_colour.frag", {})
    yield _v("sim/fullscreen.vert", "render/fxaa.frag", {})  # [render] aa = "fxaa"
    yield _v("render/static_mesh.vert", "render/mapped_mesh.frag", {})
    for curvature, normal_map in itertools.product((False, True), (False, True)):
        d = {"CURVATURE": curvature, "NORMAL_MAP": normal_map}
        yield _v("render/mapped_mesh.vert", "render/mapped_mesh.frag", d)
        yield _v("render/mapped_mesh.vert", None, d, ("v_world", "v_normal"))
        names = ("v_world", "v_normal") + (("v_tangent", "v_handedness", "v_uv") if normal_map else ())
        yield _v("render/mapped_mesh.vert", None, d, names)
        yield _v("sim/fullscreen.vert", "render/mapped_premap.frag", d)  # mapping_pass = "fragment"
    yield _v("sim/fullscreen.vert", "render/bspline_premap.frag", {})  # a spline body's mapping
    for normal_map in (False, True):
        yield _v("render/mapped_cached.vert", "render/mapped_mesh.frag", {"NORMAL_MAP": normal_map})
        yield _v("render/mapped_premapped.vert", "render/mapped_mesh.frag", {"NORMAL_MAP": normal_map})


def trilinear() -> Iterator[Variant]:
    for path, normals, form in itertools.product(PATHS, NORMAL_MODES, (1, 4)):
        d = trilinear_defines(path, normals, form)
        yield _v("trilinear/transform.vert", "trilinear/lit.frag", d)
        yield _v("trilinear/transform.vert", None, d, ("v_world", "v_normal"))


GROUPS = {"fragment backend": fragment_backend, "xpbd": xpbd, "feedback backend": feedback_backend,
          "foundation and normals": foundation, "blocked": blocked, "cells": cells, "census": census, "render": render,
          "trilinear": trilinear}


def all_variants() -> list[Variant]:
    """Every program variant, deduplicated by :func:`variant_key`, in a stable order."""
    seen: dict[tuple, Variant] = {}
    for group in GROUPS.values():
        for v in group():
            seen.setdefault(v.key, v)
    return list(seen.values())


def implicit() -> Iterator[Variant]:
    """``ImplicitFragment`` (``deformgl.sim.backends.implicit_gpu``): its passes and the sum."""
    from deformgl.sim.backends.implicit_passes import (MG_CG_PASSES, MG_PASSES, PASSES,
                                                    PRECONDITIONED_PASSES, PRODUCT_PASSES, TERM_PASSES)

    shapes = [(layers, count, terms) for layers, count in ((5, 18), (6, 24)) for terms in _term_sets(count, True)]
    for (layers, count, terms), weights, forces in itertools.product(shapes, (False, True), list(_forces())):
        common: dict[str, object] = {"NB_LAYERS": layers, "NB_COUNT": count, "SPRING_WEIGHTS": weights,
                                     "SPHERES": 0, **forces}
        nb: dict[str, object] = {"NB_LAYERS": layers, "NB_COUNT": count, "SPHERES": 0}
        for name in PASSES + MG_PASSES:  # (pass_defines: loads in SETUP only, no force switches after MATVEC)
            if name in (*PRODUCT_PASSES, *MG_PASSES) and forces["LOADS"]:
                continue
            defines = common if name in ("SETUP", *PRODUCT_PASSES, *MG_PASSES) else nb
            if terms and name in TERM_PASSES:
                defines = {**defines, **terms}
            elif terms:
                continue  # (the passes without the terms are the variants above)
            # block-Jacobi (PRECOND_BLOCK) in the passes that apply the preconditioner, the
            # scaled warm start (WARM_SCALED) in INIT
            # multigrid (pass_defines' multigrid): MULTIGRID in the CG passes, PRECOND_BLOCK in
            # the smoothing (MG_SMOOTH_ZERO: MG_SMOOTH from zero)
            blocks: tuple[dict[str, object], ...] = (
                ({}, {"PRECOND_BLOCK": True}) if name in PRECONDITIONED_PASSES else ({},))
            if name in MG_CG_PASSES:
                blocks += ({"MULTIGRID": True},)
            if name in MG_PASSES:
                blocks = ({"PRECOND_BLOCK": True},) if name != "MG_RESIDUAL" else ({},)
            pass_name: dict[str, object] = ({"MG_SMOOTH": True, "FROM_ZERO": True} if name == "MG_SMOOTH_ZERO"
                                            else {name: True})
            warm = ({}, {"WARM_SCALED": True}) if name == "INIT" else ({},)
            for c, block, scaled in itertools.product(_constraints() if name == "FINAL" else [{}], blocks, warm):
                yield _v("sim/fullscreen.vert", "sim/implicit/implicit.frag",
                         {**defines, **c, **block, **scaled, **pass_name})
    yield _v("sim/fullscreen.vert", "sim/implicit/reduce.frag", {})
    # the multigrid's coarse levels (deformgl.sim.backends.multigrid_gpu)
    for level_pass in ({"LEVEL_SMOOTH": True}, {"LEVEL_SMOOTH": True, "FROM_ZERO": True}, {"LEVEL_RESIDUAL": True},
                       {"RESTRICT": True}, {"PROLONG": True}, {"COARSEST": True}, {"RZ": True},
                       {"RZ": True, "RZ_INIT": True}):
        yield _v("sim/fullscreen.vert", "sim/implicit/multigrid.frag", level_pass)


GROUPS["implicit"] = implicit


def _encoding(group: list[Variant], strength: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """How :func:`held_tuples` and :func:`covering_set` number a group's ``strength``-tuples: the
    (variants, columns) index of each define's value per variant (absent and False alike), with
    ``strength`` constant columns after the defines (so a program with fewer defines still has
    whole tuples); the (tuples, strength) columns of every tuple; the weights that make a tuple's
    values one integer, below ``span``."""
    keys = sorted({k for v in group for k, _ in v.defines})
    values = np.zeros((len(group), len(keys) + strength), np.int64)
    for j, k in enumerate(keys):
        index: dict[object, int] = {}
        for i, v in enumerate(group):
            value = v.define_map.get(k)
            values[i, j] = index.setdefault(None if value is False else value, len(index))
    tuples = np.array(list(itertools.combinations(range(values.shape[1]), strength)), np.int64)
    radix = int(values.max()) + 1
    return values, tuples, radix ** np.arange(strength - 1, -1, -1), radix ** strength


def held_tuples(group: list[Variant], strength: int = 3) -> set[int]:
    """Every ``strength``-tuple of define values ``group`` (variants of one pair of files) holds,
    each as one integer (the tuple's columns and values)."""
    values, tuples, weights, span = _encoding(group, strength)
    codes = np.concatenate([values[i:i + 1024][:, tuples] @ weights for i in range(0, len(group), 1024)])
    return set(np.unique(codes + np.arange(len(tuples)) * span).tolist())


def covering_set(variants: list[Variant], strength: int = 3) -> list[Variant]:
    """A subset of ``variants`` that, for each pair of shader files, holds every combination of
    values of any ``strength`` of its defines that the full set holds (every triple by default:
    a pass with both cell terms, a preconditioner with a term, ...; a greedy covering array,
    in enumeration order: deterministic). The full product of a stage's switches runs to tens of
    thousands of sources (the integrators' step.frag alone 34,272); a fault needs four switches
    together to escape the triples. What :mod:`deformgl.pack.glslang` runs in CI;
    :func:`all_variants` is what built programs are checked against (tests/conftest.py)."""
    groups: dict[tuple, list[Variant]] = {}
    for v in variants:
        groups.setdefault((v.vertex, v.fragment), []).append(v)
    out: list[Variant] = []
    for group in groups.values():
        values, tuples, weights, span = _encoding(group, strength)
        covered = np.zeros((len(tuples), span), bool)
        rows = np.arange(len(tuples))
        for i, v in enumerate(group):
            codes = values[i, tuples] @ weights
            if i == 0 or not covered[rows, codes].all():
                covered[rows, codes] = True
                out.append(v)
    return out
