"""A body field carried from one body mesh to another: a model serving garments dressed on other bodies.

The shared model predicts a deformation gradient for every triangle of the body it was trained on
(for the procedural mannequins: metres, Z up, 27K triangles). A garment dressed on another body
mesh (a MakeHuman body: decimetres, Y up, 26K other triangles) needs the field on its own body's
triangles. The model's body is registered onto that body (``registration.register``: units, axes and
placement, then a non-rigid fit; cached per pair), and every triangle of the new body takes the field
of the fitted model-body triangle under its centroid, turned from the model's frame into the new
body's: with ``x_model = s R x_new + t``, a gradient ``Q`` of the model's frame is ``R^T Q R`` in the
new one (the scale cancels).
"""

from __future__ import annotations

import numpy as np

from ..errors import ModelError
from ..fitting.registration import register
from ..geometry.mesh import Mesh
from ..geometry.proximity import TriangleSurface


def map_field(Q, registration, from_body: Mesh, to_body: Mesh):
    """A per-triangle field of ``from_body`` carried onto the triangles of ``to_body``.

    Parameters
    ----------
    Q : (M0,3,3) float
        One 3x3 matrix per triangle of ``from_body``, in its frame.
    registration : registration.Registration
        ``register(from_body, to_body)``: ``from_body`` fitted onto ``to_body`` (``V`` in ``to_body``'s
        frame) and the alignment from ``to_body``'s frame to ``from_body``'s.
    from_body, to_body : Mesh

    Returns
    -------
    Q_to : (M,3,3) float64
        One matrix per triangle of ``to_body``, in its frame.
    source_triangle : (M,) int64
        The triangle of ``from_body`` each one came from.
    """
    Q = np.asarray(Q, dtype=np.float64)
    if Q.shape != (from_body.n_triangles, 3, 3):
        raise ValueError(f"the field must have shape ({from_body.n_triangles}, 3, 3), got {Q.shape}")
    if registration.V.shape != from_body.V.shape:
        raise ValueError(f"the registration has {registration.V.shape[0]} vertices, {from_body.name} "
                         f"has {from_body.n_vertices}")
    fitted = TriangleSurface(registration.V, from_body.F)
    centroids = to_body.V[to_body.F].mean(axis=1)
    _, _, tri, _ = fitted.closest(centroids)
    R = np.asarray(registration.alignment.R, dtype=np.float64)
    return np.einsum("ji,mjk,kl->mil", R, Q[tri], R), tri


def model_field(model, target, source_body: Mesh, *, cache=True):
    """The shared model's field for ``target`` on the triangles of ``source_body``: the model's own
    field when it was trained on that body's mesh, otherwise carried from the model's body
    (``map_field``, the registration cached like any other).

    Returns
    -------
    Q : (M,3,3) float64
    """

    if model.same_body(source_body):
        return model.body_field(target)
    body = model.source_body
    if body is None:
        model.check_source_body(source_body)       # raises, saying why
    if getattr(model, "conditions_on_garment", False):
        raise ModelError(model.name, "the garment-aware model serves garments dressed on the body it was "
                                     f"trained on only, not on {source_body.name}")
    reg = register(body, source_body, cache=cache)
    return map_field(model.body_field(target), reg, body, source_body)[0]
