"""Registration: the source body mesh fitted onto a target body of any mesh, units and axes.

The rest of the pipeline needs the source and target bodies as one mesh in two shapes. A customer's
body is often another mesh (a scan, another character base) in other units and axes. Registration
produces the source body in the target's shape, with the source's vertex order and faces, so that the
``direct`` and ``model`` methods run unchanged.

Stages:

1. **Alignment** (``align``): the target is brought into the source's frame by a similarity
   ``x = s R p + t``. The scale is a units factor: the ratio of the two surfaces' RMS radii, snapped
   to a known unit ratio (10^k, inches, feet) when it is near one, so that a shorter person stays
   shorter. The rotation is chosen among the principal-axis frames (4 sign choices) and the 24
   axis-aligned rotations, each refined by trimmed rigid ICP; the one with the smallest two-way
   distance wins.
2. **Global similarity** of the source onto the target: the scale and the placement along the long
   axis from the two heights (a taller or shorter person; not from closest points, which shrink a
   thinner body and move a wider one), the rotation and the rest from closest points both ways.
   Then **landmarks** from the shapes (the ends of the limbs and the head) where they are far from
   their match: a limb held at another angle.
   With a **shape basis** (``shape_basis``: deltas of the source body, such as its shape keys), the
   source is first fitted as a blend of them with a similarity (``fit_shape``: closest points both
   ways, bounded ridge least squares of the weights) and the stages below start from the blend, when
   it explains at least half of the misfit. A body model's sliders (``body_model=True``, e.g.
   MakeHuman's targets from ``body_model.makehuman_shape_basis``) are fitted with a sparse (L1) prior
   and the size from the model instead.
3. **Non-rigid ICP** with an as-rigid-as-possible regulariser (Sorkine & Alexa 2007) on the source
   graph, its weight annealed from stiff to soft. Data terms both ways: every source vertex towards
   its closest target point, and target points towards their closest point on the current fit (this
   keeps limbs from collapsing onto the torso); pairs whose normals disagree or that lie far apart
   are dropped. In the soft stages a weak pull holds each vertex at its height along the body's long
   axis, sliding along the surface (a body grows and thins across that axis). Each step solves one
   sparse system (vertex count squared, three right-hand sides).
   Then the **hands and feet** (found from the shape as the ends of the body) are fitted each as a
   whole, by a similarity (point-to-plane ICP both ways), and blended into the fit: between body
   shapes they change by a similarity, which the ARAP fit (keeping their size) lets slide.
4. **Quality**: surface distance both ways (mean, 95th percentile, max) and the share of triangles
   that flipped or stretched beyond reason. A fit beyond the limits is refused with an error that
   names the figure (another pose, a partial or non-human mesh).

Results are cached per (source, target) pair in ``cache_folder()``: ``$GARMENT_TRANSFER_CACHE``, or
``$XDG_CACHE_HOME/garment_transfer/registration`` (``~/.cache/...``); ``GARMENT_TRANSFER_CACHE=off``
or ``cache=False`` turns it off. Cache files are ``.npz`` read with ``allow_pickle=False``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial import cKDTree

from .errors import Cancelled, MeshError, RegistrationError, TopologyMismatchError
from .mesh import Mesh, edge_lengths_mean, triangle_normals
from .proximity import TriangleSurface

log = logging.getLogger(__name__)

#: Bumped whenever the algorithm or its defaults change, so old cache entries are not reused.
ALGORITHM_VERSION = 9

#: Known unit ratios: a scale ratio within UNIT_SNAP of one of these is taken to be a change of units.
UNIT_RATIOS = tuple(sorted({f * 10.0 ** k for k in range(-4, 5)
                            for f in (1.0, 2.54, 1 / 2.54, 30.48, 1 / 30.48)}))
UNIT_SNAP = 1.25

#: Limits of an acceptable fit, as shares of the target's height (a 1.7 m body: 1% = 17 mm).
#: Measured fits of MakeHuman bodies onto each other and onto the procedural mannequins stay below
#: a third of these (docs/registration.md).
LIMITS = {
    "p95": 0.012,          # 95th percentile of the distance, either way
    "max": 0.06,           # largest distance, either way
    "distorted": 0.02,     # share of source triangles flipped or stretched more than 4x
}

#: Points of each surface at which the fit's distances are measured.
QUALITY_SAMPLES = 20000

#: Principal-axis shape of a standing person: a target whose ratio of the two larger principal
#: extents differs from the source's by more than this factor is refused before fitting.
ASPECT_FACTOR = 1.6


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


@dataclass
class Registration:
    """The source body fitted onto a target body.

    Attributes
    ----------
    V : (n,3) float64
        The fitted body: the source's vertex order and faces, the target's shape, in the target's
        frame and units.
    V_source_frame : (n,3) float64
        The same in the source's frame and units.
    alignment : Similarity
        Target frame to source frame.
    quality : dict
        Surface distances both ways (``to_target_*``, ``from_target_*``: mean, p95, max, in the
        target's units, and ``*_share`` of its height) and ``distorted`` (share of triangles).
    seconds : dict
        Per stage.
    cached : bool
        Read from the cache.
    shape_weights : (k,) float64 or None
        The weights of the shape basis fitted before the non-rigid stages (None without a basis).
    """

    V: np.ndarray
    V_source_frame: np.ndarray
    alignment: Similarity
    quality: dict
    seconds: dict = field(default_factory=dict)
    cached: bool = False
    shape_weights: np.ndarray | None = None

    def body(self, source: Mesh, name=None) -> Mesh:
        """The fitted body as a Mesh in the target's frame (the source's faces)."""
        return source.with_vertices(self.V, name=name or f"{source.name}_registered")

    def summary(self) -> dict:
        """Plain numbers for JSON output."""
        out = {"quality": {k: float(v) for k, v in self.quality.items()},
               "alignment": self.alignment.as_dict(),
               "seconds": {k: float(v) for k, v in self.seconds.items()},
               "cached": bool(self.cached)}
        if self.shape_weights is not None:
            out["shape_weights"] = [float(v) for v in self.shape_weights]
        return out


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


def _similarity_fit(P, Q):
    """Rotation R, translation t and scale s minimising sum |s R p + t - q|^2 (Umeyama 1991)."""
    mp, mq = P.mean(0), Q.mean(0)
    Pc, Qc = P - mp, Q - mq
    H = Pc.T @ Qc
    U, S, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    s = float(np.trace(np.diag(S) @ D) / np.sum(Pc ** 2))
    return R, mq - s * R @ mp, s


def _rigid_fit(P, Q, w=None):
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


def _rigid_icp(P, src_tree, src_pts, R, t, iterations=20):
    """Trimmed rigid ICP of target samples P (transformed by R, t) onto source samples: a coarse pose.

    Returns R, t and the two-way RMS distance of the final pose.
    """
    for _ in range(iterations):
        X = P @ R.T + t
        d, j = src_tree.query(X)
        keep = d <= np.quantile(d, 0.9)
        dR, dt = _rigid_fit(X[keep], src_pts[j[keep]])
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
        C1, d1 = closest_in_order(source_surface, A, order_t)[:2]
        # Source samples taken back into the target's frame, their closest target points brought forward.
        B = ((Ps - t) @ R) / scale
        C2, d2 = closest_in_order(target_surface, B, order_s)[:2]
        C2 = scale * C2 @ R.T + t
        k1 = d1 <= np.quantile(d1, trim)
        k2 = d2 <= np.quantile(d2, trim)
        dR, dt = _rigid_fit(np.vstack([A[k1], C2[k2]]), np.vstack([C1[k1], Ps[k2]]))
        R, t = dR @ R, dR @ t + dt
        if np.abs(dR - np.eye(3)).max() < 1e-9 and np.abs(dt).max() < 1e-9 * scale:
            break
    return R, t


def align(source: Mesh, target: Mesh, samples=2000):
    """The similarity that brings the target body into the source body's frame.

    Parameters
    ----------
    source, target : Mesh
    samples : int
        Points of each body used by the rigid ICP.

    Returns
    -------
    alignment : Similarity
        Target frame to source frame.
    info : dict
        ``size_ratio``, ``units_scale``, ``snapped`` (whether the scale is a known unit ratio),
        ``rms`` (two-way RMS distance of the coarse pose, in source units) and the principal
        ``aspect`` of both bodies.
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
    # Eigenvectors come with either handedness: both frames right-handed, or a candidate would be a
    # mirror (measured: female_average onto a Z-up male_average re-mesh was fitted as its mirror image,
    # left hand onto right hand, within 5 mm of the surface).
    Es = Es * np.sign(np.linalg.det(Es))
    Et = Et * np.sign(np.linalg.det(Et))
    candidates = [Es @ np.diag(s) @ Et.T for s in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1))]
    candidates += AXIS_ROTATIONS
    best = None
    for R0 in candidates:
        # A quick look first: most of the 28 starts are clearly wrong after a few steps.
        R, t, rms = _rigid_icp(P, src_tree, Ps, R0, cs.copy(), iterations=4)
        if best is None or rms < best[2]:
            best = (R, t, rms)
    R, t, rms = _rigid_icp(P, src_tree, Ps, best[0], best[1], iterations=30)
    info["rms"] = rms
    t = t - scale * (R @ ct)
    R, t = _refine_rigid(TriangleSurface(source.V, source.F), TriangleSurface(target.V, target.F),
                         Ps, Pt, scale, R, t)
    return Similarity(scale, R, t), info


# --- non-rigid fit ----------------------------------------------------------------------------

def _edges(F):
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    return e[:, 0], e[:, 1]


def _corner_sums(F, values, n):
    """Per vertex, the sum of its triangles' values: (m,) or (m,c) per triangle into (n,) or (n,c).

    One ``bincount`` over the corners in corner-major order adds in the order of ``np.add.at`` over the
    three corners in turn (the same sums to the last bit), several times faster.
    """
    idx = F.T.ravel()
    values = np.asarray(values, dtype=np.float64)
    if values.ndim == 1:
        return np.bincount(idx, weights=np.tile(values, 3), minlength=n)
    return np.stack([np.bincount(idx, weights=np.tile(values[:, c], 3), minlength=n)
                     for c in range(values.shape[1])], axis=1)


def _vertex_normals(V, F):
    N, a = triangle_normals(V, F)
    out = _corner_sums(F, N * a[:, None], V.shape[0])
    n = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, n, out=np.zeros_like(out), where=n > 0)


def _svd_rotations(S):
    """(k,3,3) rotations R maximising trace(R S) (``R = V U^T`` for ``S = U diag(s) V^T``, its last
    column of V negated where that is a reflection)."""
    U, _, Vt = np.linalg.svd(S)
    R = np.einsum("nab,nca->nbc", Vt, U)
    flip = np.linalg.det(R) < 0
    if flip.any():
        Vt[flip, 2, :] *= -1
        R[flip] = np.einsum("nab,nca->nbc", Vt[flip], U[flip])
    return R


def _best_rotations(S, iterations=20):
    """``_svd_rotations(S)`` for (n,3,3) S, by the polar decomposition where it is a rotation.

    Where det S > 0 the rotation is the orthogonal polar factor of S^T, found by Newton's iteration
    with Higham's scaling (X <- (g X + X^-T / g) / 2) on the nine entries as arrays over all vertices
    at once (no per-matrix LAPACK call); where det S <= 0 (the polar factor is then a reflection) or the
    iteration has not settled to an orthogonal matrix (a nearly singular S), the SVD decides. Measured
    on a 13K-vertex body: several times faster than the SVD of all, the same rotations to 1e-14
    (conditions up to 4e5).
    """
    n = S.shape[0]
    # x[3a+b] = X[a,b] with X = S^T.
    x = np.ascontiguousarray(S.transpose(0, 2, 1).reshape(n, 9).T)

    def cofactors(x):
        a, b, c, d, e, f, g, h, i = x
        C = np.array([e * i - f * h, f * g - d * i, d * h - e * g,
                      c * h - b * i, a * i - c * g, b * g - a * h,
                      b * f - c * e, c * d - a * f, a * e - b * d])
        return C, a * C[0] + b * C[1] + c * C[2]

    C, det = cofactors(x)
    size = np.abs(x).max(axis=0)
    good = det > 1e-12 * size ** 3
    x, C, det = x[:, good], C[:, good], det[good]
    for _ in range(iterations if x.shape[1] else 0):
        inv_t = C / det
        g = np.sqrt(np.sqrt(np.einsum("kn,kn->n", inv_t, inv_t) / np.einsum("kn,kn->n", x, x)))
        x_new = 0.5 * (g * x + inv_t / g)
        change = np.abs(x_new - x).max()
        x = x_new
        if change < 1e-14:
            break
        C, det = cofactors(x)
    X = x.T.reshape(-1, 3, 3)
    R = np.empty_like(S)
    R[good] = X
    # Not settled to a rotation: the SVD.
    off = np.abs(np.einsum("nki,nkj->nij", X, X) - np.eye(3)).max(axis=(1, 2)) > 1e-12
    rest = ~good
    rest[np.flatnonzero(good)[off]] = True
    if rest.any():
        R[rest] = _svd_rotations(S[rest])
    return R


class ArapFit:
    """Non-rigid ICP of one source mesh with an as-rigid-as-possible regulariser.

    Parameters
    ----------
    X0 : (n,3) float
        Rest shape of the source (after the global fit).
    F : (m,3) int
        Source triangles.
    """

    def __init__(self, X0, F):
        self.X0 = np.asarray(X0, dtype=np.float64)
        self.F = np.asarray(F, dtype=np.int64)
        n = self.X0.shape[0]
        self.n = n
        self.i, self.j = _edges(self.F)
        # Uniform weights: the regulariser (squared edge misfits) and the data terms (squared
        # distances) are both lengths squared, so their balance does not depend on the units.
        e0 = self.X0[self.i] - self.X0[self.j]
        self.w = np.ones(self.i.shape[0])
        self.L = self._laplacian(self.w)
        self.e0 = e0
        k = self.i.shape[0]
        # Edge-to-vertex sums as sparse products: np.add.at is 10x slower on these sizes.
        rows = np.concatenate([self.i, self.j])
        cols = np.concatenate([np.arange(k), np.arange(k)])
        self.both = sp.csr_matrix((np.ones(2 * k), (rows, cols)), shape=(n, k))
        self.signed = sp.csr_matrix((np.concatenate([np.ones(k), -np.ones(k)]), (rows, cols)), shape=(n, k))
        self._order = self._rank = None

    def rotations(self, X):
        """Per-vertex best rotations (n,3,3) of the rest edges onto the current edges."""
        e = X[self.i] - X[self.j]
        outer = (self.w[:, None, None] * np.einsum("ka,kb->kab", self.e0, e)).reshape(-1, 9)
        S = np.asarray(self.both @ outer).reshape(self.n, 3, 3)
        return _best_rotations(S)

    def arap_rhs(self, R, w=None):
        Rm = 0.5 * (R[self.i] + R[self.j])
        r = (self.w if w is None else w)[:, None] * np.einsum("kab,kb->ka", Rm, self.e0)
        return np.asarray(self.signed @ r)

    def _laplacian(self, w):
        """The graph Laplacian (n,n) of the edges with weights w (k,): the pattern of ``self.L``."""
        W = sp.coo_matrix((np.concatenate([w, w]), (np.concatenate([self.i, self.j]),
                                                   np.concatenate([self.j, self.i]))), shape=(self.n, self.n)).tocsr()
        return (sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W).tocsr()

    def solve(self, X, alpha, ws, C, Bt, wt, Pt):
        """One global step.

        Parameters
        ----------
        X : (n,3) current fit (for the rotations)
        alpha : float or (k,) float, regulariser weight (dimensionless), one for all edges or one per edge
            (``self.i``, ``self.j``)
        ws : (n,) weights of source-to-target pairs, C : (n,3) their target points
        Bt : (k,n) sparse barycentric rows of target-to-source pairs, wt : (k,), Pt : (k,3)
        """
        R = self.rotations(X)
        if np.ndim(alpha) == 0:
            a = float(alpha)
            L, arap = 2.0 * a * self.L, 2.0 * a * self.arap_rhs(R)
        else:
            we = self.w * np.asarray(alpha, dtype=np.float64)
            a = float(we.max())
            L, arap = 2.0 * self._laplacian(we), 2.0 * self.arap_rhs(R, we)
        A = L + sp.diags(ws) + Bt.T @ sp.diags(wt) @ Bt
        rhs = arap + ws[:, None] * C + Bt.T @ (wt[:, None] * Pt)
        # A tiny pull to the current fit keeps the matrix definite where no data term reaches.
        eps = 1e-8 * (a * 8.0 + 1.0)
        A = (A + eps * sp.identity(self.n)).tocsc()
        rhs = rhs + eps * X
        return self._factor(A).solve(rhs[self._order])[self._rank]

    def _factor(self, A):
        """LU of the symmetric positive definite A, its rows and columns in the fill-reducing order.

        Every step's matrix has the pattern of the mesh's edges: the order (COLAMD, measured 6x faster
        than MMD_AT_PLUS_A here) is found once, and each step factors A in it with the diagonal as
        pivots (safe for a definite matrix): measured on a 13K-vertex body, 0.026 s against 0.060 s for
        splu choosing its order and pivots, the solutions the same to 2e-15 relative.
        """
        if self._order is None:
            lu = spla.splu(A, permc_spec="COLAMD", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
            self._order = np.argsort(lu.perm_c)
            self._rank = np.argsort(self._order)
        return spla.splu(A[self._order][:, self._order].tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                         options={"SymmetricMode": True})


def _pairs_to_target(X, N, surface: TriangleSurface, tn_cos, max_dist, order=None):
    """Closest target points of the fit's vertices, with weights 0 for rejected pairs (queried in
    ``order``, see ``closest_in_order``), their distances and the target's normals there."""
    C, d, tri, bary = closest_in_order(surface, X, order)
    Nt = surface.normals_at(tri, bary)
    ok = (np.einsum("ij,ij->i", N, Nt) >= tn_cos) & (d <= max_dist)
    return C, ok.astype(np.float64), d, Nt


def _pairs_from_target(X, F, P, Np, tn_cos, max_dist, order=None):
    """Closest points on the fit for target points P: sparse barycentric rows and weights (queried in
    ``order``, see ``closest_in_order``)."""
    _, d, tri, bary = closest_in_order(TriangleSurface(X, F), P, order)
    m = P.shape[0]
    Nf, _ = triangle_normals(X, F[tri])
    ok = (np.einsum("ij,ij->i", Np, Nf) >= tn_cos) & (d <= max_dist)
    B = sp.csr_matrix((bary.ravel(), (np.repeat(np.arange(m), 3), F[tri].ravel())), shape=(m, X.shape[0]))
    return B, ok.astype(np.float64), d


def _global_fit(X, F, surface, P, iterations=10, samples=2000, trim=0.9):
    """A global similarity of the source X onto the target surface: the scale and the placement along
    the long axis from the heights, the rotation and the rest of the translation from closest points
    both ways (trimmed).

    Target points P are taken back through the current map and paired with their closest source
    points: for a map near a similarity this is the closest point, and the source surface is
    built once.

    Returns
    -------
    Y : (n,3) float64
        X mapped.
    """
    scale, R, t = _global_similarity(X, F, surface, P, iterations, samples, trim)
    return scale * X @ R.T + t


def _global_similarity(X, F, surface, P, iterations=10, samples=2000, trim=0.9):
    """The similarity of ``_global_fit``: (scale, R (3,3), t (3,)) with ``Y = scale * X R^T + t``."""
    Qs = surface_samples(X, F, samples, seed=2)[0]
    source_surface = TriangleSurface(X, F)
    Pt = P if P.shape[0] <= samples else P[:samples]
    # A similarity, not a general affine map: measured on MakeHuman bodies, a free affine fit
    # shears a same-family body away from its true correspondence (5 mm against 3 mm unfitted),
    # while the size ratio alone brings a taller body most of the way. The scale is the ratio of the
    # heights (extents along the source's long axis; a surface's extreme is one of its vertices), not
    # fitted to closest points: those shrink a thinner body of the same height (measured on
    # female_slim_banana: 0.8% at 50K triangles, 1.8% at 5K, its legs 6 mm too high), and the
    # non-rigid fit, which keeps lengths, then slides the limbs instead of thinning them.
    cs, Cs, _ = surface_moments(X, F)
    ct, _, _ = surface_moments(surface.V, surface.F)
    axis = principal_frame(Cs)[0][:, 0]
    X_used = X[np.unique(F)]
    ends_t = surface.V[np.unique(surface.F)] @ axis
    scale = float(np.ptp(ends_t) / np.ptp(X_used @ axis))
    mid_t = 0.5 * (ends_t.min() + ends_t.max())
    R, t = np.eye(3), ct - scale * cs
    order_s, order_t = coherent_order(Qs), coherent_order(Pt)
    for _ in range(iterations):
        Y = scale * Qs @ R.T + t
        C, d = closest_in_order(surface, Y, order_s)[:2]
        back = ((Pt - t) @ R) / scale
        Cb, db = closest_in_order(source_surface, back, order_t)[:2]
        k1 = d <= np.quantile(d, trim)
        k2 = db <= np.quantile(db, trim)
        src_pts = np.vstack([Qs[k1], Cb[k2]])
        dst = np.vstack([C[k1], Pt[k2]])
        R_new, t_new = _rigid_fit(scale * src_pts, dst)
        # Along the long axis the two extents coincide (soles and crowns), whatever closest points
        # say: a wider hip or belly would otherwise move the whole body (measured on female_pear
        # 50K: legs 2.2 mm too low, 1.4 mm with this).
        ends = (scale * X_used @ R_new.T + t_new) @ axis
        t_new = t_new + (mid_t - 0.5 * (ends.min() + ends.max())) * axis
        done = np.abs(R_new - R).max() < 1e-7 and np.abs(t_new - t).max() < 1e-7 * scale
        R, t = R_new, t_new
        if done:
            break
    return scale, R, t


def vertex_areas(V, F):
    """(n,) a third of the area of the triangles around each vertex."""
    _, a = triangle_normals(V, F)
    return _corner_sums(F, a / 3.0, V.shape[0])


#: Regulariser weights, stiff to soft, and the steps taken at each.
SCHEDULE = ((2000.0, 3), (600.0, 3), (200.0, 3), (60.0, 3), (20.0, 3), (5.0, 3), (1.0, 3))


#: On a target whose mean edge is longer than COARSE_TARGET times the source's, the source's edges
#: where the target's facets are more than COARSE_FINE times longer than its own (the hands, feet and
#: face of a body against a 5K-triangle re-mesh; the torso and limbs are 1-1.8x there) stop softening
#: at weight COARSE_STOP: the soft stages would copy the target's facets into them, while elsewhere
#: they bring the fit closer. Measured on MakeHuman (female_average onto 5K-triangle re-meshes):
#: stopping every edge at 20 left the torso and hips 5.7 and 8.4 mm from the truth on female_pear;
#: softening every edge took them to 4.4 and 6.8 mm but the head, hands and feet from 0.7, 0.9, 3.2
#: to 1.5, 1.8, 5.0 mm; with the fine edges held at 60 (ratio 1.6): 3.9, 6.0, 0.5, 1.2, 3.3 mm, the
#: garments transferred through the fit 3.1 mm from their transfer through the true body (4.0 mm
#: stopped at 20). Ratio 2.0: the feet 4.6 mm; 1.4: the torso 4.8 mm.
COARSE_TARGET = 1.5
COARSE_STOP = 60.0
COARSE_FINE = 1.6


def _finer_than_target(X, F, i, j, surface: TriangleSurface):
    """(k,) bool per edge (i, j) of the source: where the target's facets near it are more than
    COARSE_FINE times longer than the source's edges there.

    A vertex's own edge length is the mean of its edges; the target's there is the side of the
    equilateral triangle of the closest target facet's area.
    """
    n = X.shape[0]
    length = np.linalg.norm(X[i] - X[j], axis=1)
    ends = np.concatenate([i, j])
    own = np.bincount(ends, np.concatenate([length, length]), minlength=n) / np.maximum(
        np.bincount(ends, minlength=n), 1)
    _, _, tri, _ = surface.closest(X)
    T, G = surface.V, surface.F
    area = triangle_normals(T, G[tri])[1]
    ratio = np.sqrt(4.0 * area / np.sqrt(3.0)) / np.maximum(own, 1e-300)
    fine = ratio > COARSE_FINE
    return fine[i] | fine[j]

#: Each vertex of a landmark region counts as this many vertices, in the stages whose regulariser
#: weight is at least LANDMARK_UNTIL.
LANDMARK_WEIGHT = 30.0
LANDMARK_RADIUS = 0.04
LANDMARK_GATE = 0.02
LANDMARK_SAMPLES = 40000
LANDMARK_UNTIL = 200.0

#: In the stages whose regulariser weight is at most AXIAL_FROM, each vertex is pulled (this many times
#: its data weight) back to the global fit's height by sliding along the surface. Measured on
#: MakeHuman, a body grows or thins across its long axis (the front of a thinner thigh recedes 2 cm,
#: its vertices drop 1-4 mm), while the closest-point fit reaches a thinner part of a tapered limb
#: by sliding along it: on female_pear 50K the legs came out 1.4 mm low and the garments 3.24 and
#: 2.19 mm from their transfer through the true body; 2.48 and 1.57 mm with the pull.
AXIAL_WEIGHT = 0.5
AXIAL_FROM = 100.0


def _extremes(V, e1, e2, height, band=0.03):
    """(6,3) ends of a body along e2 (both) and e1 (both ends, per side or in the middle); NaN rows
    where an end has one landmark instead of two.

    Each end is the centroid of the points within ``band`` of the height from the extreme: a single
    extreme vertex is ill-defined on a flat sole or a blunt hand.
    """
    V = np.asarray(V, dtype=np.float64)
    a, b = V @ e1, V @ e2
    tol = band * height

    def end(score, mask):
        s = np.where(mask, score, -np.inf)
        return V[s >= s.max() - tol].mean(axis=0)

    everywhere = np.ones(V.shape[0], bool)
    pts = [end(b, everywhere), end(-b, everywhere)]
    for score in (a, -a):
        r, l_ = end(score, b > 0), end(score, b < 0)
        if abs((r - l_) @ e2) < 0.1 * height:
            # Both sides end near the midline (a head): one landmark, not two noisy ones.
            pts += [end(score, everywhere), np.full(3, np.nan)]
        else:
            pts += [r, l_]
    return np.array(pts)


def extremity_landmarks(X, F, target_V, target_F):
    """Matching ends of the limbs and the head, found from the shapes (both bodies in one frame).

    Ends along the source's two longest principal axes: the two lateral ends (the hands in an
    A-pose) and, at each end of the long axis, one per side (the feet) or one in the middle (the
    top of the head).

    Returns
    -------
    source_points : (k,3) float64
    target_points : (k,3) float64
    """
    _, C, _ = surface_moments(X, F)
    E, _ = principal_frame(C)
    height = float(np.ptp(X @ E[:, 0]))
    # Area-uniform points, not vertices: a body dense in the hands and face would pull its centroids.
    s = _extremes(surface_samples(X, F, LANDMARK_SAMPLES)[0], E[:, 0], E[:, 1], height)
    t = _extremes(surface_samples(target_V, target_F, LANDMARK_SAMPLES)[0], E[:, 0], E[:, 1], height)
    keep = np.isfinite(s[:, 0]) & np.isfinite(t[:, 0])
    return s[keep], t[keep]


def _landmark_targets(X, F, target_V, target_F, height):
    """Where the regions around the limbs' ends must go, for ends that are far from their match.

    A landmark moves the region within LANDMARK_RADIUS of the height around the source extreme by
    the extreme's offset (a hand held at another angle moves as a whole). Ends already within
    LANDMARK_GATE of their match are left to the surface terms: measured on MakeHuman bodies of one
    family, pulling ends that agree only adds error (the extreme is often another toe or finger).

    Returns
    -------
    index : (k,) int64
        Source vertices pulled.
    points : (k,3) float64
        Their targets.
    """
    ls, lt = extremity_landmarks(X, F, target_V, target_F)
    far = np.linalg.norm(lt - ls, axis=1) > LANDMARK_GATE * height
    tree = cKDTree(X)
    idx, pts = [], []
    for q, p in zip(ls[far], lt[far]):
        group = np.asarray(tree.query_ball_point(q, LANDMARK_RADIUS * height), dtype=np.int64)
        idx.append(group)
        pts.append(X[group] + (p - q))
    if not idx:
        return np.zeros(0, np.int64), np.zeros((0, 3))
    idx, pts = np.concatenate(idx), np.concatenate(pts)
    _, first = np.unique(idx, return_index=True)
    return idx[first], pts[first]


#: Compact parts fitted as wholes after the non-rigid fit: the hands and feet, each the connected
#: piece of the source within this share of the height around its end. Measured on MakeHuman bodies,
#: a hand or a foot changes between body shapes by a similarity to within 0.3 mm (hands; a male hand
#: is a female one scaled by 1.21) and 0.2 mm (feet of one family), while the ARAP fit, which keeps
#: their size, lets their many small features slide against the target by 1 to 10 mm. The head is not
#: one of them: a male head differs from a female one by 3.4 mm beyond a similarity, more than the
#: ARAP fit's 2.8 mm.
PART_RADIUS = {"hand": 0.12, "foot": 0.10}
#: Vertices beyond this share of the part's radius blend into the surrounding fit.
PART_CORE = 0.6
PART_ITERATIONS = 20
#: Target points sampled for the part fits, and the fewest near a part for it to be fitted.
PART_SAMPLES = 40000
PART_POINTS = 30
#: A part fit is used only when its scale is within this factor of the global fit's, its core moved
#: less than this share of the height from the non-rigid fit on average, and its distance to the target
#: is within this factor of the non-rigid fit's.
PART_SCALE = 1.5
PART_MOVE = 0.015
PART_RESIDUAL = 1.5


def _parts(X, F, edges):
    """Source vertex sets of the hands and feet, found from the shape (the ends of the body).

    Parameters
    ----------
    X : (n,3) float
        The source body.
    F : (m,3) int
    edges : tuple of two (e,) int arrays
        The mesh's edges.

    Returns
    -------
    list of (name, index (k,) int64, blend (k,) float64)
        ``blend`` is 1 in the part's core, falling to 0 at its border.
    """
    from scipy.sparse.csgraph import connected_components

    _, C, _ = surface_moments(X, F)
    E, _ = principal_frame(C)
    height = float(np.ptp(X @ E[:, 0]))
    ends = _extremes(surface_samples(X, F, LANDMARK_SAMPLES)[0], E[:, 0], E[:, 1], height)
    names = ["hand", "hand"]
    for k in (2, 4):
        # An end with one landmark in the middle is the head; one with two, the feet.
        names += [None, None] if np.isnan(ends[k + 1, 0]) else ["foot", "foot"]
    n = X.shape[0]
    out = []
    for name, q in zip(names, ends):
        if name is None or not np.isfinite(q).all():
            continue
        r = PART_RADIUS[name] * height
        d = np.linalg.norm(X - q, axis=1)
        inside = d < r
        # The connected piece around the end: a sphere around a hand may also hold some of a thigh.
        i, j = edges
        keep = inside[i] & inside[j]
        G = sp.coo_matrix((np.ones(int(keep.sum())), (i[keep], j[keep])), shape=(n, n))
        _, label = connected_components(G, directed=False)
        seed = int(np.argmin(np.where(inside, d, np.inf)))
        idx = np.flatnonzero(inside & (label == label[seed]))
        blend = np.clip((1.0 - d[idx] / r) / (1.0 - PART_CORE), 0.0, 1.0)
        out.append((name, idx, blend))
    return out


def _rodrigues(w):
    angle = float(np.linalg.norm(w))
    if angle < 1e-300:
        return np.eye(3)
    k = w / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def _part_similarity(Y0, Fp, core, Xcur, P, Np, iterations=PART_ITERATIONS, trim=0.9):
    """Similarity of one part's rest shape onto the target surface, from its fitted shape.

    Point-to-plane ICP of the target points near the part against its surface: a part slides into
    place along the surface in a few steps, where point-to-point pairs creep (measured on a male
    hand: 1.2 mm against 7.4 mm after 20 steps). Only the target's points pull: they are spread by
    area, where the part's vertices crowd on its fingers or toes, whose re-meshed surface is the
    least faithful (measured on a re-mesh within 0.3 mm of the truth: 1.3 mm of drift with the
    part's vertices pulling too, 0.3 mm without).

    Parameters
    ----------
    Y0 : (k,3) float
        The part's rest shape.
    Fp : (f,3) int
        Its triangles (indices into Y0).
    core : (k,) bool
        The vertices of its core (away from where it joins the body).
    Xcur : (k,3) float
        The part in the non-rigid fit: the start.
    P, Np : (p,3) float
        Target points and their normals.

    Returns
    -------
    Y : (k,3) float64 or None
        Y0 mapped; None when too few target points are near the part.
    scale : float
        The similarity's scale.
    """
    R, t, scale = _similarity_fit(Y0, Xcur)
    part_surface = TriangleSurface(Y0, Fp)
    # Target points whose closest point on the part is outside its core (near the wrist, ankle) may
    # belong to the rest of the body: pairing them would drag the part towards it.
    outer_tri = ~core[Fp].all(axis=1)
    centre = Y0.mean(axis=0)
    radius = np.linalg.norm(Y0 - centre, axis=1).max()
    for _ in range(iterations):
        c = scale * R @ centre + t
        near = np.flatnonzero(np.linalg.norm(P - c, axis=1) < scale * radius)
        back = ((P[near] - t) @ R) / scale
        Cb, db, tb = part_surface.closest(back)[:3]
        keep = ~outer_tri[tb]
        keep &= db <= np.quantile(db, trim) if keep.any() else keep
        if keep.sum() < PART_POINTS:
            return None, scale
        M = scale * Cb[keep] @ R.T + t
        Q, N = P[near[keep]], Np[near[keep]]
        o = M.mean(axis=0)
        d = M - o
        A = np.hstack([np.cross(d, N), np.einsum("ij,ij->i", N, d)[:, None], N])
        b = -np.einsum("ij,ij->i", N, M - Q)
        x = np.linalg.lstsq(A, b, rcond=None)[0]
        # The step maps y to o + (1 + x3) dR (y - o) + x[4:].
        dR, grow = _rodrigues(x[:3]), 1.0 + x[3]
        R = dR @ R
        t = o + grow * (dR @ (t - o)) + x[4:]
        scale = scale * grow
        if np.abs(x).max() < 1e-7:
            break
    return scale * Y0 @ R.T + t, scale


def _fit_parts(X_rest, X, F, edges, surface, height):
    """The fit X with its hands and feet replaced by similarity fits of their rest shapes.

    Parameters
    ----------
    X_rest : (n,3) float
        The source after the global fit (the parts' rest shapes).
    X : (n,3) float
        The non-rigid fit.
    F : (m,3) int
    edges : tuple of two (e,) int arrays
    surface : TriangleSurface
        The target.
    height : float
        The target's height.

    Returns
    -------
    (n,3) float64
    """
    X = X.copy()
    # Denser target points than the fit's: a hand is 2% of the body's area.
    P, tri, _ = surface_samples(surface.V, surface.F, PART_SAMPLES, seed=7)
    Np = surface.face_normals[tri]
    for name, idx, blend in _parts(X_rest, F, edges):
        local = np.full(X.shape[0], -1, np.int64)
        local[idx] = np.arange(idx.size)
        Fp = local[F]
        Fp = Fp[(Fp >= 0).all(axis=1)]
        if Fp.shape[0] < 4:
            continue
        Y, scale = _part_similarity(X_rest[idx], Fp, blend >= 1.0, X[idx], P, Np)
        if Y is None:
            continue
        # Kept only where it is plausibly the same part: not grown or shrunk beyond reason, not moved
        # far from where the non-rigid fit put it, and near the target surface about as closely.
        # Measured: MakeHuman hands and feet move 0.02-0.6% of the height and fit within 1.2x of the
        # non-rigid fit's distance; the procedural mannequin's mitten hands onto MakeHuman's moved 6%,
        # its feet fit 2.6x farther, and kept they flipped 2% of its triangles.
        core = blend >= 1.0
        moved = np.linalg.norm(Y[core] - X[idx][core], axis=1).mean()
        d_part = surface.closest(Y[core])[1].mean()
        d_fit = surface.closest(X[idx][core])[1].mean()
        if (not 1 / PART_SCALE < scale < PART_SCALE or moved > PART_MOVE * height
                or d_part > PART_RESIDUAL * d_fit + 1e-4 * height):
            log.info("registration: %s part fit not used (scale %.3g, moved %.3g, distance %.3g against %.3g)",
                     name, scale, moved, d_part, d_fit)
            continue
        X[idx] += blend[:, None] * (Y - X[idx])
    return X


def nonrigid_fit(X0, F, target_V, target_F, *, schedule=SCHEDULE, normal_cos=0.5, max_share=0.05,
                 target_samples=None, progress=None, seed=0, surface=None, start_similarity=None):
    """Fit the source shape X0 onto the target surface (both in the same frame).

    Parameters
    ----------
    X0 : (n,3) float
        Source body, aligned with the target.
    F : (m,3) int
        Source triangles.
    target_V : (k,3) float
    target_F : (l,3) int
    schedule : sequence of (alpha, steps)
        Regulariser weights from stiff to soft.
    normal_cos : float
        Pairs whose normals make a larger angle than arccos(normal_cos) are dropped.
    max_share : float
        Pairs farther apart than this share of the body's height are dropped.
    target_samples : int, optional
        Target points used for the target-to-source term (default: as many as source vertices).
    progress : callable, optional
        ``progress(fraction)``; returning True cancels.
    surface : TriangleSurface, optional
        The target surface (target_V, target_F) already built (its search tree is reused).
    start_similarity : tuple, optional
        ``(scale, R (3,3), t (3,))``: the global similarity of X0 onto this target when it is already
        known (``fit_shape``'s ``info["similarity"]`` when the blend is not used: the same fit of the
        same points, so it is not done twice). Used only with the default target points.

    Returns
    -------
    X : (n,3) float64
    """
    F = np.asarray(F, dtype=np.int64)
    if surface is None:
        surface = TriangleSurface(target_V, target_F)
    height = float(np.ptp(np.asarray(target_V), axis=0).max())
    max_dist = max_share * height
    ns = target_samples or min(X0.shape[0], 8000)
    P, tri, _ = surface_samples(target_V, target_F, ns, seed=seed)
    Np = surface.face_normals[tri]

    if start_similarity is not None and target_samples is None and seed == 0:
        scale, R, t = start_similarity
        X = scale * X0 @ R.T + t
    else:
        X = _global_fit(X0, F, surface, P)
    li, lp = _landmark_targets(X, F, surface.V, target_F, height)
    fit = ArapFit(X, F)
    # Each term weighs by the area it stands for: a body dense in the face and hands must not
    # let them dominate, and the two directions weigh alike.
    area = vertex_areas(X, F)
    wv = area / area.mean()
    wp = np.full(P.shape[0], wv.sum() / P.shape[0])
    # A target much coarser than the source is itself off the true surface by its facets: the soft
    # stages would copy them into the source's finely meshed parts (hands, feet, face), which stay
    # stiff there (COARSE_FINE); on the torso and limbs they bring the fit closer.
    coarse = edge_lengths_mean(target_V, target_F) > COARSE_TARGET * edge_lengths_mean(X0, F)
    fine = None
    if coarse:
        fine = _finer_than_target(X, F, fit.i, fit.j, surface)
    total = sum(s for _, s in schedule)
    done = 0
    axis = principal_frame(surface_moments(fit.X0, F)[1])[0][:, 0]
    # The fit moves a little per step: the query orders of its start and of the target points serve all.
    order_x, order_p = coherent_order(X), coherent_order(P)
    for alpha, steps in schedule:
        for _ in range(steps):
            N = _vertex_normals(X, F)
            C, ws, _, _ = _pairs_to_target(X, N, surface, normal_cos, max_dist, order_x)
            B, wt, _ = _pairs_from_target(X, F, P, Np, normal_cos, max_dist, order_p)
            w = ws * wv
            if alpha >= LANDMARK_UNTIL and li.size and LANDMARK_WEIGHT > 0:
                # Landmarks pull the limbs' ends while the fit is stiff (a limb held at another angle
                # swings into place as a whole), then the surfaces alone decide.
                C = C.copy()
                C[li] = (w[li, None] * C[li] + LANDMARK_WEIGHT * lp) / (w[li, None] + LANDMARK_WEIGHT)
                w = w.copy()
                w[li] += LANDMARK_WEIGHT
            if alpha <= AXIAL_FROM and AXIAL_WEIGHT > 0:
                # Along the surface only (the axis's tangential part), so the pull never holds the
                # fit off the target; it is lagged (the point moves with the fit) so one scalar
                # system still serves the three coordinates.
                along = axis[None, :] - (N @ axis)[:, None] * N
                q = X + ((fit.X0 - X) @ axis)[:, None] * along
                wq = AXIAL_WEIGHT * wv
                C = (w[:, None] * C + wq[:, None] * q) / (w + wq)[:, None]
                w = w + wq
            a = alpha
            if fine is not None and alpha < COARSE_STOP:
                a = np.where(fine, COARSE_STOP, alpha)
            X = fit.solve(X, a, w, C, B, wt * wp, P)
            done += 1
            if progress is not None and progress(done / total):
                raise Cancelled("registration cancelled")
    if not coarse:
        # Not on a much coarser target: its hands and feet are a few facets, off the true surface
        # by more than the part's own error (measured: 12 mm on a 5K-triangle MakeHuman re-mesh).
        X = _fit_parts(fit.X0, X, F, (fit.i, fit.j), surface, height)
    return X


# --- shape prior ------------------------------------------------------------------------------

#: Shape-space fit (``fit_shape``): ICP steps at most; the ridge (a weight of 1 costs this share of the
#: current residual energy, so a target that the space reaches exactly is fitted exactly); the default
#: bounds of every weight: 0 to 1, a shape key slider's own range in Blender (a delta is a shape the
#: body may move towards, not away from: measured leave-one-out on MakeHuman, bounds of -1 to 2 let a
#: female target borrow "less male" proportions, 77% of a negative slim body, and doubled its error).
SHAPE_ITERATIONS = 30
SHAPE_RIDGE = 0.05
SHAPE_BOUNDS = (0.0, 1.0)
#: Share of the point-to-point distance in the shape fit's data terms (the rest is point-to-plane:
#: the surfaces say how far apart they are across, not where a vertex belongs along them).
SHAPE_POINT_SHARE = 0.1
#: Points of each surface paired in a shape-fit step (a few weights need few points).
SHAPE_SAMPLES = 3000
#: The fitted blend is used only when it removes at least this share of the source's misfit energy.
#: Measured leave-one-out on MakeHuman (the target body never in the basis): where the space holds the
#: target's kind of body (a male target, another male body in the basis) the blend removed 84-86% and
#: took the vertex error from 9 to 1.3 mm; where it does not (a slim female target, only a pear and
#: two male bodies in the basis) it removed 20% by borrowing another body's proportions, and used it
#: doubled the error (1.7 to 3.9 mm).
SHAPE_MIN_EXPLAINED = 0.5
#: A body model's basis (``body_model=True``): a sparse prior instead of the ridge. Each weight costs
#: ``SHAPE_SPARSITY`` of the height times the RMS length of its delta per unit (an L1 penalty, solved
#: by coordinate descent), so a slider is moved only where it explains a misfit of about that size:
#: a body model has hundreds of near-collinear sliders, and a ridge or no prior lets the surface fit
#: spread the target over many of them (wrong regional weights, measured in docs/registration.md).
#: Then the sliders it moved are refitted with a tenth of the penalty (the L1 shrinks the weights).
SHAPE_SPARSITY = 1e-4
SHAPE_REFIT_SHARE = 0.1
SHAPE_REFIT_ITERATIONS = 8
#: Steps of the sparse fit before the refit (at most; it stops when the weights settle).
SHAPE_MODEL_ITERATIONS = 15


def check_shape_basis(basis, n_vertices, name="shape basis"):
    """A shape basis as (k, n, 3) float64 deltas, or ValueError naming what is wrong.

    Parameters
    ----------
    basis : array_like (k, n, 3)
        Shape deltas of the source body (its vertex order).
    n_vertices : int
        The source body's vertex count n.
    name : str
        Names the basis in the messages.

    Returns
    -------
    (k, n, 3) float64
    """
    try:
        B = np.asarray(basis, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: not an array of numbers ({exc})") from None
    if B.ndim == 2 and B.shape == (n_vertices, 3):
        raise ValueError(f"{name}: has shape {B.shape}, one delta; a basis is (k, {n_vertices}, 3): "
                         f"use basis[None] for one delta")
    if B.ndim != 3:
        raise ValueError(f"{name}: must be (k, {n_vertices}, 3) shape deltas of the source body, "
                         f"got an array of shape {B.shape}")
    if B.shape[0] == 0:
        raise ValueError(f"{name}: has no deltas (k = 0); pass None for no basis")
    if B.shape[1] != n_vertices:
        raise ValueError(f"{name}: its deltas have {B.shape[1]} vertices but the source body has "
                         f"{n_vertices}; a basis is made of the source body's own mesh")
    if B.shape[2] != 3:
        raise ValueError(f"{name}: its deltas have {B.shape[2]} coordinates per vertex, not 3")
    bad = ~np.isfinite(B).all(axis=(1, 2))
    if bad.any():
        raise ValueError(f"{name}: delta {int(np.flatnonzero(bad)[0])} has NaN or infinite values")
    return B


def shape_basis_from_bodies(source: Mesh, bodies) -> np.ndarray:
    """A shape basis from bodies of the source's mesh: their differences from the source.

    Parameters
    ----------
    source : Mesh
        The source body.
    bodies : sequence of Mesh
        The source's mesh (vertex order and faces) in other shapes, in the source's frame and units.

    Returns
    -------
    (k, n, 3) float64
    """
    bodies = list(bodies)
    if not bodies:
        raise ValueError("shape basis: no bodies given")
    for body in bodies:
        if not same_mesh(source, body):
            raise TopologyMismatchError(
                body.name, f"has {body.n_vertices} vertices and {body.n_faces} faces but the source body "
                           f"{source.name} has {source.n_vertices} and {source.n_faces} (or other faces): a "
                           f"shape basis body must be the source body's mesh in another shape")
    return np.stack([np.asarray(b.V, dtype=np.float64) - source.V for b in bodies])


def _shape_bounds(bounds, k, name="shape basis"):
    """(k,) lower and (k,) upper bounds of the weights from (lo, hi) or (k, 2)."""
    b = np.asarray(bounds, dtype=np.float64)
    if b.shape == (2,):
        b = np.broadcast_to(b, (k, 2))
    if b.shape != (k, 2) or not np.isfinite(b).all() or not (b[:, 0] <= 0.0).all() or not (b[:, 1] >= 0.0).all():
        raise ValueError(f"{name}: bounds must be (low, high) or one (low, high) per delta ({k}), finite, "
                         f"with low <= 0 <= high (the source itself is in the space); got "
                         f"{np.asarray(bounds).tolist()}")
    return b[:, 0].copy(), b[:, 1].copy()


def _plane_rows(J, r, Nn, rho):
    """Rows of the least squares whose squared norm is sum_i r_i^T (rho I + (1-rho) n_i n_i^T) r_i.

    ``sqrt(rho) I + (1 - sqrt(rho)) n n^T`` squares to that metric, so J (p,3,K) and r (p,3) are
    premultiplied by it and flattened: (3p, K) and (3p,).
    """
    q = np.sqrt(rho)
    nJ = np.einsum("pc,pck->pk", Nn, J)
    nr = np.einsum("pc,pc->p", Nn, r)
    A = q * J + (1.0 - q) * Nn[:, :, None] * nJ[:, None, :]
    b = q * r + (1.0 - q) * Nn * nr[:, None]
    return A.reshape(-1, J.shape[2]), b.ravel()


def _sparse_step(H, g, w, lo, hi, mu, kw, sweeps=100, tol=1e-6):
    """One Gauss-Newton step with an L1 prior: z minimising z^T H z + 2 g^T z + 2 sum_k mu_k |w_k + z_k|
    with lo <= w + z_w <= hi, z = (z_w (kw,), the rigid motion (6,)). The rigid part is eliminated
    (its Schur complement), the weights by cyclic coordinate descent: sweeps over the weights that are
    not 0 until they settle, then one over all of them, until a whole sweep moves nothing.
    """
    Hww, Hwr, Hrr = H[:kw, :kw], H[:kw, kw:], H[kw:, kw:]
    Ki = np.linalg.inv(Hrr)
    Hs = Hww - Hwr @ Ki @ Hwr.T
    q = g[:kw] - Hwr @ Ki @ g[kw:] - Hs @ w
    x = w.copy()
    grad = Hs @ x + q
    d = np.maximum(np.diag(Hs).copy(), 1e-300)

    def sweep(indices):
        moved = 0.0
        for j in indices:
            gj = grad[j] - d[j] * x[j]
            xn = 0.0 if abs(gj) <= mu[j] else (np.sign(gj) * mu[j] - gj) / d[j]
            xn = min(max(xn, lo[j]), hi[j])
            delta = xn - x[j]
            if delta != 0.0:
                grad[:] += Hs[:, j] * delta
                x[j] = xn
                moved = max(moved, abs(delta))
        return moved

    everything = range(kw)
    for _ in range(sweeps):
        if sweep(everything) < tol:
            break
        # The weights that are not 0 and inside their bounds, with their signs as they are: one linear
        # solve gives their optimum; kept when the signs and bounds hold, else coordinate sweeps.
        act = (x != 0.0) & (x > lo) & (x < hi)
        if act.any():
            sgn = np.sign(x[act])
            rest = ~act
            try:
                xa = np.linalg.solve(Hs[np.ix_(act, act)], -(q[act] + sgn * mu[act] + Hs[np.ix_(act, rest)] @ x[rest]))
            except np.linalg.LinAlgError:
                xa = None
            if xa is not None and np.all(np.sign(xa) == sgn) and np.all(xa >= lo[act]) and np.all(xa <= hi[act]):
                x[act] = xa
                grad = Hs @ x + q
                continue
        for _ in range(sweeps):
            if sweep(np.flatnonzero(x).tolist()) < tol:
                break
    zw = x - w
    return np.concatenate([zw, -Ki @ (g[kw:] + Hwr.T @ zw)])


def fit_shape(X0, F, basis, target_V, target_F, *, bounds=SHAPE_BOUNDS, ridge=SHAPE_RIDGE,
              iterations=SHAPE_ITERATIONS, samples=SHAPE_SAMPLES, min_explained=SHAPE_MIN_EXPLAINED,
              normal_cos=0.5, max_share=0.05, seed=0, surface=None, sparsity=None, rigid=False):
    """Weights of a linear shape space of the source body, fitted with a similarity to the target.

    The model is ``Y = s R (X0 + sum_k w_k D_k) + t``. ICP-style alternation: closest-point pairs
    both ways (source points to the target, target points to the current blend), pairs whose normals
    differ by more than arccos(normal_cos) or that lie farther apart than max_share of the height
    dropped; then the weights by a bounded, ridge-regularised linear least squares (point-to-plane
    with a share of point-to-point, in the source's frame); then the similarity as in the global fit
    (the scale and the placement along the long axis from the heights, the rotation and the rest from
    the pairs). The ridge is ``ridge`` times the current weighted residual energy per unit weight: a
    target far from the space keeps its weights near 0, one that the space holds exactly is fitted
    exactly.

    Parameters
    ----------
    X0 : (n,3) float
        The source body, in the target's frame up to a similarity.
    F : (m,3) int
        Source triangles.
    basis : (k,n,3) float
        Shape deltas of the source body.
    target_V : (p,3) float
    target_F : (q,3) int
    bounds : (2,) or (k,2) float
        Lower and upper bound of the weights.
    ridge : float
        See above; 0 for plain least squares.
    iterations : int
        ICP steps at most (it stops when the weights and the similarity no longer move).
    samples : int
        Points of each surface paired per step.
    min_explained : float
        The fitted weights are used only when they remove at least this share of the misfit energy
        of the source itself (after the global similarity); otherwise the weights returned are 0.
    surface : TriangleSurface, optional
        The target surface (target_V, target_F) already built (its search tree is reused).
    sparsity : float, optional
        For a body model's basis: an L1 prior instead of the ridge (``SHAPE_SPARSITY``: each weight
        costs this share of the height times its delta's RMS length per unit), then the weights it
        moved refitted with ``SHAPE_REFIT_SHARE`` of it for ``SHAPE_REFIT_ITERATIONS`` steps.
    rigid : bool
        Keep the scale at 1 (the similarity is a rigid motion): the basis must explain the target's
        size (a body model's height sliders; the alignment has already put the target in the source's
        units). With the height rule of the global fit, a height slider and the scale trade.

    Returns
    -------
    weights : (k,) float64
    X : (n,3) float64
        ``X0 + sum_k w_k D_k``, in X0's frame (not mapped by the similarity).
    info : dict
        ``iterations``, ``scale`` (the last similarity's), ``rms`` (two-way RMS distance of the last
        pairs, in the target's units), ``energy_start`` and ``energy`` (mean squared misfit per
        coordinate of the first and last pairs), ``explained`` (1 - their ratio), ``used`` (explained
        >= min_explained), ``fitted_weights`` (the weights found, used or not) and ``similarity``
        (``(scale, R, t)``: the global similarity of X0 itself, as ``nonrigid_fit`` starts with);
        ``final_similarity``: the last step's, which maps the blend onto the target.
    """
    from scipy.optimize import lsq_linear

    X0 = np.asarray(X0, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    D = check_shape_basis(basis, X0.shape[0])
    k = D.shape[0]
    lo, hi = _shape_bounds(bounds, k)
    weights = np.zeros(k)
    size = np.sqrt(np.mean(np.sum((X0 - X0.mean(axis=0)) ** 2, axis=1)))
    active = np.sqrt(np.mean(np.sum(D ** 2, axis=2), axis=1)) > 1e-12 * size
    if not active.any():
        # Only zero deltas: nothing to fit, the source itself.
        return weights, X0.copy(), {"iterations": 0, "scale": 1.0, "rms": float("nan"), "energy": float("nan"),
                                    "energy_start": float("nan"), "fitted_weights": weights.tolist(),
                                    "explained": 0.0, "used": False}
    Da = D[active]
    lo, hi = lo[active], hi[active]
    w = np.zeros(int(active.sum()))

    if surface is None:
        surface = TriangleSurface(target_V, target_F)
    height = float(np.ptp(np.asarray(target_V), axis=0).max())
    max_dist = max_share * height
    rng = np.random.default_rng(seed)
    # Area-uniform points of the source as fixed barycentric combinations of its vertices: the same
    # points follow the blend, so one step's pairs are linear in the weights.
    _, stri, sbary = surface_samples(X0, F, samples, seed=seed + 11)
    Sv = sp.csr_matrix((sbary.ravel(), (np.repeat(np.arange(samples), 3), F[stri].ravel())),
                       shape=(samples, X0.shape[0]))
    SD = np.stack([Sv @ d for d in Da], axis=2)                 # (samples,3,k)
    P, ptri, _ = surface_samples(target_V, target_F, samples, seed=int(rng.integers(1 << 30)))
    Np = surface.face_normals[ptri]
    P_global = surface_samples(target_V, target_F, min(X0.shape[0], 8000), seed=seed)[0]
    scale, R, t = _global_similarity(X0, F, surface, P_global)
    start = (scale, R.copy(), t.copy())
    if rigid:
        t = t + (scale - 1.0) * R @ X0[np.unique(F)].mean(axis=0)
        scale = 1.0
    rms = np.sqrt(np.mean(np.sum(Da ** 2, axis=2), axis=1))
    refit = None
    cs, Cs, _ = surface_moments(X0, F)
    axis = principal_frame(Cs)[0][:, 0]
    used = np.unique(F)
    ends_t = surface.V[np.unique(surface.F)] @ axis
    top, bottom = used[np.argmax(X0[used] @ axis)], used[np.argmin(X0[used] @ axis)]
    mid_t, span_t = 0.5 * (ends_t.min() + ends_t.max()), float(np.ptp(ends_t))
    rho = SHAPE_POINT_SHARE
    info = {"iterations": 0}
    order_s, order_p = coherent_order(Sv @ X0), coherent_order(P)
    kw = w.size
    total = iterations + (SHAPE_REFIT_ITERATIONS if sparsity else 0)
    Dmat = Da.reshape(kw, -1)

    def blend(w):
        nz = np.flatnonzero(w)
        return X0 + (w[nz] @ Dmat[nz]).reshape(X0.shape)

    it = 0
    while it < total:
        if sparsity and refit is None and it >= iterations:
            refit = np.abs(w) > 0
            if not refit.any():
                break
        cols = np.arange(kw) if refit is None else np.flatnonzero(refit)
        kc = cols.size
        X = blend(w)
        Y = scale * X @ R.T + t
        # Source points to the target (normals of the fit there), target points to the fit.
        C, ok1, d1, Nt = _pairs_to_target(Sv @ Y, triangle_normals(Y, F[stri])[0], surface, normal_cos, max_dist,
                                          order_s)
        B, ok2, d2 = _pairs_from_target(Y, F, P, Np, normal_cos, max_dist, order_p)
        ok1, ok2 = ok1 > 0, ok2 > 0
        B = B[ok2]
        # In the source's frame: the model points (linear in the weights) against the target points
        # moved by a small rigid motion (omega, tau) about c, which updates the similarity. Gauss-Newton
        # on point-to-plane distances: the pairs slide into place in a few steps, where point-to-point
        # pairs creep.
        T_pts = ((np.vstack([C[ok1], P[ok2]]) - t) @ R) / scale
        Nn = np.vstack([Nt[ok1], Np[ok2]]) @ R
        model = np.vstack([Sv[ok1] @ X, B @ X])
        # The scale follows the blend's height (the global fit's scale), linear in the weights through
        # the two extreme vertices: a change dw scales the blend about its centre by -dh/h.
        if not rigid:
            h = float((X[top] - X[bottom]) @ axis)
            dh = (Da[cols, top] - Da[cols, bottom]) @ axis                         # (kc,)
            cx = X[used].mean(axis=0)

        def weight_jacobian(sel):
            """(p,3,len(sel)): the model points' derivatives by the weights cols[sel]."""
            Jw = np.concatenate([SD[ok1][:, :, cols[sel]], np.stack([B @ Da[j] for j in cols[sel]], axis=2)
                                 if len(sel) else np.zeros((B.shape[0], 3, 0))])
            if not rigid:
                Jw = Jw - (model - cx)[:, :, None] * (dh[sel] / h)[None, None, :]
            return Jw

        c = T_pts.mean(axis=0)
        v = T_pts - c
        Jr = np.zeros((v.shape[0], 3, 6))
        Jr[:, 0, 1], Jr[:, 0, 2], Jr[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
        Jr[:, 1, 0], Jr[:, 2, 0], Jr[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
        Jr[:, :, 3:] = -np.eye(3)
        r0 = model - T_pts
        if sparsity:
            def metric(r):
                return rho * r + (1.0 - rho) * Nn * np.einsum("pc,pc->p", Nn, r)[:, None]

            n1, Sv1 = int(ok1.sum()), Sv[ok1]

            def weight_gradient(res):
                """J_w^T M res for every weight in cols, without forming J_w: through the vertices."""
                m = metric(res)
                G = Sv1.T @ m[:n1] + B.T @ m[n1:]
                gr = (Dmat @ G.ravel()) if refit is None else (Dmat[cols] @ G.ravel())
                if not rigid:
                    gr = gr - (dh / h) * float(np.sum((model - cx) * m))
                return gr

            energy = float(np.sum(r0 * metric(r0)))
            # The L1 prior, per unit of each delta's RMS length (a regional slider costs its reach).
            mu = sparsity * height * v.shape[0] * rms[cols]
            if refit is not None:
                mu = SHAPE_REFIT_SHARE * mu
            # Solved on a working set (the weights not 0 and those whose gradient nears their penalty),
            # grown until no weight outside it would move: the same step as on all of them.
            wc = w[cols]
            ws = np.flatnonzero((wc != 0.0) | (np.abs(weight_gradient(r0)) > 0.5 * mu))
            while True:
                J = np.concatenate([weight_jacobian(ws), Jr], axis=2)
                A, b = _plane_rows(J, r0, Nn, rho)
                H = A.T @ A
                H += 1e-12 * np.trace(H) / H.shape[0] * np.eye(H.shape[0])
                zs = _sparse_step(H, A.T @ b, wc[ws], lo[cols][ws], hi[cols][ws], mu[ws], ws.size)
                grad = np.abs(weight_gradient(r0 + np.einsum("pck,k->pc", J, zs)))
                out = np.ones(kc, bool)
                out[ws] = False
                grow = np.flatnonzero(out & (grad > mu * (1 + 1e-6)))
                if grow.size == 0:
                    break
                ws = np.union1d(ws, grow)
            dw = np.zeros(kc)
            dw[ws] = zs[:ws.size]
            omega, tau = zs[ws.size:ws.size + 3], zs[ws.size + 3:]
            w[cols] = np.clip(wc + dw, lo[cols], hi[cols])
        else:
            A, b = _plane_rows(np.concatenate([weight_jacobian(np.arange(kc)), Jr], axis=2), r0, Nn, rho)
            energy = float(b @ b)
            H = A.T @ A
            g = A.T @ b
            lam = ridge * energy
            H[:kw, :kw] += lam * np.eye(kw)
            g[:kw] += lam * w
            H += 1e-12 * np.trace(H) / H.shape[0] * np.eye(H.shape[0])
            # Bounded least squares of the quadratic: |L^T z + L^-1 g|^2 with H = L L^T.
            L = np.linalg.cholesky(H)
            low = np.concatenate([lo - w, np.full(6, -np.inf)])
            high = np.concatenate([hi - w, np.full(6, np.inf)])
            z = lsq_linear(L.T, -np.linalg.solve(L, g), bounds=(low, high), method="bvls", tol=1e-14).x
            dw, omega, tau = z[:kw], z[kw:kw + 3], z[kw + 3:]
            w = np.clip(w + dw, lo, hi)
        log.debug("shape fit step %d: weights %s, energy %.4g, omega %.3g, tau %.3g", it,
                  np.round(w, 4).tolist(), energy, np.abs(omega).max(), np.abs(tau).max() / height)
        # Target-to-source map x = R^T (y - t) / s composed with x -> Rd (x - c) + c + tau.
        Rd = _rodrigues(omega)
        R_new = R @ Rd.T
        t_new = t + scale * R @ (c - Rd.T @ (c + tau))
        X = blend(w)
        heights = X[used] @ axis
        top, bottom = used[np.argmax(heights)], used[np.argmin(heights)]
        if rigid:
            scale_new = scale
        else:
            scale_new = span_t / float(np.ptp(heights))
            # The new scale about the blend's centre; then its extents along the axis on the target's.
            cx = X[used].mean(axis=0)
            t_new = t_new + (scale - scale_new) * R_new @ cx
            ends = (scale_new * X[used] @ R_new.T + t_new) @ axis
            t_new = t_new + (mid_t - 0.5 * (ends.min() + ends.max())) * axis
        done = (np.abs(dw).max() < 1e-5 and np.abs(R_new - R).max() < 1e-6
                and np.abs(t_new - t).max() < 1e-6 * height)
        scale, R, t = scale_new, R_new, t_new
        info = {"iterations": it + 1, "scale": float(scale), "energy": energy / max(b.size, 1),
                "energy_start": info.get("energy_start", energy / max(b.size, 1)),
                "rms": float(np.sqrt(0.5 * (np.mean(d1[ok1] ** 2) + np.mean(d2[ok2] ** 2))))}
        it += 1
        if done:
            if not sparsity or refit is not None:
                break
            # The sparse fit has settled: the refit of the weights it moved starts with the next step.
            iterations, total = it, it + SHAPE_REFIT_ITERATIONS
    weights[active] = w
    info["fitted_weights"] = weights.tolist()
    info["similarity"] = start
    info["final_similarity"] = (float(scale), R, t)
    info["explained"] = float(1.0 - info["energy"] / max(info["energy_start"], 1e-300))
    info["used"] = info["explained"] >= min_explained
    log.info("shape fit: weights %s after %d steps (rms %.3g), %.0f%% of the misfit explained%s",
             np.round(weights, 4).tolist(), info["iterations"], info["rms"], 100 * info["explained"],
             "" if info["used"] else f" (under {min_explained:.0%}: not used)")
    if not info["used"]:
        return np.zeros(k), X0.copy(), info
    return weights, X0 + np.tensordot(weights, D, axes=1), info


# --- quality ----------------------------------------------------------------------------------

def fit_quality(X, F, source_X0, target_V, target_F, X_source_frame=None):
    """Surface distance both ways and distortion of a fit.

    Parameters
    ----------
    X : (n,3) float
        The fitted source body (same frame as the target).
    F : (m,3) int
        Source triangles.
    source_X0 : (n,3) float
        The source body, for the distortion figure.
    target_V, target_F : the target surface.
    X_source_frame : (n,3) float, optional
        The fit in the source's frame (default X): normals are compared there.

    Returns
    -------
    dict
        ``to_target_mean/p95/max`` (points of the fit to the target surface), ``from_target_mean/p95/max``
        (points of the target to the fit; both over area-uniform points), each also as ``*_share``
        of the target's height, and
        ``distorted`` (share of triangles flipped or with an area changed more than 4x beyond the
        overall change).
    """
    height = float(np.ptp(np.asarray(target_V), axis=0).max())
    # Area-uniform points: a surface distance, not a vertex one (a body dense in the fingers and
    # face would otherwise be judged by them).
    d1 = closest_in_order(TriangleSurface(target_V, target_F), surface_samples(X, F, QUALITY_SAMPLES, seed=3)[0])[1]
    d2 = closest_in_order(TriangleSurface(X, F), surface_samples(target_V, target_F, QUALITY_SAMPLES, seed=4)[0])[1]
    q = {}
    for name, d in (("to_target", d1), ("from_target", d2)):
        for stat, v in (("mean", d.mean()), ("p95", np.quantile(d, 0.95)), ("max", d.max())):
            q[f"{name}_{stat}"] = float(v)
            q[f"{name}_{stat}_share"] = float(v / height)
    N0, a0 = triangle_normals(source_X0, F)
    N1, a1 = triangle_normals(X if X_source_frame is None else X_source_frame, F)
    ratio = (a1 / max(a1.sum(), 1e-300)) / np.maximum(a0 / max(a0.sum(), 1e-300), 1e-300)
    flipped = np.einsum("ij,ij->i", N0, N1) < 0.0
    stretched = (ratio > 4.0) | (ratio < 0.25)
    q["distorted"] = float((flipped | stretched).mean())
    q["height"] = height
    return q


def check_quality(quality, source_name, target_name, limits=None):
    """Raise RegistrationError naming the first figure beyond its limit."""
    limits = dict(LIMITS, **(limits or {}))
    hint = (f"is {target_name} a whole person in the same pose as {source_name} "
            "(arms, legs), in one piece?")
    for way, text in (("from_target", f"from {target_name} to the fitted body"),
                      ("to_target", f"from the fitted body to {target_name}")):
        for stat, label in (("p95", "95th percentile of the distance"), ("max", "largest distance")):
            share = quality[f"{way}_{stat}_share"]
            if share > limits[stat]:
                raise RegistrationError(
                    target_name, f"registration failed: the {label} {text} is "
                                 f"{quality[f'{way}_{stat}']:.4g} ({share:.2%} of the height; the limit "
                                 f"is {limits[stat]:.2%}): {hint}")
    if quality["distorted"] > limits["distorted"]:
        raise RegistrationError(
            target_name, f"registration failed: {quality['distorted']:.1%} of the fitted body's "
                         f"triangles are flipped or stretched more than 4x (the limit is "
                         f"{limits['distorted']:.1%}): {hint}")


def check_aspect(info, source_name, target_name):
    """Refuse a target whose principal shape is unlike the source's (a sphere, a box, a head)."""
    a, b = info["aspect_source"], info["aspect_target"]
    if max(a / b, b / a) > ASPECT_FACTOR:
        raise RegistrationError(
            target_name, f"registration refused: its principal aspect ratio (longest to second axis) "
                         f"is {b:.2f} but {source_name}'s is {a:.2f} (factor over {ASPECT_FACTOR}): "
                         f"it does not look like a person in the source's pose")


# --- cache ------------------------------------------------------------------------------------

def cache_folder():
    """The registration cache folder, or None when caching is turned off.

    ``$GARMENT_TRANSFER_CACHE`` (``off``, ``0`` or ``none`` turn it off), else
    ``$XDG_CACHE_HOME/garment_transfer/registration``, else ``~/.cache/garment_transfer/registration``.
    """
    env = os.environ.get("GARMENT_TRANSFER_CACHE")
    if env is not None:
        if env.strip().lower() in ("", "off", "0", "none", "false", "no"):
            return None
        return env
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "garment_transfer", "registration")


def _mesh_digest(mesh: Mesh, h):
    h.update(np.ascontiguousarray(mesh.V, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.F, dtype=np.int64).tobytes())


def cache_key(source: Mesh, target: Mesh, settings: dict) -> str:
    """Content hash of both bodies (positions and faces) and the settings."""
    h = hashlib.sha256()
    h.update(f"registration v{ALGORITHM_VERSION}".encode())
    _mesh_digest(source, h)
    h.update(b"|")
    _mesh_digest(target, h)
    h.update(json.dumps(settings, sort_keys=True).encode())
    return h.hexdigest()[:32]


def _cache_load(folder, key, n):
    path = os.path.join(folder, f"{key}.npz")
    if not os.path.isfile(path):
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            V, Vs = z["V"], z["V_source_frame"]
            meta = json.loads(str(z["meta"]))
            weights = np.asarray(z["shape_weights"]) if "shape_weights" in z.files else None
    except (OSError, ValueError, KeyError) as exc:
        log.warning("ignoring unreadable registration cache file %s (%s)", path, exc)
        return None
    if V.shape != (n, 3):
        return None
    a = meta["alignment"]
    alignment = Similarity(a["scale"], np.asarray(a["rotation"]), np.asarray(a["translation"]))
    return Registration(V, Vs, alignment,
                        meta["quality"], meta.get("seconds", {}), cached=True, shape_weights=weights)


def _cache_save(folder, key, reg: Registration):
    try:
        os.makedirs(folder, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".npz", dir=folder)
        with os.fdopen(fd, "wb") as fh:
            meta = {"alignment": reg.alignment.as_dict(), "quality": reg.quality, "seconds": reg.seconds}
            arrays = {} if reg.shape_weights is None else {"shape_weights": np.asarray(reg.shape_weights)}
            np.savez(fh, V=reg.V, V_source_frame=reg.V_source_frame, meta=np.array(json.dumps(meta)), **arrays)
        os.replace(tmp, os.path.join(folder, f"{key}.npz"))
    except OSError as exc:
        # A read-only or full disk only costs the next run the fit again.
        log.warning("could not write the registration cache in %s (%s)", folder, exc)


# --- the whole stage --------------------------------------------------------------------------

def register(source: Mesh, target: Mesh, *, cache=True, check=True, limits=None, progress=None,
             schedule=SCHEDULE, shape_basis=None, shape_bounds=SHAPE_BOUNDS, body_model=False) -> Registration:
    """Fit the source body onto the target body (any mesh, units and axes; a similar pose).

    Parameters
    ----------
    source : Mesh
        The source body (the garment's body).
    target : Mesh
        Any body mesh of a person in a similar pose.
    cache : bool or str
        True: the default cache folder (``cache_folder()``); a path: that folder; False: no cache.
    check : bool
        Refuse a failed fit (RegistrationError). False returns it with its figures.
    limits : dict, optional
        Overrides of ``LIMITS``.
    progress : callable, optional
        ``progress(fraction)``; returning True cancels.
    schedule : sequence of (alpha, steps)
        The non-rigid stages (``SCHEDULE``).
    shape_basis : (k,n,3) float, optional
        Shape deltas of the source body (its vertex order, its frame and units): for example its
        shape keys relative to the basis shape, or other bodies of its mesh less the source
        (``shape_basis_from_bodies``). After the alignment the weights of this linear shape space
        are fitted to the target with a similarity (``fit_shape``), and the non-rigid stages start
        from the blended body: where the space holds the target's kind of body, it carries the
        correspondence that the surfaces alone do not give (along the limbs, around the torso).
    shape_bounds : (2,) or (k,2) float
        Bounds of the weights (1 = one delta's worth); ``SHAPE_BOUNDS`` by default.
    body_model : bool
        The basis is a body model's sliders (``body_model.makehuman_shape_basis``): fitted with the
        sparse prior (``SHAPE_SPARSITY``) and the size from the model (``rigid``), see ``fit_shape``.

    Returns
    -------
    Registration

    Raises
    ------
    RegistrationError
        The fit failed; the message names the figure and its limit.
    ValueError
        A shape basis or bounds of the wrong shape, or not finite (the message says which).
    """
    for role, m in (("source body", source), ("target body", target)):
        if m.n_triangles < 4:
            raise MeshError(m.name, f"the {role} has {m.n_triangles} triangles; a body is needed")
    settings = {"schedule": [list(s) for s in schedule]}
    if shape_basis is not None:
        shape_basis = check_shape_basis(shape_basis, source.n_vertices)
        lo, hi = _shape_bounds(shape_bounds, shape_basis.shape[0])
        # Only with a basis: the key of a registration without one is unchanged.
        settings["shape_basis"] = {"sha256": hashlib.sha256(np.ascontiguousarray(shape_basis).tobytes()).hexdigest(),
                                   "shape": list(shape_basis.shape), "low": lo.tolist(), "high": hi.tolist(),
                                   "ridge": SHAPE_RIDGE, "iterations": SHAPE_ITERATIONS,
                                   "min_explained": SHAPE_MIN_EXPLAINED, "samples": SHAPE_SAMPLES}
        if body_model:
            settings["shape_basis"].update({"body_model": True, "sparsity": SHAPE_SPARSITY,
                                            "iterations": SHAPE_MODEL_ITERATIONS,
                                            "refit": [SHAPE_REFIT_SHARE, SHAPE_REFIT_ITERATIONS]})
    folder = cache_folder() if cache is True else (cache or None)
    key = cache_key(source, target, settings) if folder else None
    if folder:
        hit = _cache_load(folder, key, source.n_vertices)
        if hit is not None:
            if check:
                check_quality(hit.quality, source.name, target.name, limits)
            return hit

    seconds = {}
    t = time.perf_counter()
    alignment, info = align(source, target)
    check_aspect(info, source.name, target.name)
    seconds["align"] = time.perf_counter() - t
    t = time.perf_counter()
    T = alignment.apply(target.V)
    # One target surface (its search tree, its normals) for the shape fit and the non-rigid fit.
    surface = TriangleSurface(T, target.F)
    start, weights, similarity = source.V, None, None
    if shape_basis is not None:
        weights, start, shape_info = fit_shape(source.V, source.F, shape_basis, T, target.F,
                                               bounds=shape_bounds, surface=surface,
                                               sparsity=SHAPE_SPARSITY if body_model else None,
                                               rigid=bool(body_model),
                                               iterations=SHAPE_MODEL_ITERATIONS if body_model else SHAPE_ITERATIONS)
        if not shape_info["used"]:
            # The non-rigid fit starts from the source itself: the shape fit's first step was its global fit.
            similarity = shape_info.get("similarity")
        seconds["shape"] = time.perf_counter() - t
        t = time.perf_counter()
    Xs = nonrigid_fit(start, source.F, T, target.F, schedule=schedule, progress=progress, surface=surface,
                      start_similarity=similarity)
    seconds["fit"] = time.perf_counter() - t
    t = time.perf_counter()
    V = alignment.inverse().apply(Xs)
    quality = fit_quality(V, source.F, source.V, target.V, target.F, X_source_frame=Xs)
    quality.update({k: float(v) for k, v in info.items() if k != "snapped"})
    quality["units_snapped"] = float(info["snapped"])
    if shape_basis is not None:
        quality["shape_explained"] = shape_info["explained"]
        quality["shape_used"] = float(shape_info["used"])
    seconds["quality"] = time.perf_counter() - t
    seconds["total"] = sum(seconds.values())
    reg = Registration(V, Xs, alignment, quality, seconds, shape_weights=weights)
    log.info("registered %s onto %s in %.2f s: %s", source.name, target.name, seconds["total"], quality)
    if check:
        check_quality(quality, source.name, target.name, limits)
    if folder:
        _cache_save(folder, key, reg)
    return reg


def same_mesh(a: Mesh, b: Mesh) -> bool:
    """Whether two bodies are one mesh (vertex count and polygons) in two shapes."""
    return (a.n_vertices == b.n_vertices and a.face_start.shape == b.face_start.shape
            and a.face_vertices.shape == b.face_vertices.shape
            and np.array_equal(a.face_start, b.face_start)
            and np.array_equal(a.face_vertices, b.face_vertices))


def transfer_to_any_body(source_body: Mesh, target_body: Mesh, garment: Mesh, *, cache=True,
                         limits=None, registration: Registration | None = None, progress=None,
                         shape_basis=None, shape_bounds=SHAPE_BOUNDS, body_model=False, **options):
    """``transfer_garment`` onto any target body: registered first when it is another mesh.

    The garment is transferred in the source's frame onto the fitted body (so the ``model`` method
    sees the frame and units it was trained in), kept out of the real target surface, and taken to
    the target's frame.

    Parameters
    ----------
    source_body, target_body, garment : Mesh
    cache : bool or str
        See ``register``.
    limits : dict, optional
        See ``register``.
    registration : Registration, optional
        A registration of these two bodies made earlier (skips ``register``).
    progress : callable, optional
        ``progress(fraction, stage)``; returning True cancels.
    shape_basis : (k,n,3) float, optional
        See ``register`` (used only when the target is another mesh).
    shape_bounds : (2,) or (k,2) float
        See ``register``.
    body_model : bool
        See ``register``.
    **options
        Passed to ``transfer_garment`` (method, model, target, offset, fix_penetration, ...).

    Returns
    -------
    result : TransferResult
        In the target's frame; ``info["registration"]`` holds the fit's figures when one was made.
    registration : Registration or None
        None when the two bodies are one mesh.
    """
    from . import penetration
    from .embedding import body_scale
    from .transfer import OFFSET_SHARE, transfer_garment

    if same_mesh(source_body, target_body):
        return transfer_garment(source_body, target_body, garment, progress=progress, **options), None

    def sub(lo, hi):
        if progress is None:
            return None
        return lambda f, *stage: progress(lo + (hi - lo) * f, *(stage or ("register",)))

    reg = registration or register(source_body, target_body, cache=cache, limits=limits,
                                   progress=sub(0.0, 0.6), shape_basis=shape_basis,
                                   shape_bounds=shape_bounds, body_model=body_model)
    options = dict(options)
    if options.get("offset") is not None:
        options["offset"] = options["offset"] * reg.alignment.scale
    fitted = source_body.with_vertices(reg.V_source_frame,
                                       name=f"{source_body.name} fitted to {target_body.name}")
    result = transfer_garment(source_body, fitted, garment, progress=sub(0.6, 0.95), **options)
    t = time.perf_counter()
    # The fitted body follows the target within the fit's residual; the cloth must clear the real one.
    surface = TriangleSurface(reg.alignment.apply(target_body.V), target_body.F)
    offset = options.get("offset")
    if offset is None:
        offset = OFFSET_SHARE * body_scale(surface.V)
    if options.get("fix_penetration", True):
        V, fix = penetration.fix_penetration(result.V, garment.F, surface, offset)
        result.info["target_fix"] = fix
        inside = fix["inside_after"]
    else:
        V = result.V
        inside = int((surface.signed_distance(V)[0] < 0).sum())
    result.V = reg.alignment.inverse().apply(V)
    result.penetrating_vertices = inside
    result.info["registration"] = reg.summary()
    result.info["offset"] = float(offset / reg.alignment.scale)
    result.seconds["register"] = float(reg.seconds.get("total", 0.0)) if not reg.cached else 0.0
    result.seconds["target_fix"] = time.perf_counter() - t
    result.seconds["total"] += result.seconds["register"] + result.seconds["target_fix"]
    return result, reg
