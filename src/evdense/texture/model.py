"""The texturing settings (:class:`TextureConfig`) and a textured mesh (:class:`TexturedMesh`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evdense.mesh.geometry import (
    sample_bilinear,
)


@dataclass
class TextureConfig:
    """Settings of view selection, atlas packing and seam levelling."""

    smoothness: float = 1.0
    """Potts weight between neighbouring faces textured from different views (data costs are in [0, 1])."""
    mrf_cycles: int = 2
    """Alpha-expansion sweeps over all views."""
    min_facing_cos: float = 0.1
    """Cosine between a face normal and the direction to the camera needed to use a view."""
    border: float = 2.0
    """Pixels between a face's projection and the image border."""
    depth_tolerance: float = 0.01
    """Relative depth tolerance of the occlusion test against a view's depth map."""
    margin: int = 2
    """Texels of image content kept around each chart (bilinear filtering and mip-mapping at seams)."""
    max_atlas_size: int = 8192
    """Largest atlas side in texels; charts are scaled down uniformly beyond it."""
    level_seams: bool = True
    """Solve the additive seam-levelling correction."""
    seam_smoothness: float = 1.0
    """Weight of the within-chart smoothness of the correction, relative to seam agreement."""
    seam_max_angle: float = 30.0
    """Seams along creases sharper than this (degrees between face normals) are not levelled: the
    two sides are different surfaces, whose colours may differ."""
    seam_max_difference: float = 0.2
    """Seam samples whose colours differ by more than this (in [0, 1] units) are taken for a real
    colour edge (or an occlusion error), not an exposure difference, and not levelled."""
    max_views: int = 200
    """Views used at most (evenly spaced through the list)."""


@dataclass
class TexturedMesh:
    """A mesh with one texture atlas: ``vertices (V, 3)``, ``faces (F, 3)``, per-corner texture
    coordinates ``face_uvs (F, 3, 2)`` (OBJ convention: u right, v up, in [0, 1]) and the atlas
    ``(H, W, C)`` float32 in [0, 1]."""

    vertices: np.ndarray
    faces: np.ndarray
    face_uvs: np.ndarray
    atlas: np.ndarray
    face_view: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """The view that textures each face (-1: none saw it, flat colour)."""
    vertex_colors: np.ndarray | None = None
    """``(V, 3)`` RGB in [0, 1], for the vertex-coloured export."""

    def texel_coords(self) -> np.ndarray:
        """Per-corner atlas pixel coordinates ``(F, 3, 2)`` (x right, y down, texel centres at integers)."""
        H, W = self.atlas.shape[:2]
        x = self.face_uvs[..., 0] * W - 0.5
        y = (1.0 - self.face_uvs[..., 1]) * H - 0.5
        return np.stack([x, y], axis=-1)

    def sample(self, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """Atlas colours ``(N, C)`` at points given by face index ``(N,)`` and barycentrics
        ``(N, 2)`` ``(b1, b2)`` (the point ``(1 - b1 - b2) v0 + b1 v1 + b2 v2``)."""
        tc = self.texel_coords()[face]
        w = np.stack([1 - bary[:, 0] - bary[:, 1], bary[:, 0], bary[:, 1]], axis=1)
        xy = np.einsum("nk,nkc->nc", w, tc)
        return sample_bilinear(self.atlas, xy[:, 0], xy[:, 1])
