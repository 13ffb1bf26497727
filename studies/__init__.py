"""The studies behind the tables of docs/ACCURACY.md and docs/PERFORMANCE.md: one command each,
run from the repository root (``python -m studies.scaling``). Not part of the wheel: the product
(:mod:`deformgl`) never imports them (the import contract in pyproject.toml)."""
