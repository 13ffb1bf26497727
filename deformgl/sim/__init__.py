"""Simulation of the node grid: spring systems, the integrators of Movania & Feng 2012, the
stability limits and run guards, the blow-up census, the float64 references and the GPU backends
(``backends/``: fragment passes and transform feedback).
"""
