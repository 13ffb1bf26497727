"""Detailed-mesh mappings of Mosegaard & Sørensen 2005, section 3.3: binding vertices to node
triangles, the constant and curvature-corrected bases (float64 references), tangents, and nodes
driven from outside.
"""
