"""Trilinear transformations in a scene graph (Knuth, Kohlhammer & Kuijper): the transforms, the
scene graph and its renderer, anchors, attachments to a simulated body, shapes and the paper's scenes.
"""
