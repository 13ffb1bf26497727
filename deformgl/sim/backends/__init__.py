"""The GPU simulation backends: the foundation's packed-normal Verlet fragment pass (Mosegaard &
Sørensen 2005, 3.1), fragment-pass integrators and transform-feedback integrators (Movania & Feng
2012).
"""
