"""deformgl: GPU soft bodies on a coarse grid, detailed meshes deformed by them, rendered headless."""

__version__ = "0.1.0"
