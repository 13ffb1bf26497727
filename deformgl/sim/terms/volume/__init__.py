"""The cells' volumetric term and corner inversion barrier (docs/EQUATIONS.md, "Any Poisson's
ratio"), one physics term in one package: its float64 energy, forces and inversion census
(:mod:`~deformgl.sim.terms.volume.energy`), its Hessian (:mod:`~deformgl.sim.terms.volume.hessian`),
the term object (:mod:`~deformgl.sim.terms.volume.term`), its GLSL chunks
(:mod:`~deformgl.sim.terms.volume.chunks`, ``shaders/terms/cell*``) and per-node tables
(:mod:`~deformgl.sim.terms.volume.tables`), its XPBD form (:mod:`~deformgl.sim.terms.volume.xpbd_form`)
and its check pass (:mod:`~deformgl.sim.terms.volume.check_pass`)."""
