"""One animated glTF 2.0 binary (.glb) of a deformed mesh sequence: the first frame as the mesh,
every later frame as a morph target (position and normal offsets), and an animation of the
morph weights that shows frame k at time k / fps (one weight 1, the others 0; linear between).

Written atomically (:func:`deformgl.files.write_atomic`). Layout: one buffer of float32 positions
and normals (frame 0), uint32 indices, per target float32 position and normal deltas, then the
keyframe times and weights; POSITION accessors carry the min/max glTF requires.
"""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Sequence

import numpy as np

from deformgl.files import write_atomic

__all__ = ["glb_morph_bytes", "write_morph_glb"]

_FLOAT, _UINT = 5126, 5125
_ARRAY, _ELEMENTS = 34962, 34963


def _unit(n: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return (n / np.where(length > 0, length, 1.0)).astype(np.float32)


def glb_morph_bytes(frames: Sequence[tuple[np.ndarray, np.ndarray]], faces: np.ndarray, fps: float) -> bytes:
    """The .glb of ``frames`` ((V, 3) vertices and normals each, the same V) on ``faces``."""
    base_v = np.asarray(frames[0][0], np.float32)
    base_n = _unit(np.asarray(frames[0][1], np.float32))
    blobs: list[bytes] = []
    views: list[dict] = []
    accessors: list[dict] = []

    def add(data: np.ndarray, kind: str, ctype: int, target: int | None = None, bounds: bool = False) -> int:
        raw = np.ascontiguousarray(data).tobytes()
        offset = sum(len(b) for b in blobs)
        blobs.append(raw + b"\0" * (-len(raw) % 4))
        view = {"buffer": 0, "byteOffset": offset, "byteLength": len(raw)}
        if target is not None:
            view["target"] = target
        views.append(view)
        acc = {"bufferView": len(views) - 1, "componentType": ctype, "count": int(len(data)), "type": kind}
        if bounds:
            acc["min"] = [float(x) for x in data.min(axis=0)]
            acc["max"] = [float(x) for x in data.max(axis=0)]
        accessors.append(acc)
        return len(accessors) - 1

    position = add(base_v, "VEC3", _FLOAT, _ARRAY, bounds=True)
    normal = add(base_n, "VEC3", _FLOAT, _ARRAY)
    indices = add(np.asarray(faces, np.uint32).reshape(-1), "SCALAR", _UINT, _ELEMENTS)
    targets = []
    for v, n in frames[1:]:
        dv = np.asarray(v, np.float32) - base_v
        dn = _unit(np.asarray(n, np.float32)) - base_n
        targets.append({"POSITION": add(dv, "VEC3", _FLOAT, _ARRAY, bounds=True),
                        "NORMAL": add(dn, "VEC3", _FLOAT, _ARRAY)})
    count = len(targets)
    primitive: dict = {"attributes": {"POSITION": position, "NORMAL": normal}, "indices": indices, "mode": 4}
    mesh: dict = {"primitives": [primitive]}
    gltf: dict = {"asset": {"version": "2.0", "generator": "deformgl"}, "scene": 0,
                  "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}], "meshes": [mesh]}
    if count:
        primitive["targets"] = targets
        mesh["weights"] = [0.0] * count
        times = (np.arange(count + 1) / float(fps)).astype(np.float32)
        weights = np.zeros((count + 1, count), np.float32)
        weights[np.arange(1, count + 1), np.arange(count)] = 1.0
        t = add(times, "SCALAR", _FLOAT)
        accessors[t]["min"], accessors[t]["max"] = [float(times[0])], [float(times[-1])]
        w = add(weights.reshape(-1), "SCALAR", _FLOAT)
        gltf["animations"] = [{"name": "deformgl frames", "samplers": [{"input": t, "output": w,
                                                                        "interpolation": "LINEAR"}],
                               "channels": [{"sampler": 0, "target": {"node": 0, "path": "weights"}}]}]
    binary = b"".join(blobs)
    gltf["buffers"] = [{"byteLength": len(binary)}]
    gltf["bufferViews"], gltf["accessors"] = views, accessors
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks


def write_morph_glb(path: str | os.PathLike[str], frames: Sequence[tuple[np.ndarray, np.ndarray]],
                    faces: np.ndarray, fps: float) -> None:
    """Write :func:`glb_morph_bytes` atomically."""
    payload = glb_morph_bytes(frames, faces, fps)
    write_atomic(path, lambda stream: stream.write(payload))
