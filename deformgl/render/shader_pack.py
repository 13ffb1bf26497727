"""Inputs for the shader pack's example program (``examples/mapped_mesh_example.py``): what another
application would hold to draw a mapped mesh with ``shaders/render/mapped_mesh.*`` alone."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import moderngl
import numpy as np

from deformgl.gl.es_context import read_texture
from deformgl.render.camera import View
from deformgl.grid.nodes import CompactLayout, NodeGrid
from deformgl.files import write_atomic
from deformgl.render.mapped import MappedVertices
from deformgl.render.passes import Lighting


def pack_inputs(state: moderngl.Texture, grid: NodeGrid, layout: CompactLayout,
                data: MappedVertices, faces: np.ndarray, view: View, lighting: Lighting,
                size: tuple[int, int], background: tuple[float, float, float]) -> dict[str, np.ndarray | np.float32]:
    """The example's inputs (see its docstring for the keys); reads the state texture once."""
    w, h = layout.size
    image = np.frombuffer(read_texture(state), dtype="f4").reshape(h, w, 4)
    texels = {f"texel{c + 1}": layout.texel(grid.ijk[data.tri_nodes[:, c]]).astype("i4") for c in range(3)}
    u = lighting.uniforms()
    arrays: dict[str, np.ndarray | np.float32] = dict(
        state=image, **texels, weights=data.weights.astype("f4"), offset=data.offset.astype("f4"),
        offset_world=data.offset_world.astype("f4"), normal=data.normal.astype("f4"),
        normal_world=data.normal_world.astype("f4"), curvature=data.use_curvature.astype("f4"),
        faces=np.asarray(faces, dtype="i4"), view_projection=view.view_projection.astype("f4"),
        eye=np.asarray(view.eye, dtype="f4"), light_direction=np.asarray(u["u_light_direction"]),
        light_colour=np.asarray(u["u_light_colour"]), material_colour=np.asarray(u["u_material_colour"]),
        ambient=np.float32(lighting.ambient), specular=np.float32(lighting.specular),
        shininess=np.float32(lighting.shininess), size=np.asarray(size), background=np.asarray(background))
    return arrays


def write_pack_inputs(path: Path, arrays: Mapping[str, np.ndarray | np.float32]) -> None:
    """Write the example's ``.npz`` atomically."""
    # allow_pickle=True is numpy's default, named so that mypy knows ``arrays`` cannot hold it
    write_atomic(path, lambda stream: np.savez_compressed(stream, allow_pickle=True, **arrays))
