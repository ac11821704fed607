"""Deformation gradients between two shapes of one triangle mesh (paper eq. 2-3; Sumner & Popovic 2004)."""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict

import numpy as np

from .mesh import DEGENERATE_AREA, cross_rows

#: The rest shapes' inverted frames, by digest of the rest shape: a source body goes to many targets
#: (and its garments to every target), and its frames are the same every time. Kept for meshes of up
#: to REST_KEPT_TRIANGLES triangles (bodies; a huge garment's frames would cost memory for little).
_RESTS: OrderedDict = OrderedDict()
_RESTS_KEPT = 4
REST_KEPT_TRIANGLES = 200_000
_RESTS_LOCK = threading.Lock()


def triangle_frames(V, F):
    """Per-triangle frames ``[e1 e2 n]`` with ``n = e1 x e2 / sqrt(|e1 x e2|)``.

    Parameters
    ----------
    V : (n,3) float
    F : (m,3) int

    Returns
    -------
    X : (m,3,3) float64
        Columns e1 = x2 - x1, e2 = x3 - x1 and the scaled normal n.
    dbl_area : (m,) float64
        |e1 x e2| (twice the triangle's area).
    """
    V = np.asarray(V, dtype=np.float64)
    x1 = V[F[:, 0]]
    e1 = V[F[:, 1]] - x1
    e2 = V[F[:, 2]] - x1
    c = cross_rows(e1, e2)
    dbl = np.linalg.norm(c, axis=1)
    n = np.divide(c, np.sqrt(dbl)[:, None], out=np.zeros_like(c), where=dbl[:, None] > 0)
    return np.stack([e1, e2, n], axis=2), dbl


def inverse_3x3(A):
    """Closed-form inverses of a stack of 3x3 matrices.

    Parameters
    ----------
    A : (m,3,3) float

    Returns
    -------
    Ainv : (m,3,3) float64
        Undefined (inf/nan) where det is 0: callers mask those.
    det : (m,) float64
    """
    a, b, c = A[:, 0, 0], A[:, 0, 1], A[:, 0, 2]
    d, e, f = A[:, 1, 0], A[:, 1, 1], A[:, 1, 2]
    g, h, i = A[:, 2, 0], A[:, 2, 1], A[:, 2, 2]
    co = np.empty_like(A)
    co[:, 0, 0] = e * i - f * h
    co[:, 0, 1] = c * h - b * i
    co[:, 0, 2] = b * f - c * e
    co[:, 1, 0] = f * g - d * i
    co[:, 1, 1] = a * i - c * g
    co[:, 1, 2] = c * d - a * f
    co[:, 2, 0] = d * h - e * g
    co[:, 2, 1] = b * g - a * h
    co[:, 2, 2] = a * e - b * d
    det = a * co[:, 0, 0] + b * co[:, 1, 0] + c * co[:, 2, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        return co / det[:, None, None], det


def deformation_gradients(X, Y, F):
    """Deformation gradients ``Q_t = Y_t X_t^-1`` of every triangle from shape X to shape Y.

    ``Q_t`` maps the triangle's edges exactly (``Q e1 = e1'``, ``Q e2 = e2'``) and its scaled normal
    to the deformed one. It is the identity on an unchanged mesh and equals ``A`` for a similarity
    ``x -> A x + b`` (rotation times uniform scale). For a general affine map it equals ``A`` on the
    triangle's plane; the out-of-plane column is not determined by one triangle.

    Parameters
    ----------
    X : (n,3) float
        Rest shape.
    Y : (n,3) float
        Deformed shape (same vertex order).
    F : (m,3) int
        Triangles (those of the rest shape).

    Returns
    -------
    Q : (m,3,3) float64
        Never NaN: degenerate triangles get the identity.
    degenerate : (m,) bool
        Triangles of (near) zero area in X, flagged; their Q is the identity.
    """
    F = np.ascontiguousarray(F, dtype=np.int64)
    Xinv, degenerate = _rest(X, F)
    Yf, _ = triangle_frames(Y, F)
    Q = Yf @ Xinv
    Q[degenerate] = np.eye(3)
    bad = ~np.all(np.isfinite(Q), axis=(1, 2))
    # A copy: the kept one is shared.
    degenerate = degenerate | bad
    Q[bad] = np.eye(3)
    return Q, degenerate


def _rest(X, F):
    """The inverted frames (m,3,3) of the rest shape X and its degenerate triangles (m,) bool."""
    X = np.ascontiguousarray(X, dtype=np.float64)
    key = None
    if F.shape[0] <= REST_KEPT_TRIANGLES:
        digest = hashlib.blake2b(X.tobytes(), digest_size=20)
        digest.update(F.tobytes())
        key = (X.shape, F.shape, digest.digest())
        with _RESTS_LOCK:
            if key in _RESTS:
                _RESTS.move_to_end(key)
                return _RESTS[key]
    Xf, dbl_x = triangle_frames(X, F)
    Xinv, _ = inverse_3x3(Xf)
    h2 = np.mean(np.sum((Xf[:, :, 0]) ** 2, axis=1)) if F.shape[0] else 1.0
    degenerate = ~(dbl_x > DEGENERATE_AREA * h2)
    if key is not None:
        # Shared between calls: read-only, so no caller can change what the next one gets.
        Xinv.flags.writeable = False
        degenerate.flags.writeable = False
        with _RESTS_LOCK:
            _RESTS[key] = (Xinv, degenerate)
            while len(_RESTS) > _RESTS_KEPT:
                _RESTS.popitem(last=False)
    return Xinv, degenerate


def orthonormal_frames(V, F):
    """(M,3,3) rows t1, t2, n of each triangle: t1 along its first edge, n its unit normal."""
    V = np.asarray(V, dtype=np.float64)
    e1 = V[F[:, 1]] - V[F[:, 0]]
    e2 = V[F[:, 2]] - V[F[:, 0]]
    n = cross_rows(e1, e2)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    t1 = e1 / np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-300)
    return np.stack([t1, cross_rows(n, t1), n], axis=1)
