"""The directions of a body's limbs, found from its shape, and how far two shapes of one body differ in pose.

The transfer moves a garment by the body's change of shape. A change of pose (an arm lowered, a leg lifted)
is not a change of shape: deformation gradients that turn a whole limb bend the cloth at the joint, and a
registration that fits one pose onto another follows the limb only in part. ``limb_angles`` measures it,
so that a target in another pose is refused with the figure rather than dressed badly.

How, for a body with no skeleton: its four limb ends are the extremes of its surface along its two longest
principal axes (the hands at the ends of the second in an A- or T-pose, the feet at one end of the first; the
head, one landmark in the middle, is not a limb). From each end, graph distances along the mesh's edges
find the limb (a hand near a thigh is not taken for the thigh: the path goes up the arm). Two bands of each
limb, at given shares of the height from its end (the forearm and the upper arm, the shin and the thigh),
each cut in two halves by that distance, give a direction each: from the centroid of the half further from
the end to that of the half nearer it. Centroids of rings of a limb lie on its axis whatever its girth, so a
heavier or thinner limb keeps its direction; a turned one does not. The same vertices are measured on the
other shape (the same mesh: a target of the source's mesh, or the source fitted onto another mesh), after
turning it as a whole so that its trunk (the vertices beyond every band) lies best on the source's, where that
turn is more than ``TURN_NOISE``: a body standing turned in the world (a character facing another way in the
scene) is in the same pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from ..geometry.mesh import triangle_normals
from .alignment import rigid_fit

#: The bands of each limb, as shares of the body's height from the limb's end: (name, near, far). An arm in
#: an A-pose is about 0.37 of the height from fingertip to shoulder, a leg about 0.48 from sole to hip.
ARM_BANDS = (("forearm", 0.11, 0.21), ("upper arm", 0.23, 0.33))
LEG_BANDS = (("shin", 0.10, 0.22), ("thigh", 0.29, 0.40))
#: Each end is the mean of the surface within this share of the height from the extreme.
END_BAND = 0.02
#: Degrees: a turn of the trunk up to this is taken for the shape's own, not the body's turn in the world (the
#: trunks of MakeHuman's women and men lie best on each other turned by 1.6-2.3 degrees, measured).
TURN_NOISE = 5.0


@dataclass
class Limbs:
    """The limb bands of one body mesh, found on one of its shapes (``find_limbs``).

    Attributes
    ----------
    names : list of str
        ``"left forearm"`` and so on, one per band (left and right on the source's second axis: +, -).
    near, far : list of (k,) int64
        Each band's vertices in its half nearer the limb's end, and in its half further from it.
    trunk : (t,) int64 or None
        The vertices further along the surface from every limb's end than its furthest band (the torso and the
        head), by which two shapes are turned onto each other before their limbs are compared; None: all.
    """

    names: list
    near: list
    far: list
    trunk: np.ndarray | None = None

    def directions(self, V):
        """(b,3) unit direction of each band in a shape V (n,3) of the mesh: far half's centroid to near
        half's."""
        d = np.array([V[n].mean(axis=0) - V[f].mean(axis=0) for n, f in zip(self.near, self.far)])
        return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)


def _principal_axes(V, F):
    """The surface's area-weighted centroid and principal axes (columns, longest first)."""
    _, area = triangle_normals(V, F)
    c = V[F].mean(axis=1)
    centre = (area[:, None] * c).sum(axis=0) / area.sum()
    d = c - centre
    C = (area[:, None, None] * d[:, :, None] * d[:, None, :]).sum(axis=0)
    w, E = np.linalg.eigh(C)
    return centre, E[:, np.argsort(w)[::-1]]


def _end(V, score, mask, tol):
    """The vertex nearest the mean of the masked vertices within ``tol`` of the masked maximum of ``score``."""
    s = np.where(mask, score, -np.inf)
    p = V[s >= s.max() - tol].mean(axis=0)
    return int(np.argmin(np.where(mask, np.linalg.norm(V - p, axis=1), np.inf)))


def find_limbs(V, F) -> Limbs | None:
    """The limb bands of a body in an A- or T-pose, from its shape.

    Parameters
    ----------
    V : (n,3) float
    F : (m,3) int

    Returns
    -------
    Limbs, or None when no four limb ends are found (a body cut off, or not a standing person).
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    centre, E = _principal_axes(V, F)
    a, b = (V - centre) @ E[:, 0], (V - centre) @ E[:, 1]
    height = float(np.ptp(a))
    tol = END_BAND * height
    left, right = b > 0, b < 0
    # The feet: the end of the long axis that has one extreme per side, not one in the middle (the head).
    feet = None
    for s in (a, -a):
        pl, pr = _end(V, s, left, tol), _end(V, s, right, tol)
        if abs(b[pl] - b[pr]) >= 0.1 * height:
            feet = (pl, pr)
            break
    if feet is None:
        return None
    ends = [("left arm", _end(V, b, np.ones_like(left), tol), ARM_BANDS),
            ("right arm", _end(V, -b, np.ones_like(left), tol), ARM_BANDS),
            ("left leg", feet[0], LEG_BANDS), ("right leg", feet[1], LEG_BANDS)]
    i, j = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]).T
    w = np.linalg.norm(V[i] - V[j], axis=1)
    graph = sp.coo_matrix((w, (i, j)), shape=(V.shape[0],) * 2).tocsr()
    reach = max(band[2] for _, _, bands in ends for band in bands) * height
    dist = dijkstra(graph, directed=False, indices=[e for _, e, _ in ends], limit=reach * 1.01)
    names, near, far = [], [], []
    for (limb, _, bands), d in zip(ends, dist):
        for band, lo, hi in bands:
            mid = 0.5 * (lo + hi) * height
            n = np.flatnonzero((d >= lo * height) & (d < mid))
            f = np.flatnonzero((d >= mid) & (d < hi * height))
            if n.size < 3 or f.size < 3:
                return None
            names.append(f"{limb.split()[0]} {band}")
            near.append(n)
            far.append(f)
    trunk = np.flatnonzero(np.all(dist >= reach, axis=0))
    return Limbs(names, near, far, trunk if trunk.size >= 3 else None)


def trunk_rotation(source_V, other_V, index=None):
    """(3,3) the rotation that best turns the vertices ``index`` of ``source_V`` onto those of ``other_V`` about
    their centroids (least squares, no reflection: ``alignment.rigid_fit``): ``other ~ source @ R.T`` up to a
    shift."""
    P, Q = np.asarray(source_V, float), np.asarray(other_V, float)
    if index is not None:
        P, Q = P[index], Q[index]
    return rigid_fit(P, Q)[0]


def _angles(names, d0, d1):
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", d0, d1), -1.0, 1.0)))
    k = int(np.argmax(angle))
    return {"degrees": float(angle[k]), "band": names[k], "bands": {n: float(x) for n, x in zip(names, angle)}}


def limb_angles(source_V, F, other_V, limbs: Limbs | None = None):
    """How far the limbs of two shapes of one body mesh point apart.

    Parameters
    ----------
    source_V : (n,3) float
        The shape the limbs are found on (the source body).
    F : (m,3) int
    other_V : (n,3) float
        Another shape of the same mesh (a target of the source's mesh, or the source fitted onto a target),
        in any frame: where its trunk lies best on the source's turned by more than ``TURN_NOISE``, it is turned
        back first (``trunk_rotation``).
    limbs : Limbs, optional
        ``find_limbs(source_V, F)``, when known.

    Returns
    -------
    dict
        ``degrees``: the largest angle between a band's directions in the two shapes (None without limbs),
        ``band``: its name, ``bands``: {name: degrees} of every band.
    """
    limbs = find_limbs(source_V, F) if limbs is None else limbs
    if limbs is None:
        return {"degrees": None, "band": None, "bands": {}}
    R = trunk_rotation(source_V, other_V, limbs.trunk)
    turn = np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))
    return _angles(limbs.names, limbs.directions(np.asarray(source_V, float)),
                   limbs.directions(np.asarray(other_V, float)) @ (R if turn > TURN_NOISE else np.eye(3)))
