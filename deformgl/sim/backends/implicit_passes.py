"""The passes of ``shaders/sim/implicit/implicit.frag`` and their defines: which pass evaluates
what (the physics terms, the preconditioner), the texture units they read on, and
:func:`pass_defines`, what :class:`~deformgl.sim.backends.implicit_gpu.ImplicitFragment` compiles
and :mod:`deformgl.pack.variants` enumerates."""

from __future__ import annotations

import numpy as np

from deformgl.sim.integrators import Constraints
from deformgl.sim.springs import SpringSystem

__all__ = ["TERM_PASSES", "TERM_UNITS", "PASSES", "PRODUCT_PASSES", "MG_PASSES", "MG_CG_PASSES", "PRECONDITIONED_PASSES",
           "UNITS", "REDUCE_UNIT", "pass_defines"]

#: The passes of ``implicit.frag`` (one define each).
PASSES = ("SETUP", "WARM", "INIT", "MATVEC", "UPDATE", "DIRECTION", "FINAL", "TRUE_RESIDUAL")
#: The passes that evaluate A's product (the springs, the node terms and the physics terms).
PRODUCT_PASSES = ("WARM", "INIT", "MATVEC", "TRUE_RESIDUAL")
#: Its multigrid passes on the finest level (MG_SMOOTH_ZERO: MG_SMOOTH with FROM_ZERO).
MG_PASSES = ("MG_SMOOTH_ZERO", "MG_SMOOTH", "MG_RESIDUAL")
#: The passes that apply P^-1 (multigrid: MULTIGRID instead, the cycle runs between them).
MG_CG_PASSES = ("INIT", "UPDATE", "DIRECTION")
UNITS = {"u_node": 0, "u_neighbours": 1, "u_weights": 2, "u_x": 3, "u_v": 4, "u_vec": 5, "u_inv": 6,
          "u_b": 7, "u_dv": 8, "u_r": 9, "u_p": 10, "u_q": 11, "u_rz": 12, "u_pq": 13, "u_rz_new": 14,
          "u_warm": 13}  # (u_warm: INIT only, which reads no u_pq)
REDUCE_UNIT = 15
#: block-Jacobi's off-diagonal texture shares the reduction's unit (OpenGL ES 3 guarantees 16
#: units): every draw binds what it reads, and no pass reads both.
UNITS["u_inv_off"] = REDUCE_UNIT
#: The passes that apply P^-1 (block-Jacobi: they read ``inv_off`` too).
PRECONDITIONED_PASSES = ("SETUP", "INIT", "UPDATE", "DIRECTION")
#: The passes that evaluate the physics terms (deformgl.sim.terms: forces in SETUP, K y in
#: :data:`PRODUCT_PASSES` and the multigrid's fine passes); a term that reads the node's 3x3x3
#: neighbourhood (HOOD_NODES) reads its 27-node table on the unit of ``u_rz``, which only UPDATE and
#: DIRECTION read.
TERM_PASSES = ("SETUP", *PRODUCT_PASSES, *MG_PASSES)
UNITS["u_hood_nodes"] = UNITS["u_rz"]
#: The multigrid passes' right-hand side and DIRECTION's z, on the unit of ``u_q``, which neither reads.
UNITS["u_mg_rhs"] = UNITS["u_z"] = UNITS["u_q"]
#: The units the terms' node tables use in :data:`TERM_PASSES`: those of dv, p and rz_new, which
#: only UPDATE, DIRECTION and FINAL read.
TERM_UNITS = (UNITS["u_dv"], UNITS["u_p"], UNITS["u_rz_new"])


def pass_defines(system: SpringSystem, *, flexion: bool, weights: bool, drags: int, loads: int,
                 constraints: Constraints | None, block: bool = False,
                 scaled: bool = True,
                 multigrid: bool = False, term_defines: dict[str, object] | None = None) -> dict[str, dict[str, object]]:
    """The defines of each pass of ``implicit.frag`` (what :mod:`deformgl.pack.variants` lists);
    ``term_defines``: the physics terms' defines
    (:meth:`deformgl.sim.terms.glsl.PassTerms.defines`) in :data:`TERM_PASSES`; ``multigrid``: the V-cycle's passes
    (:data:`MG_PASSES`, with PRECOND_BLOCK in MG_SMOOTH's) and MULTIGRID in
    :data:`MG_CG_PASSES` (``block`` then puts PRECOND_BLOCK in SETUP only)."""
    common: dict[str, object] = {"NB_LAYERS": 6 if flexion else 5, "NB_COUNT": 24 if flexion else 18,
                                 "SPRING_DAMPING": bool(np.any(system.damping > 0)), "SPRING_WEIGHTS": weights,
                                 "DRAGS": drags, "LOADS": loads, "SPHERES": 0}
    if system.wind_drag > 0:
        common["WIND"] = True
    # only what each pass uses: the loads enter b (SETUP), the spring and node terms A (SETUP,
    # INIT, MATVEC); UPDATE, DIRECTION and FINAL combine vectors (FINAL: and the constraints)
    nb = {"NB_LAYERS": common["NB_LAYERS"], "NB_COUNT": common["NB_COUNT"], "SPHERES": 0}
    product = {**common, "LOADS": 0}
    names = PASSES + (MG_PASSES if multigrid else ())
    out = {name: {**(common if name == "SETUP" else product if name in (*PRODUCT_PASSES, *MG_PASSES)
                     else nb), name: True} for name in names}
    if multigrid:
        out["MG_SMOOTH_ZERO"] = {**out.pop("MG_SMOOTH_ZERO"), "MG_SMOOTH": True, "FROM_ZERO": True}
        del out["MG_SMOOTH_ZERO"]["MG_SMOOTH_ZERO"]
        for name in MG_CG_PASSES:
            out[name]["MULTIGRID"] = True
        for name in ("MG_SMOOTH_ZERO", "MG_SMOOTH"):
            out[name]["PRECOND_BLOCK"] = True
    if scaled:
        out["INIT"]["WARM_SCALED"] = True
    c = constraints
    if c is not None and (c.ground is not None or c.spheres):
        out["FINAL"].update(CONSTRAINTS=True, GROUND=c.ground is not None, SPHERES=len(c.spheres))
    if block:
        for name in ("SETUP",) if multigrid else PRECONDITIONED_PASSES:
            out[name]["PRECOND_BLOCK"] = True
    hood = {"HOOD_NODES": True} if (term_defines or {}).get("TERMS_HOOD") else {}
    for name in (n for n in TERM_PASSES if n in out):
        out[name].update(term_defines or {}, **hood)
    return out
