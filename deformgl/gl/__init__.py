"""OpenGL plumbing, the lowest layer: the EGL context, the GLSL preprocessor (``#include``,
defines), compiled programs and the owner of GL objects. Knows nothing of physics.
"""
