"""GLSL shader files of deformgl (the reference shader pack); see README.md in this folder."""
