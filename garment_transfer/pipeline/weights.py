"""Skinning weights carried from a body to a garment: nearest surface point, interpolated.

The same rule as Blender's Data Transfer modifier with "Nearest Face Interpolated": each garment
vertex takes the weights at its closest point on the body, blended from that triangle's three corners
by barycentric coordinates. Weights stay in [0, 1] and vary smoothly over the garment.
"""

from __future__ import annotations

import numpy as np

from ..geometry.proximity import TriangleSurface


def surface_weights(body_V, body_F, weights, points, surface=None):
    """Per-vertex weights of a body, read at the points' closest places on its surface.

    Parameters
    ----------
    body_V : (n,3) float
    body_F : (m,3) int
        The body's triangles.
    weights : (n,k) float
        ``k`` weight layers (vertex groups) of the body's vertices.
    points : (p,3) float
        The garment's vertices, in the body's space.
    surface : TriangleSurface, optional
        The body prepared for queries, to reuse.

    Returns
    -------
    W : (p,k) float64
    """
    body_V = np.asarray(body_V, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    if weights.ndim != 2 or weights.shape[0] != body_V.shape[0]:
        raise ValueError(f"weights must be (n,k) with n = {body_V.shape[0]} body vertices, "
                         f"got {weights.shape}")
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if points.shape[0] == 0 or weights.shape[1] == 0:
        return np.zeros((points.shape[0], weights.shape[1]))
    surface = surface or TriangleSurface(body_V, body_F)
    _, _, tri, bary = surface.closest(points)
    corners = np.asarray(body_F, dtype=np.int64)[tri]
    return np.einsum("pc,pck->pk", bary, weights[corners])
