"""The non-rigid fit: non-rigid ICP with an as-rigid-as-possible regulariser, landmarks from the shapes,
and the hands and feet fitted each as a whole."""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial import cKDTree

from ..errors import Cancelled
from ..geometry.mesh import edge_lengths_mean, triangle_normals, vertex_areas, vertex_normals
from ..geometry.proximity import TriangleSurface
from .alignment import (
    closest_in_order,
    closest_points,
    coherent_order,
    principal_frame,
    rigid_fit,
    similarity_fit,
    surface_moments,
    surface_samples,
)
from .coarse import CoarseBody

log = logging.getLogger(__name__)


# --- non-rigid fit ----------------------------------------------------------------------------

def _edges(F):
    """The mesh's edges (i < j), in increasing order of (i, j)."""
    a = np.concatenate([F[:, 0], F[:, 1], F[:, 2]])
    b = np.concatenate([F[:, 1], F[:, 2], F[:, 0]])
    n = int(F.max()) + 1 if F.size else 0
    # One integer per edge: a 1D unique is several times faster than unique rows, same order.
    key = np.unique(np.minimum(a, b) * n + np.maximum(a, b))
    return key // n, key % n


def svd_rotations(S):
    """(k,3,3) rotations R maximising trace(R S) (``R = V U^T`` for ``S = U diag(s) V^T``, its last
    column of V negated where that is a reflection)."""
    U, _, Vt = np.linalg.svd(S)
    R = np.einsum("nab,nca->nbc", Vt, U)
    flip = np.linalg.det(R) < 0
    if flip.any():
        Vt[flip, 2, :] *= -1
        R[flip] = np.einsum("nab,nca->nbc", Vt[flip], U[flip])
    return R


def best_rotations(S, iterations=20):
    """``svd_rotations(S)`` for (n,3,3) S, by the polar decomposition where it is a rotation.

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
        R[rest] = svd_rotations(S[rest])
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
        return best_rotations(S)

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


def pairs_to_target(X, N, surface: TriangleSurface, tn_cos, max_dist, order=None):
    """Closest target points of the fit's vertices, with weights 0 for rejected pairs (queried in
    ``order``, see ``closest_in_order``), their distances and the target's normals there."""
    C, d, tri, bary = closest_in_order(surface, X, order)
    Nt = surface.normals_at(tri, bary)
    ok = (np.einsum("ij,ij->i", N, Nt) >= tn_cos) & (d <= max_dist)
    return C, ok.astype(np.float64), d, Nt


def pairs_from_target(X, F, P, Np, tn_cos, max_dist, order=None):
    """Closest points on the fit for target points P: sparse barycentric rows and weights (queried in
    ``order``, see ``closest_in_order``)."""
    _, d, tri, bary = closest_in_order(TriangleSurface(X, F), P, order)
    m = P.shape[0]
    Nf, _ = triangle_normals(X, F[tri])
    ok = (np.einsum("ij,ij->i", Np, Nf) >= tn_cos) & (d <= max_dist)
    B = sp.csr_matrix((bary.ravel(), (np.repeat(np.arange(m), 3), F[tri].ravel())), shape=(m, X.shape[0]))
    return B, ok.astype(np.float64), d


def global_fit(X, F, surface, P, iterations=10, samples=2000, trim=0.9):
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
    scale, R, t = global_similarity(X, F, surface, P, iterations, samples, trim)
    return scale * X @ R.T + t


def global_similarity(X, F, surface, P, iterations=10, samples=2000, trim=0.9):
    """The similarity of ``global_fit``: (scale, R (3,3), t (3,)) with ``Y = scale * X R^T + t``."""
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
        C, d = closest_points(surface, Y, order_s)[:2]
        back = ((Pt - t) @ R) / scale
        Cb, db = closest_points(source_surface, back, order_t)[:2]
        k1 = d <= np.quantile(d, trim)
        k2 = db <= np.quantile(db, trim)
        src_pts = np.vstack([Qs[k1], Cb[k2]])
        dst = np.vstack([C[k1], Pt[k2]])
        R_new, t_new = rigid_fit(scale * src_pts, dst)
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


#: The non-rigid fit's stages, coarse to fine: (triangles of the decimated source, or None for the source
#: itself; its stages as (regulariser weight, steps), stiff to soft). Each level starts from the fit of
#: the one before, carried to it (``coarse.CoarseBody``). Measured on MakeHuman (``female_average`` onto
#: 5K- and 50K-triangle re-meshes of the five bodies, lab/notes/registration-study.md, version 10): the
#: stiff stages need two steps, not three (the same fits); the soft ones on the whole source need their
#: five steps (three: the garments 6% farther from their transfer through the true body on
#: ``female_pear`` 50K). Against every stage on the whole source (version 9) the body's mean error is
#: within 0.1 mm on half the targets and 0.1-0.4 mm nearer the truth on the others, the garments within
#: 0.2 mm; the self-registration 0.13 -> 0.22 mm. A step costs about 0.02 s of CPU on 1,002 vertices,
#: 0.035 s on 3,002 and 0.13 s on the 13,380 of the MakeHuman body (onto a 50K-triangle target).
LEVELS = ((2000, ((2000.0, 2), (600.0, 2), (200.0, 2))),
          (6000, ((60.0, 2), (20.0, 2), (5.0, 2), (1.0, 2))),
          (None, ((5.0, 2), (1.0, 3))))


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


def finer_than_target(X, F, i, j, surface: TriangleSurface):
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


def _landmark_targets(X, ls, lt, height):
    """Where the regions around the limbs' ends must go, for ends that are far from their match.

    A landmark moves the region within LANDMARK_RADIUS of the height around the source extreme by
    the extreme's offset (a hand held at another angle moves as a whole). Ends already within
    LANDMARK_GATE of their match are left to the surface terms: measured on MakeHuman bodies of one
    family, pulling ends that agree only adds error (the extreme is often another toe or finger).

    Parameters
    ----------
    X : (n,3) float
        The source body (or its decimated body: the ends are points of the surface).
    ls, lt : (k,3) float
        The ends of the source and the target (``extremity_landmarks``).
    height : float

    Returns
    -------
    index : (k,) int64
        Source vertices pulled.
    points : (k,3) float64
        Their targets.
    """
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


def rodrigues(w):
    angle = float(np.linalg.norm(w))
    if angle < 1e-300:
        return np.eye(3)
    k = w / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def part_similarity(Y0, Fp, core, Xcur, P, Np, iterations=PART_ITERATIONS, trim=0.9):
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
    R, t, scale = similarity_fit(Y0, Xcur)
    part_surface = TriangleSurface(Y0, Fp)
    # Target points whose closest point on the part is outside its core (near the wrist, ankle) may
    # belong to the rest of the body: pairing them would drag the part towards it.
    outer_tri = ~core[Fp].all(axis=1)
    centre = Y0.mean(axis=0)
    radius = np.linalg.norm(Y0 - centre, axis=1).max()
    # The target points within twice the part's reach of its start: each step picks its points among
    # these (the same ones as among all of them while the part stays within that reach).
    c0, reach = scale * R @ centre + t, 2.0 * scale * radius
    pool = np.flatnonzero(np.linalg.norm(P - c0, axis=1) < reach)
    for _ in range(iterations):
        c = scale * R @ centre + t
        if np.linalg.norm(c - c0) + scale * radius > reach:
            c0, reach = c, 2.0 * scale * radius
            pool = np.flatnonzero(np.linalg.norm(P - c0, axis=1) < reach)
        near = pool[np.linalg.norm(P[pool] - c, axis=1) < scale * radius]
        back = ((P[near] - t) @ R) / scale
        Cb, db, tb = closest_points(part_surface, back)
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
        dR, grow = rodrigues(x[:3]), 1.0 + x[3]
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
        Y, scale = part_similarity(X_rest[idx], Fp, blend >= 1.0, X[idx], P, Np)
        if Y is None:
            continue
        # Kept only where it is plausibly the same part: not grown or shrunk beyond reason, not moved
        # far from where the non-rigid fit put it, and near the target surface about as closely.
        # Measured: MakeHuman hands and feet move 0.02-0.6% of the height and fit within 1.2x of the
        # non-rigid fit's distance; the procedural mannequin's mitten hands onto MakeHuman's moved 6%,
        # its feet fit 2.6x farther, and kept they flipped 2% of its triangles.
        core = blend >= 1.0
        moved = np.linalg.norm(Y[core] - X[idx][core], axis=1).mean()
        d_part = closest_points(surface, Y[core])[1].mean()
        d_fit = closest_points(surface, X[idx][core])[1].mean()
        if (not 1 / PART_SCALE < scale < PART_SCALE or moved > PART_MOVE * height
                or d_part > PART_RESIDUAL * d_fit + 1e-4 * height):
            log.info("registration: %s part fit not used (scale %.3g, moved %.3g, distance %.3g against %.3g)",
                     name, scale, moved, d_part, d_fit)
            continue
        X[idx] += blend[:, None] * (Y - X[idx])
    return X


def nonrigid_fit(X0, F, target_V, target_F, *, levels=LEVELS, normal_cos=0.5, max_share=0.05, target_samples=None,
                 progress=None, seed=0, surface=None, start_similarity=None):
    """Fit the source shape X0 onto the target surface (both in the same frame).

    After a global similarity, the stages of each level run in turn, coarse to fine: on the source
    decimated to that level's triangles (each level decimated from the next finer one; a level that
    would not have 1.5 times fewer triangles, or that libigl cannot decimate, leaves its stages to the
    next finer level), each starting from the fit before it carried to it; then the hands and feet are
    fitted as wholes.

    Parameters
    ----------
    X0 : (n,3) float
        Source body, aligned with the target.
    F : (m,3) int
        Source triangles.
    target_V : (k,3) float
    target_F : (l,3) int
    levels : sequence of (int or None, sequence of (alpha, steps))
        ``LEVELS``: triangles of each level (None, the last: the source) and its regulariser weights
        from stiff to soft.
    normal_cos : float
        Pairs whose normals make a larger angle than arccos(normal_cos) are dropped.
    max_share : float
        Pairs farther apart than this share of the body's height are dropped.
    target_samples : int, optional
        Target points used for the target-to-source term (default: as many as the level's vertices, at
        most 8,000).
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
    if start_similarity is not None and target_samples is None and seed == 0:
        scale, R, t = start_similarity
        X = scale * X0 @ R.T + t
    else:
        ns = target_samples or min(X0.shape[0], 8000)
        X = global_fit(X0, F, surface, surface_samples(target_V, target_F, ns, seed=seed)[0])
    # A target much coarser than the source is itself off the true surface by its facets: the soft
    # stages would copy them into the source's finely meshed parts (hands, feet, face), which stay
    # stiff there (COARSE_FINE); on the torso and limbs they bring the fit closer.
    coarse = edge_lengths_mean(target_V, target_F) > COARSE_TARGET * edge_lengths_mean(X0, F)
    stages = Stages(surface, height, extremity_landmarks(X, F, surface.V, surface.F), coarse=coarse,
                    normal_cos=normal_cos, max_dist=max_share * height, seed=seed, target_samples=target_samples,
                    total=sum(s for _, level in levels for _, s in level), progress=progress)
    Y = fit = None
    for V, G, schedule, alpha_scale, body in decimated_levels(X, F, levels):
        start = V if Y is None else body.carry(Y, fit.rotations(Y))
        fit, Y = stages.run(V, G, start, schedule, alpha_scale=alpha_scale)
    if not coarse:
        # Not on a much coarser target: its hands and feet are a few facets, off the true surface
        # by more than the part's own error (measured: 12 mm on a 5K-triangle MakeHuman re-mesh).
        Y = _fit_parts(X, Y, F, (fit.i, fit.j), surface, height)
    return Y


def decimated_levels(X, F, levels):
    """The bodies the stages of ``levels`` run on, coarse to fine.

    Parameters
    ----------
    X : (n,3) float
        The source body.
    F : (m,3) int
    levels : sequence of (int or None, sequence of (alpha, steps))
        See ``LEVELS``; the last is the source's (None).

    Returns
    -------
    list of (V (k,3), G (l,3), schedule, alpha_scale, body)
        Coarse to fine: each level's rest shape and triangles, its stages, the factor of its
        regulariser weights (``coarse.regulariser_scale`` against the source) and the ``CoarseBody``
        that carries the fit of the level before onto it (None for the first).
    """
    if not levels or levels[-1][0] is not None:
        raise ValueError(f"levels must end with the source's own (None, stages), got {levels!r}")
    fine_to_coarse = [[X, F, tuple(levels[-1][1]), 1.0, None]]
    for faces, schedule in reversed(levels[:-1]):
        finer = fine_to_coarse[-1]
        body = CoarseBody.of(finer[0], finer[1], faces)
        if body is None:
            # Not decimated: its stages run first on the next finer level.
            finer[2] = tuple(schedule) + finer[2]
            continue
        finer[4] = body
        fine_to_coarse.append([body.X, body.F, tuple(schedule), finer[3] * body.alpha_scale, None])
    return [tuple(level) for level in fine_to_coarse[::-1]]


class Stages:
    """The non-rigid fit's stages onto one target, for a body at either resolution.

    Parameters
    ----------
    surface : TriangleSurface
        The target.
    height : float
        The target's height.
    landmarks : tuple of two (k,3) float
        The ends of the source and of the target (``extremity_landmarks``).
    coarse : bool
        The target is much coarser than the source (``COARSE_TARGET``).
    normal_cos, max_dist : float
        Pairs whose normals differ more, or farther apart, are dropped.
    seed : int
        Of the target's points.
    target_samples : int or None
        Target points of the target-to-source term (None: the body's vertex count, at most 8,000).
    total : int
        Steps in all (for ``progress``).
    progress : callable or None
        ``progress(fraction)``; returning True cancels.
    """

    def __init__(self, surface, height, landmarks, *, coarse, normal_cos, max_dist, seed, target_samples,
                 total, progress):
        self.surface, self.height, self.landmarks, self.coarse = surface, height, landmarks, coarse
        self.normal_cos, self.max_dist, self.seed, self.target_samples = normal_cos, max_dist, seed, target_samples
        self.total, self.progress, self.done = total, progress, 0

    def run(self, X_rest, F, X, schedule, alpha_scale=1.0):
        """Run ``schedule`` on the body of rest shape X_rest (k,3) and triangles F, from X (k,3).

        ``alpha_scale`` multiplies every regulariser weight (``coarse.regulariser_scale``).

        Returns
        -------
        fit : ArapFit
        X : (k,3) float64
        """
        surface = self.surface
        ns = self.target_samples or min(X_rest.shape[0], 8000)
        P, tri, _ = surface_samples(surface.V, surface.F, ns, seed=self.seed)
        Np = surface.face_normals[tri]
        li, lp = _landmark_targets(X_rest, *self.landmarks, self.height)
        fit = ArapFit(X_rest, F)
        # Each term weighs by the area it stands for: a body dense in the face and hands must not
        # let them dominate, and the two directions weigh alike.
        area = vertex_areas(X_rest, F)
        wv = area / area.mean()
        wp = np.full(P.shape[0], wv.sum() / P.shape[0])
        fine = finer_than_target(X_rest, F, fit.i, fit.j, surface) if self.coarse else None
        axis = principal_frame(surface_moments(X_rest, F)[1])[0][:, 0]
        # The fit moves a little per step: the query orders of its start and of the target points serve all.
        order_x, order_p = coherent_order(X), coherent_order(P)
        for alpha, steps in schedule:
            for _ in range(steps):
                N = vertex_normals(X, F)
                C, ws, _, _ = pairs_to_target(X, N, surface, self.normal_cos, self.max_dist, order_x)
                B, wt, _ = pairs_from_target(X, F, P, Np, self.normal_cos, self.max_dist, order_p)
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
                    q = X + ((X_rest - X) @ axis)[:, None] * along
                    wq = AXIAL_WEIGHT * wv
                    C = (w[:, None] * C + wq[:, None] * q) / (w + wq)[:, None]
                    w = w + wq
                a = alpha
                if fine is not None and alpha < COARSE_STOP:
                    a = np.where(fine, COARSE_STOP, alpha)
                X = fit.solve(X, a * alpha_scale, w, C, B, wt * wp, P)
                self.done += 1
                if self.progress is not None and self.progress(self.done / self.total):
                    raise Cancelled("registration cancelled")
        return fit, X


# --- shape prior ------------------------------------------------------------------------------
