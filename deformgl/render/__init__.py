"""Drawing: cameras, render targets, the grid-surface and mapped-mesh passes (vertex texture fetch)
and the reference shader pack's inputs.
"""
