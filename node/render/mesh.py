"""A textured triangle mesh in world coordinates: the surface of a projection pose."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Mesh"]


@dataclass(frozen=True)
class Mesh:
    """A textured triangle mesh in world coordinates.

    Attributes
    ----------
    vertices : (V, 3) float32
        World mm.
    uvs : (V, 2) float32
        Texture coordinates; (0, 0) is the top-left corner of the content image and
        (1, 1) its bottom-right corner (content pixel x = u * W - 0.5).
    faces : (F, 3) uint32
        Vertex indices of each triangle, all < V.

    Arrays are converted to these dtypes (C-contiguous); shapes, finiteness and index
    ranges are checked (ValueError).
    """

    vertices: np.ndarray
    uvs: np.ndarray
    faces: np.ndarray

    def __post_init__(self) -> None:
        vertices = np.ascontiguousarray(self.vertices, dtype=np.float32)
        uvs = np.ascontiguousarray(self.uvs, dtype=np.float32)
        faces_in = np.asarray(self.faces)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or vertices.shape[0] < 3:
            raise ValueError(f"mesh vertices must be (V, 3) with V >= 3, got shape {vertices.shape}")
        if uvs.shape != (vertices.shape[0], 2):
            raise ValueError(f"mesh uvs must be (V, 2) = ({vertices.shape[0]}, 2), got shape {uvs.shape}")
        if faces_in.ndim != 2 or faces_in.shape[1] != 3 or faces_in.shape[0] < 1:
            raise ValueError(f"mesh faces must be (F, 3) with F >= 1, got shape {faces_in.shape}")
        if not np.issubdtype(faces_in.dtype, np.integer):
            raise ValueError(f"mesh faces must hold integer vertex indices, got {faces_in.dtype}")
        if faces_in.min() < 0 or faces_in.max() >= vertices.shape[0]:
            raise ValueError(
                f"mesh faces index vertices {int(faces_in.min())}..{int(faces_in.max())}, "
                f"but there are only {vertices.shape[0]} vertices"
            )
        if not (np.isfinite(vertices).all() and np.isfinite(uvs).all()):
            raise ValueError("mesh vertices and uvs must be finite")
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "uvs", uvs)
        object.__setattr__(self, "faces", np.ascontiguousarray(faces_in, dtype=np.uint32))
