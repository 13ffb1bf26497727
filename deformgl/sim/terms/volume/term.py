"""The cells' volumetric term and corner barrier (:mod:`deformgl.sim.terms.volume.energy`) as one physics term
(:class:`deformgl.sim.terms.Term`): its float64 force and energy, its Hessian (Gauss-Newton, or
the form that goes with the springs' ``geometric`` option: :mod:`deformgl.sim.terms.volume.hessian`), its
share of the dt bound (the centre term at rest, the barrier's envelope), its GLSL forms
(:mod:`deformgl.sim.terms.volume.chunks`: the passes' chunk and the transform-feedback chunk) and its
XPBD form (:mod:`deformgl.sim.terms.volume.xpbd_form`, on the GPU :class:`deformgl.sim.terms.volume.cell_xpbd.XpbdCells`). A
system with ``cells`` holds one as the first of its terms (:class:`~deformgl.sim.springs.SpringSystem`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from deformgl.grid.nodes import NodeGrid
from deformgl.sim.terms.volume.hessian import CELL_HESSIAN, cell_matrix
from deformgl.sim.terms.base import FeedbackTerm, GlslTerm, Term, TermNeeds
from deformgl.sim.terms.volume.energy import (CellVolumes, barrier_envelope_product, barrier_envelope_triplets,
                                              describe_inverted, frequency_terms, rest_product,
                                              rest_stiffness_triplets, volume_energy, volume_forces)
from deformgl.sim.terms.volume.chunks import TERM_NAME, volume_feedback, volume_glsl
from deformgl.sim.terms.volume.xpbd_form import CellConstraints

__all__ = ["NEEDS", "VolumeTerm"]

#: What the term costs, from the scene alone (:class:`~deformgl.sim.terms.TermNeeds`): on the host
#: the cells' (C, 8) int64 corners (C <= N) and the GPU gather's (N, 27) int32 neighbourhood table
#: (:mod:`deformgl.sim.terms.volume.tables`); on the GPU backends its 27-neighbourhood and incident-cell
#: mask, 7 RGBA32I texels per node texel (an upper bound: dense grids compute the neighbourhood).
#: Every integrator runs it.
NEEDS = TermNeeds("material", host_bytes_per_node=8 * 8 + 27 * 4, texel_bytes=7 * 16)


@dataclass(frozen=True, eq=False)
class VolumeTerm(Term):
    """The physics term of ``cells`` (immutable)."""

    cells: CellVolumes

    name = TERM_NAME

    def acts(self) -> bool:
        """At least one cell and a modulus > 0."""
        c = self.cells
        return c.count > 0 and (c.volume_modulus > 0 or c.barrier_modulus > 0)

    def add_forces(self, x: np.ndarray, v: np.ndarray, t: float, out: np.ndarray) -> None:
        """:func:`~deformgl.sim.terms.volume.energy.volume_forces` (the centre term and the corner barrier)."""
        volume_forces(self.cells, x, out=out)

    def energy(self, x: np.ndarray) -> float:
        """:func:`~deformgl.sim.terms.volume.energy.volume_energy`."""
        return volume_energy(self.cells, x)

    def stiffness(self, x: np.ndarray) -> sp.csr_matrix:
        """The Gauss-Newton Hessian at x (:func:`~deformgl.sim.terms.volume.hessian.cell_matrix`)."""
        return self.hessian(x)

    def hessian(self, x: np.ndarray, geometric: str = "projected") -> sp.csr_matrix:
        """The Hessian in the form that goes with the springs' ``geometric``
        (:data:`~deformgl.sim.terms.volume.hessian.CELL_HESSIAN`)."""
        return cell_matrix(self.cells, x, len(x), CELL_HESSIAN[geometric])

    def dt_stiffness(self, x_rest: np.ndarray, *, barrier: bool = False) -> sp.csr_matrix:
        """The centre term's stiffness at rest (the barrier is inactive there) and, with
        ``barrier``, the barrier's envelope (:func:`~deformgl.sim.terms.volume.energy.barrier_envelope_product`)."""
        n = 3 * len(x_rest)
        parts = [rest_stiffness_triplets(self.cells)] + ([barrier_envelope_triplets(self.cells)] if barrier else [])
        rows, cols, values = (np.concatenate(a) for a in zip(*parts))
        return sp.csr_matrix((values, (rows, cols)), shape=(n, n))

    def dt_product(self, x_rest: np.ndarray, dx: np.ndarray, *, barrier: bool = False) -> np.ndarray:
        """:func:`~deformgl.sim.terms.volume.energy.rest_product` (and the barrier's envelope) of dx."""
        out = rest_product(self.cells, dx)
        if barrier:
            out += barrier_envelope_product(self.cells, dx)
        return out

    def frequency_terms(self, x_rest: np.ndarray, *, barrier: bool = False) -> np.ndarray:
        """:func:`~deformgl.sim.terms.volume.energy.frequency_terms` (its bound on the node's ``m w^2``)."""
        return frequency_terms(self.cells, len(x_rest), barrier=barrier)

    def describe(self) -> str:
        return f"the cells' inversion barrier, kappa_b = {self.cells.barrier_modulus:.4g} Pa"

    def limit_share(self, x_rest: np.ndarray, node: int, springs: float) -> str:
        """The barrier's envelope (not the centre term) against the springs' share at ``node``."""
        if self.cells.barrier_modulus > 0:
            n = len(x_rest)
            envelope = (frequency_terms(self.cells, n, barrier=True) - frequency_terms(self.cells, n))[node]
            if envelope > springs:
                return self.describe()
        return ""

    def inversions(self, x: np.ndarray, grid: NodeGrid | None) -> tuple[int, str]:
        """:func:`~deformgl.sim.terms.volume.energy.describe_inverted` (a cell is inverted where its
        trilinear map has a Jacobian <= 0 at a corner)."""
        return describe_inverted(self.cells, x, None if grid is None else grid.ijk)

    def refusal(self, backend: str) -> str | None:
        return None  # (every backend runs it)

    def xpbd(self, inverse_mass: np.ndarray) -> CellConstraints:
        """Its XPBD form: the cells' volume constraints and corner barriers
        (:class:`~deformgl.sim.terms.volume.xpbd_form.CellConstraints`)."""
        return CellConstraints(self.cells, inverse_mass)

    def glsl(self, grid: NodeGrid | None) -> GlslTerm:
        """Its GLSL form (:func:`deformgl.sim.terms.volume.chunks.volume_glsl`)."""
        return volume_glsl(self.cells, grid)

    def feedback(self, grid: NodeGrid | None) -> FeedbackTerm:
        """Its transform-feedback form (:func:`deformgl.sim.terms.volume.chunks.volume_feedback`)."""
        return volume_feedback(self.cells, grid)
