"""Alignment: a target body brought into the source body's frame (units, axes, placement) by a similarity."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..geometry.mesh import Mesh, triangle_normals
from ..geometry.proximity import TriangleSurface

#: Known unit ratios: a scale ratio within UNIT_SNAP of one of these is taken to be a change of units.
UNIT_RATIOS = tuple(sorted({f * 10.0 ** k for k in range(-4, 5)
                            for f in (1.0, 2.54, 1 / 2.54, 30.48, 1 / 30.48)}))
UNIT_SNAP = 1.25

#: Principal-axis shape of a standing person: a target whose ratio of the two larger principal
#: extents differs from the source's by more than this factor is refused before fitting.
ASPECT_FACTOR = 1.6

#: Points of each body with which the rotations tried by ``align`` are first compared (a few steps of
#: rigid ICP each); those whose distance is within SCREEN_MARGIN of the best are compared again with all
#: the samples, and the best of those is fitted. The screen alone picks among rotations that fit about
#: equally (a body symmetric about its long axis) by its sampling: measured, a symmetric column was
#: turned by 90 degrees; compared again, the one that wins with all the samples wins.
SCREEN_SAMPLES = 500
SCREEN_MARGIN = 1.5

#: Which way a body faces, from its feet: along its long axis, the end whose lowest ``FEET_SLAB`` of the
#: height spreads wider (two feet, not one head) by ``FEET_SPREAD`` times is the feet; their points lie ahead
#: of the shins' (``SHIN_SLAB``) by the toes, along the body's front-to-back axis (the principal axis of least
#: extent of a standing person). The distances of a front-to-back turn of a body differ little (the belly of a
#: heavy body fits the back of a slim one about as well as its front): measured on the procedural mannequins,
#: the closest pose turned the heavy and the apple one round, so the garment came out back to front. A pose
#: whose toes point the other way from the source's is turned half round the long axis. Feet ahead of the
#: shins by less than ``TOES_MIN`` of the height decide nothing: measured, bodies with feet 0.027-0.058 (the
#: MakeHuman bodies, the mannequins, re-meshed and posed ones), a body cut off above the ankles, the knees or
#: the shins at most 0.013.
FEET_SLAB = 0.05
SHIN_SLAB = (0.06, 0.14)
FEET_SPREAD = 1.8
TOES_MIN = 0.02


@dataclass
class Similarity:
    """``x = scale * R p + t``: points p of one frame to another.

    Attributes
    ----------
    scale : float
    R : (3,3) float64
        A rotation (det +1).
    t : (3,) float64
    """

    scale: float
    R: np.ndarray
    t: np.ndarray

    def apply(self, P):
        """(k,3) points mapped forward."""
        return self.scale * np.asarray(P, dtype=np.float64) @ self.R.T + self.t

    def inverse(self) -> "Similarity":
        Ri = self.R.T
        return Similarity(1.0 / self.scale, Ri, -(Ri @ self.t) / self.scale)

    def as_dict(self) -> dict:
        return {"scale": float(self.scale), "rotation": self.R.tolist(), "translation": self.t.tolist()}

# --- geometry helpers -------------------------------------------------------------------------

def surface_moments(V, F):
    """Area-weighted centroid and covariance of a triangle surface (exact under similarities).

    Returns
    -------
    centroid : (3,) float64
    cov : (3,3) float64
        Second moment about the centroid per unit area.
    area : float
    """
    V = np.asarray(V, dtype=np.float64)
    c = V[F]
    _, a = triangle_normals(V, F)
    A = float(a.sum())
    if A <= 0:
        raise ValueError("surface with zero area")
    m = c.mean(axis=1)
    centroid = (a[:, None] * m).sum(axis=0) / A
    d = c - centroid
    # Exact second moment of a triangle: (sum_i d_i d_i^T + (sum d)(sum d)^T) / 12 per unit area.
    s = d.sum(axis=1)
    outer = np.einsum("tki,tkj->tij", d, d) + np.einsum("ti,tj->tij", s, s)
    cov = np.einsum("t,tij->ij", a, outer) / (12.0 * A)
    return centroid, cov, A


def principal_frame(cov):
    """(3,3) eigenvectors as columns, largest variance first; (3,) the variances."""
    w, E = np.linalg.eigh(cov)
    order = np.argsort(w)[::-1]
    return E[:, order], w[order]


def _proper_axis_rotations():
    out = []
    for perm in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        for signs in np.ndindex(2, 2, 2):
            R = np.zeros((3, 3))
            R[np.arange(3), perm] = np.where(np.array(signs) == 0, 1.0, -1.0)
            if np.linalg.det(R) > 0:
                out.append(R)
    return out


AXIS_ROTATIONS = _proper_axis_rotations()


def units_scale(ratio):
    """A size ratio snapped to a unit ratio when it is near one (returns (scale, snapped))."""
    best = min(UNIT_RATIOS, key=lambda u: abs(np.log(ratio / u)))
    if abs(np.log(ratio / best)) <= np.log(UNIT_SNAP):
        return float(best), True
    return float(ratio), False


def similarity_fit(P, Q):
    """Rotation R, translation t and scale s minimising sum |s R p + t - q|^2 (Umeyama 1991)."""
    mp, mq = P.mean(0), Q.mean(0)
    Pc, Qc = P - mp, Q - mq
    H = Pc.T @ Qc
    U, S, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    s = float(np.trace(np.diag(S) @ D) / np.sum(Pc ** 2))
    return R, mq - s * R @ mp, s


def rigid_fit(P, Q, w=None):
    """Rotation R and translation t minimising sum w |R p + t - q|^2 (Kabsch)."""
    w = np.ones(P.shape[0]) if w is None else w
    W = w.sum()
    mp = (w[:, None] * P).sum(0) / W
    mq = (w[:, None] * Q).sum(0) / W
    H = ((P - mp) * w[:, None]).T @ (Q - mq)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, mq - R @ mp


def surface_samples(V, F, count, seed=0):
    """Points spread uniformly by area over a triangle surface (deterministic for a seed).

    Vertex sets are poor stand-ins for a surface when two meshes are sampled differently (a body
    dense in the face and hands against a uniform re-mesh): area-uniform points are not biased.

    Returns
    -------
    P : (count,3) float64
    tri : (count,) int64
    bary : (count,3) float64
    """
    V = np.asarray(V, dtype=np.float64)
    _, a = triangle_normals(V, F)
    rng = np.random.default_rng(seed)
    tri = rng.choice(F.shape[0], count, p=a / a.sum())
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    bary = np.stack([1.0 - s, s * (1.0 - r2), s * r2], axis=1)
    P = np.einsum("ki,kij->kj", bary, V[F[tri]])
    return P, tri.astype(np.int64), bary


def coherent_order(P):
    """(p,) int64: an order of the points P (p,3) along a Morton (Z-order) curve, near points together.

    Closest-point queries in this order visit the search tree's nodes in turn: measured on 8K
    area-uniform samples (random order) against a 50K-triangle body, 0.035 s against 0.055 s. Each
    point's answer does not depend on the order.
    """
    P = np.asarray(P, dtype=np.float64)
    if P.shape[0] == 0:
        return np.zeros(0, np.int64)
    lo = P.min(axis=0)
    span = max(float(np.ptp(P, axis=0).max()), 1e-300)
    q = np.clip((P - lo) / span * 1023.0, 0, 1023).astype(np.int64)
    code = np.zeros(P.shape[0], np.int64)
    for bit in range(10):
        for k in range(3):
            code |= ((q[:, k] >> bit) & 1) << (3 * bit + k)
    return np.argsort(code, kind="stable")


def closest_in_order(surface: TriangleSurface, P, order=None):
    """``surface.closest(P)`` (closest points, distances, triangles, barycentric coordinates), the
    queries made in ``order`` (``coherent_order(P)`` by default; pass it when P moves by a rigid map or
    a small step, so near points stay near) and the answers given back in P's order."""
    P = np.asarray(P, dtype=np.float64)
    if order is None:
        order = coherent_order(P)
    out = surface.closest(P[order])
    back = np.empty_like(order)
    back[order] = np.arange(order.size)
    return tuple(x[back] for x in out)


def closest_points(surface: TriangleSurface, P, order=None):
    """Closest points of P (p,3) on the surface as libigl's search finds them, queried in ``order`` (as
    ``closest_in_order``): the points (p,3), their distances (p,) and a triangle holding each (p,).

    For the fits that need only where the surface is and how far: ``surface.closest`` also works out
    the barycentric coordinates and, where the point is on an edge or a corner, the one triangle of
    lowest index (so that a binding does not depend on the tree), which costs half as much again.
    """
    P = np.ascontiguousarray(P, dtype=np.float64)
    if P.shape[0] == 0:
        return np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64)
    if order is None:
        order = coherent_order(P)
    sq, tri, C = surface.tree.squared_distance(surface.V, surface.F, P[order])
    back = np.empty_like(order)
    back[order] = np.arange(order.size)
    return (np.asarray(C, dtype=np.float64)[back], np.sqrt(np.maximum(sq, 0.0))[back],
            np.asarray(tri, dtype=np.int64)[back])


def _rigid_icp(P, src_tree, src_pts, R, t, iterations=20):
    """Trimmed rigid ICP of target samples P (transformed by R, t) onto source samples: a coarse pose.

    Returns R, t and the two-way RMS distance of the final pose.
    """
    for _ in range(iterations):
        X = P @ R.T + t
        d, j = src_tree.query(X)
        keep = d <= np.quantile(d, 0.9)
        dR, dt = rigid_fit(X[keep], src_pts[j[keep]])
        R, t = dR @ R, dR @ t + dt
        if np.linalg.norm(dR - np.eye(3)) < 1e-10 and np.linalg.norm(dt) < 1e-12:
            break
    X = P @ R.T + t
    d1 = src_tree.query(X)[0]
    d2 = cKDTree(X).query(src_pts)[0]
    return R, t, float(np.sqrt(0.5 * (np.mean(d1 ** 2) + np.mean(d2 ** 2))))


def _refine_rigid(source_surface, target_surface, Ps, Pt, scale, R, t, iterations=15, trim=0.9):
    """Rigid ICP against the true surfaces both ways (exact closest points, not sample to sample).

    The pose maps target points p to ``scale * R p + t``; Ps, Pt are samples of the source and of
    the target (in their own frames).
    """
    order_t, order_s = coherent_order(Pt), coherent_order(Ps)
    for _ in range(iterations):
        A = scale * Pt @ R.T + t
        C1, d1 = closest_points(source_surface, A, order_t)[:2]
        # Source samples taken back into the target's frame, their closest target points brought forward.
        B = ((Ps - t) @ R) / scale
        C2, d2 = closest_points(target_surface, B, order_s)[:2]
        C2 = scale * C2 @ R.T + t
        k1 = d1 <= np.quantile(d1, trim)
        k2 = d2 <= np.quantile(d2, trim)
        dR, dt = rigid_fit(np.vstack([A[k1], C2[k2]]), np.vstack([C1[k1], Ps[k2]]))
        R, t = dR @ R, dR @ t + dt
        if np.abs(dR - np.eye(3)).max() < 1e-9 and np.abs(dt).max() < 1e-9 * scale:
            break
    return R, t


def toe_shift(P, axis, depth):
    """How far a body's feet lie ahead of its shins along ``depth``, as a share of its height; None when it has
    no clear feet.

    Parameters
    ----------
    P : (k,3) float
        Points spread evenly over the body's surface (``surface_samples``).
    axis : (3,) float
        The body's long axis (unit; either sign).
    depth : (3,) float
        Its front-to-back axis (unit; the sign says which way counts as ahead).

    Returns
    -------
    float or None
        Signed; None when neither end of the axis spreads ``FEET_SPREAD`` times wider than the other, or the
        shift is under ``TOES_MIN``.
    """
    P = np.asarray(P, dtype=np.float64)
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    h = P @ axis
    height = float(h.max() - h.min())
    if not height > 0:
        return None
    ends = []
    for sign in (1.0, -1.0):
        up = sign * h
        low = up.min()
        feet = P[up <= low + FEET_SLAB * height]
        across = (feet - feet.mean(axis=0)) - np.outer((feet - feet.mean(axis=0)) @ axis, axis)
        ends.append((float(np.linalg.norm(across, axis=1).mean()), up, low))
    wide, narrow = sorted(ends, key=lambda e: -e[0])
    if not wide[0] >= FEET_SPREAD * narrow[0]:
        return None
    _, up, low = wide
    feet = P[up <= low + FEET_SLAB * height]
    shins = P[(up >= low + SHIN_SLAB[0] * height) & (up <= low + SHIN_SLAB[1] * height)]
    if shins.shape[0] == 0:
        return None
    shift = float((feet.mean(axis=0) - shins.mean(axis=0)) @ np.asarray(depth, dtype=np.float64)) / height
    return shift if abs(shift) >= TOES_MIN else None


def align(source: Mesh, target: Mesh, samples=2000, refine=True):
    """The similarity that brings the target body into the source body's frame.

    Parameters
    ----------
    source, target : Mesh
    samples : int
        Points of each body used by the rigid ICP.
    refine : bool
        Refine the pose against the exact closest points of both surfaces (``_refine_rigid``). Without
        it, the pose is the rigid ICP's between the two sets of samples (about the spacing of the
        samples): ``register`` does without it, since its global fit is the same refinement with the
        scale (measured on MakeHuman re-meshes: its result moved 0.2-0.7 mm, as much as ten more
        steps of the global fit move it).

    Returns
    -------
    alignment : Similarity
        Target frame to source frame.
    info : dict
        ``size_ratio``, ``units_scale``, ``snapped`` (whether the scale is a known unit ratio),
        ``rms`` (two-way RMS distance of the coarse pose, in source units), the principal
        ``aspect`` of both bodies, ``toes_source``, ``toes_target`` (how far each body's feet lie ahead
        of its shins along the source's front-to-back axis, as shares of the height, ``toe_shift``: the same
        sign when they face the same way; left out when either has no clear feet) and ``turned_round`` (the
        closest pose faced the other way and was turned round by the toes).
    """
    cs, Cs, _ = surface_moments(source.V, source.F)
    ct, Ct, _ = surface_moments(target.V, target.F)
    Es, ws = principal_frame(Cs)
    Et, wt = principal_frame(Ct)
    ratio = float(np.sqrt(np.trace(Cs) / np.trace(Ct)))
    scale, snapped = units_scale(ratio)
    info = {"size_ratio": ratio, "units_scale": scale, "snapped": snapped,
            "aspect_source": float(np.sqrt(ws[0] / ws[1])), "aspect_target": float(np.sqrt(wt[0] / wt[1]))}

    Ps = surface_samples(source.V, source.F, samples, seed=0)[0]
    Pt = surface_samples(target.V, target.F, samples, seed=1)[0]
    src_tree = cKDTree(Ps)
    P = (Pt - ct) * scale
    # The samples are independent, so the first few are a smaller sample of the same surfaces.
    k = min(SCREEN_SAMPLES, samples)
    screen_tree = cKDTree(Ps[:k])
    # Eigenvectors come with either handedness: both frames right-handed, or a candidate would be a
    # mirror (measured: female_average onto a Z-up male_average re-mesh was fitted as its mirror image,
    # left hand onto right hand, within 5 mm of the surface).
    Es = Es * np.sign(np.linalg.det(Es))
    Et = Et * np.sign(np.linalg.det(Et))
    candidates = [Es @ np.diag(s) @ Et.T for s in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1))]
    candidates += AXIS_ROTATIONS
    # A quick look first: most of the 28 starts are clearly wrong after a few steps. Those that are
    # not are compared again on all the samples, in the same order, so the same one wins as when all
    # are compared on all the samples.
    screened = [_rigid_icp(P[:k], screen_tree, Ps[:k], R0, cs.copy(), iterations=4)[2] for R0 in candidates]
    best = None
    for R0, rms in zip(candidates, screened):
        if rms > SCREEN_MARGIN * min(screened):
            continue
        R, t, rms = _rigid_icp(P, src_tree, Ps, R0, cs.copy(), iterations=4)
        if best is None or rms < best[2]:
            best = (R, t, rms)
    R, t, rms = _rigid_icp(P, src_tree, Ps, best[0], best[1], iterations=30)
    # A front-to-back turn fits about as closely: the toes decide (``toe_shift``), along the source's long axis
    # and its axis of least extent.
    axis, depth = Es[:, 0], Es[:, 2]
    toes = toe_shift(Ps, axis, depth)
    toes_target = None if toes is None else toe_shift(P @ R.T + t, axis, depth)
    info["turned_round"] = False
    if toes_target is not None and toes * toes_target < 0:
        half = 2.0 * np.outer(axis, axis) - np.eye(3)      # half a turn about the long axis
        R2, t2, rms2 = _rigid_icp(P, src_tree, Ps, half @ R, half @ (t - cs) + cs, iterations=30)
        turned = toe_shift(P @ R2.T + t2, axis, depth)
        if turned is not None and toes * turned > 0:
            R, t, rms, toes_target = R2, t2, rms2, turned
            info["turned_round"] = True
    info["rms"] = rms
    if toes_target is not None:
        info.update(toes_source=toes, toes_target=toes_target)
    t = t - scale * (R @ ct)
    if not refine:
        return Similarity(scale, R, t), info
    R, t = _refine_rigid(TriangleSurface(source.V, source.F), TriangleSurface(target.V, target.F),
                         Ps, Pt, scale, R, t)
    return Similarity(scale, R, t), info
