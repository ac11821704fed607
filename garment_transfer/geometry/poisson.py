"""Rebuilding a mesh from per-triangle deformation gradients (paper eq. 5).

Minimise ``sum_t w_t tr(R_t M_t R_t^T) + lam * sum_i |y_i - p_i|^2``, where ``R_t`` (3x2) holds the
residuals ``(y_tk - y_t1) - Q_t (x_tk - x_t1)`` of triangle t's two edges (k = 2, 3) and ``M_t`` is a
2x2 metric (``ENERGIES``):

- ``"gradients"`` (the default): ``M_t = c area_t (E_t^T E_t)^-1`` with ``E_t`` the triangle's two source
  edges, so that the term is the linear finite-element energy ``c sum_t w_t area_t |grad y_t - Q_t|^2`` of
  the difference between the garment's gradient and the target's (in its cotangent form, each edge's
  weight clamped to be positive: ``triangle_metrics``). It does not depend on which vertex of a
  triangle comes first, and a thin triangle resists being turned as much as a well-shaped one: with the
  paper's metric a thin triangle's short edge costs little to turn, so whatever strain the anchors leave
  gathers there and folds it over (MakeHuman's ``male_casualsuit02`` on ``female_pear`` with its own placement:
  MDC 0.0146 against 0.0093, ``python -m lab.poisson_energy``). ``c`` makes a
  median triangle cost what it costs with the paper's metric; an edge's weight is capped at
  ``METRIC_CAP`` times the median (angles under about 1 degree are held no stiffer).
- ``"edges"``: ``M_t = I``, the paper's eq. 5, ``sum_k |Q_t (x_tk - x_t1) - (y_tk - y_t1)|^2``.

The first term fixes the shape but not where it is (translation-invariant). The second, weak, term
ties every vertex to an anchor position ``p_i`` (where the body says the garment goes): with a small
``lam`` it only decides the low frequencies, the placement, and leaves folds to the gradients. The
normal equations ``(G^T W G + lam I) y = G^T W b + lam p`` (``W`` block diagonal of ``w_t M_t``) have a
matrix that depends only on the garment's topology and source positions: it is factored once and
reused for every target.

Two ways to solve it:

- ``factor``: a sparse LU factorisation (SuperLU, in the order of ``nested_dissection``), then two
  triangular solves per target. The factor is the expensive part (0.6-0.8 s for a 78K-vertex garment
  on one core of the benchmark machine) and its memory grows faster than the garment; a solve is then
  0.03-0.07 s.
- ``multigrid``: conjugate gradients preconditioned by a smoothed-aggregation multigrid cycle
  (``Multigrid``), started from the anchors, the three coordinates on threads at once. Building the
  hierarchy is 0.13 s at 78K vertices (on a thread while the garment is bound, ``transfer.prepare_garment``)
  and the three solves 0.11-0.14 s on two cores; time and memory grow linearly (500K vertices: about 1 s
  to build, 1.1 s to solve). It answers to ``MULTIGRID_TOLERANCE`` (relative residual), which on the
  benchmark garments is within 1e-8 of the garment's size of the factor's answer.

``choose_method`` picks: the factor when the garment is reused for many targets and small enough,
multigrid for one target and for very large garments (``python -m lab.speed`` measures both).
"""

from __future__ import annotations

import logging
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .mesh import degenerate_triangles, edge_lengths_mean
from .proximity import THREADS

logger = logging.getLogger(__name__)

#: Vertices per block where the nested dissection stops (measured: 64 factors fastest, 0.5-0.8 s
#: in all at 55K-78K vertices, order included).
LEAF = 64
#: Above this many vertices a garment is solved by multigrid even when reused: its factor grows
#: faster than the garment (150K vertices: 1.7 s to factor and 0.09 s per solve, against 0.44 s and
#: 0.76 s by multigrid, so the factor pays from the second target; 500K vertices: 22 s and 2.2 GB).
FACTOR_MAX_VERTICES = 200_000
#: From this many vertices a one-target transfer is solved by multigrid: below, the factor is as fast
#: (best of 6, factor and multigrid alternating, on the benchmark dress: 14K vertices 0.08 s against
#: 0.10 s, 23K 0.16 against 0.17, 42K 0.34 against 0.30, 78K 0.79 against 0.57).
MULTIGRID_MIN_VERTICES = 40_000
MULTIGRID_TOLERANCE = 1e-8
#: The multigrid smoother's polynomial: its degree, and the share of the largest eigenvalue where the
#: part of the spectrum it damps begins (``_hierarchy``).
CHEBYSHEV_DEGREE = 2
CHEBYSHEV_LOWER = 0.1
#: ... and where it ends, as a multiple of the estimate of that eigenvalue, found in this many steps.
CHEBYSHEV_UPPER = 1.2
SPECTRUM_STEPS = 10
#: The prolongator's Jacobi damping (over the largest eigenvalue of D^-1 A), and the hierarchy's
#: limits: a level this small is solved directly; at most this many levels above it.
PROLONGATION_OMEGA = 4.0 / 3.0
COARSE_MAX = 10
#: Strength of connection of the aggregation (pyamg's symmetric measure): couplings weaker than this
#: share of their rows' largest are not followed. 0 follows every edge, which on the bench dress's thin
#: cells and the finite-element energy needs 33 iterations instead of 11-13 (0.05-0.1; edge energy 10-12
#: with either; 0.25 is worse for both: one-off script, 156K triangles).
STRENGTH_THETA = 0.08
LEVELS_MAX = 9
#: Threads solving the coordinates by multigrid at once (one per coordinate at most).
SOLVE_THREADS = min(3, THREADS)
METHODS = ("factor", "multigrid")
#: The metrics of the gradient term (module doc).
ENERGIES = ("gradients", "edges")
#: The largest weight of an edge in the gradient term, as a multiple of the median (``triangle_metrics``).
METRIC_CAP = 50.0


def choose_method(n_vertices, reused=True):
    """``"factor"`` or ``"multigrid"`` for a garment of ``n_vertices`` vertices, solved for many
    targets (``reused``) or one."""
    if n_vertices > FACTOR_MAX_VERTICES or (not reused and n_vertices >= MULTIGRID_MIN_VERTICES):
        return "multigrid"
    return "factor"


def edge_operator(n, F):
    """The sparse operator G mapping vertex positions to the two edges ``x2-x1, x3-x1`` of every triangle.

    Parameters
    ----------
    n : int
        Vertex count.
    F : (m,3) int

    Returns
    -------
    G : (2m,n) scipy.sparse.csr_matrix
        Rows 2t and 2t+1 are the two edges of triangle t.
    """
    m = F.shape[0]
    rows = np.repeat(np.arange(2 * m), 2)
    cols = np.stack([F[:, 1], F[:, 0], F[:, 2], F[:, 0]], axis=1).reshape(-1)
    vals = np.tile([1.0, -1.0], 2 * m)
    return sp.csr_matrix((vals, (rows, cols)), shape=(2 * m, n))


def triangle_metrics(V, F, weights):
    """The gradient term's 2x2 metric of every triangle, ``w_t M_t`` (module doc, ``"gradients"``).

    ``c area (E^T E)^-1`` written with the triangle's cotangents, ``1/2 [[k3 + k1, -k1], [-k1, k2 + k1]]``
    (``k_i``: the cotangent of the angle at vertex i, ``c`` times), that is ``1/2 sum_e k_e |r_e|^2`` over
    the three edges' residuals, each ``k`` clamped to ``[0, METRIC_CAP x the median]``. Without an obtuse
    angle (and under the cap) it is the finite-element metric itself; the clamping keeps every edge's
    weight positive, so the system stays a graph Laplacian plus a diagonal, which the multigrid's
    aggregation expects (with the unclamped metric and the earlier cycle the bench dress needed 118
    iterations instead of 12).

    Parameters
    ----------
    V : (n,3) float
    F : (m,3) int
    weights : (m,) float
        ``w_t``; a triangle of weight 0 (degenerate) gets a zero metric.

    Returns
    -------
    (m,2,2) float64, symmetric positive semi-definite.
    """
    V = np.asarray(V, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    x1 = V[F[:, 0]]
    e1, e2 = V[F[:, 1]] - x1, V[F[:, 2]] - x1
    a, b, d = (np.einsum("mj,mj->m", e1, e1), np.einsum("mj,mj->m", e1, e2), np.einsum("mj,mj->m", e2, e2))
    det = a * d - b * b
    used = (weights > 0) & (det > 0)
    M = np.zeros((F.shape[0], 2, 2))
    if not used.any():
        return M
    root = np.sqrt(det[used])
    # Cotangents of the angles at vertices 1, 2, 3 (|e1 x e2| = sqrt(det) for all three).
    k = np.stack([b[used], a[used] - b[used], d[used] - b[used]], axis=1) / root[:, None]
    k = np.clip(k, 0.0, METRIC_CAP * np.median(np.maximum(k, 0.0)))
    # c: the median triangle costs what it costs with the identity metric, for a gradient error in the
    # triangle's plane: |e1|^2 + |e2|^2 against 2 c area.
    k *= 0.5 * np.median((a[used] + d[used]) / root)
    M[used] = np.stack([np.stack([k[:, 2] + k[:, 0], -k[:, 0]], -1), np.stack([-k[:, 0], k[:, 1] + k[:, 0]], -1)], -2)
    return M * weights[:, None, None]


def anchor_weight_for(V, F, stiffness_length, edge_length=None):
    """The weight ``lam`` at which the anchors decide shape features longer than ``stiffness_length``.

    The gradient term behaves like ``h^-2`` times a Dirichlet energy per unit area for a mesh of edge
    length ``h``, and the anchor term like ``lam h^-2``; they balance at wavelength ``h / sqrt(lam)``.
    ``edge_length``: the mesh's ``edge_lengths_mean``, if known.
    """
    h = edge_lengths_mean(V, F) if edge_length is None else edge_length
    return float((h / stiffness_length) ** 2)


class PoissonSolver:
    """Factor once per garment, solve for any deformation gradient field.

    Parameters
    ----------
    V : (n,3) float
        The garment's source shape.
    F : (m,3) int
    anchor_weight : float or (n,) float
        ``lam`` > 0 (see module doc), one for all vertices or one per vertex (anchors that bind
        only some vertices firmly and leave the others almost free).
    triangle_weights : (m,) float, optional
        ``w_t``; degenerate triangles of the source get 0 by default.
    method : {"factor", "multigrid"}
        How the system is solved (module doc).
    energy : {"gradients", "edges"}
        The gradient term's metric (module doc): the finite-element energy, or the paper's.
    """

    def __init__(self, V, F, anchor_weight, triangle_weights=None, method="factor", energy="gradients"):
        if method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
        if energy not in ENERGIES:
            raise ValueError(f"energy must be one of {', '.join(ENERGIES)}, got {energy!r}")
        self.energy = energy
        self.method = method
        self.V = np.asarray(V, dtype=np.float64)
        self.F = np.asarray(F, dtype=np.int64)
        n = self.V.shape[0]
        weight = np.asarray(anchor_weight, dtype=np.float64)
        if weight.ndim not in (0, 1) or (weight.ndim == 1 and weight.shape != (n,)):
            raise ValueError(f"anchor_weight must be a number or have shape ({n},), got {weight.shape}")
        if not np.all(weight > 0):
            raise ValueError(f"anchor_weight must be > 0, got {weight.min() if weight.size else weight}")
        if triangle_weights is None:
            triangle_weights = (~degenerate_triangles(self.V, self.F)).astype(np.float64)
        self.triangle_weights = np.asarray(triangle_weights, dtype=np.float64)
        self.anchor_weight = float(weight) if weight.ndim == 0 else weight
        self._lam = np.broadcast_to(weight, (n,))[:, None]
        G = edge_operator(n, self.F)
        if energy == "edges":
            W = sp.diags(np.repeat(self.triangle_weights, 2))
        else:
            m = self.F.shape[0]
            rows = np.repeat(np.arange(2 * m).reshape(m, 2), 2, axis=1).reshape(-1)
            cols = np.tile(np.arange(2 * m).reshape(m, 2), (1, 2)).reshape(-1)
            W = sp.csr_matrix((triangle_metrics(self.V, self.F, self.triangle_weights).reshape(-1), (rows, cols)),
                              shape=(2 * m, 2 * m))
        self.GtW = (G.T @ W).tocsr()
        K = self.GtW @ G + sp.diags(np.broadcast_to(weight, (n,)).astype(np.float64))
        self.factor = self.hierarchy = None
        if method == "factor":
            self.factor = _factor(K.tocsc(), self.V)
        else:
            self.K = K.tocsr()
            self.hierarchy = _hierarchy(self.K)
        x1 = self.V[self.F[:, 0]]
        # Source edges per triangle: (m,3,2), columns e1, e2.
        self.edges = np.stack([self.V[self.F[:, 1]] - x1, self.V[self.F[:, 2]] - x1], axis=2)

    def solve(self, Q, anchors):
        """Vertex positions whose triangles follow Q, placed by the anchors.

        Parameters
        ----------
        Q : (m,3,3) float
            Target deformation gradient of every triangle.
        anchors : (n,3) float
            Where each vertex should be, weakly.

        Returns
        -------
        Y : (n,3) float64
        """
        # Q e1 and Q e2 of every triangle, interleaved as the rows of G (two products of a matrix and
        # a vector are 4x faster than one three-index einsum).
        b = np.stack([np.einsum("mij,mj->mi", Q, self.edges[:, :, 0]),
                      np.einsum("mij,mj->mi", Q, self.edges[:, :, 1])], axis=1).reshape(-1, 3)
        anchors = np.asarray(anchors, dtype=np.float64)
        rhs = self.GtW @ b + self._lam * anchors
        if self.factor is not None:
            return self.factor.solve(rhs)
        columns = range(rhs.shape[1])
        if SOLVE_THREADS == 1:
            return np.column_stack([self._iterate(rhs[:, c], anchors[:, c]) for c in columns])
        # The coordinates are independent systems, and a multigrid cycle here is scipy's sparse products
        # and numpy's vector operations, which release the GIL: they run at once.
        with ThreadPoolExecutor(min(SOLVE_THREADS, rhs.shape[1])) as pool:
            return np.column_stack(list(pool.map(lambda c: self._iterate(rhs[:, c], anchors[:, c]), columns)))

    def _iterate(self, rhs, start):
        residuals = []
        x = self.hierarchy.solve(rhs, x0=start, tol=MULTIGRID_TOLERANCE, maxiter=200, residuals=residuals)
        scale = np.linalg.norm(rhs)
        if not (np.isfinite(x).all() and np.linalg.norm(rhs - self.K @ x) <= 10 * MULTIGRID_TOLERANCE * scale):
            # Not converged (never seen on garments: a safeguard): the exact answer, at the factor's price.
            logger.warning("multigrid did not converge in %d iterations; factoring instead", len(residuals))
            if self.factor is None:
                self.factor = _factor(self.K.tocsc(), self.V)
            return self.factor.solve(rhs)
        return x


class JoinedPoissonSolver:
    """The solve of a garment whose vertices at one place are one (``mesh.joined_pieces``: pieces not joined at
    their seams): the joined garment's ``PoissonSolver``, each place anchored where its first vertex is, the answer
    given to every vertex of the place, so that the result keeps its seams closed.

    Parameters
    ----------
    solver : PoissonSolver
        Of the joined garment (its anchor weights those of each place's first vertex).
    first : (p,) int
        The first vertex at each place.
    place : (n,) int
        Each vertex's place.
    """

    def __init__(self, solver: PoissonSolver, first, place):
        self.solver = solver
        self.first = np.asarray(first, dtype=np.int64)
        self.place = np.asarray(place, dtype=np.int64)
        self.method = solver.method

    def solve(self, Q, anchors):
        """As ``PoissonSolver.solve``: (n,3), equal at each place."""
        return self.solver.solve(Q, np.asarray(anchors, dtype=np.float64)[self.first])[self.place]


class OrderedFactor:
    """A sparse LU factor of ``K[p][:, p]``, solving ``K x = b``."""

    def __init__(self, K, order):
        self.order = order
        Kp = K[order][:, order].tocsc()
        # K is symmetric positive definite: no pivoting needed, and the ordering is ours.
        self.lu = spla.splu(Kp, permc_spec="NATURAL", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        # One factor serves the poses fitted at once in threads (``pose_fit.fit_poses``): one solve at a time.
        self._lock = threading.Lock()

    def solve(self, b):
        x = np.empty_like(b, dtype=np.float64)
        rhs = np.ascontiguousarray(b[self.order], dtype=np.float64)
        with self._lock:
            x[self.order] = self.lu.solve(rhs)
        return x


def nested_dissection(V, K, leaf=LEAF):
    """A fill-reducing order of the vertices for factoring K: geometric nested dissection.

    The vertices are split in two halves across their widest extent; the vertices of one half joined
    to the other (the separator) are numbered last, each half first, recursively, down to ``leaf``
    vertices. On a garment's surface the separators are short curves, so the factor's fill stays near
    ``n log n`` whatever the mesh. SuperLU's own minimum-degree order gives a little less fill but its run
    time is erratic on real garments: 5.5 s and 24.8 s for the demo's wrap dress and pleated skirt
    subdivided to 55K and 77K vertices, against 0.5 s and 0.7 s here, order included.

    Parameters
    ----------
    V : (n,3) float
    K : (n,n) sparse
        Its pattern says which vertices are joined.
    leaf : int

    Returns
    -------
    order : (n,) int64
        A permutation of ``0..n-1``.
    """
    G = sp.csr_matrix(K)
    indptr, indices = G.indptr, G.indices
    n = V.shape[0]
    side = np.zeros(n, np.int8)
    out = []
    stack = [(np.arange(n), False)]
    # Depth-first, the separator after both halves: a stack of (vertices, done-marker) entries.
    while stack:
        idx, is_separator = stack.pop()
        if is_separator or idx.size <= leaf:
            out.append(idx)
            continue
        P = V[idx]
        axis = int(np.argmax(P.max(axis=0) - P.min(axis=0)))
        half = idx.size // 2
        left = np.zeros(idx.size, bool)
        left[np.argpartition(P[:, axis], half)[:half]] = True
        L, R = idx[left], idx[~left]
        side[R] = 2
        side[L] = 1
        starts, counts = indptr[L], indptr[L + 1] - indptr[L]
        total = int(counts.sum())
        owner = np.repeat(np.arange(L.size), counts)
        neighbour = indices[np.repeat(starts - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
                            + np.arange(total)]
        touches = np.zeros(L.size, bool)
        touches[owner[side[neighbour] == 2]] = True
        side[idx] = 0
        # Pushed in reverse: left half, right half, then the separator.
        stack.append((L[touches], True))
        stack.append((R, False))
        stack.append((L[~touches], False))
    return np.concatenate(out) if out else np.zeros(0, np.int64)


def _factor(K, V):
    return OrderedFactor(K, nested_dissection(V, K))


def _hierarchy(K):
    return Multigrid(K)


def _dot(u, v):
    # Not np.dot: BLAS, whose threads would spin on the cores the other work uses.
    return float(np.einsum("i,i->", u, v))


def largest_eigenvalue(A, steps, scale=None):
    """An estimate from below of the largest eigenvalue of a symmetric positive semidefinite matrix,
    by ``steps`` Lanczos steps from a fixed start (the same answer every time).

    Parameters
    ----------
    A : (n,n) sparse
    steps : int
    scale : (n,) float, optional
        Estimate that of ``S A S`` for ``S = diag(scale)`` instead (with ``scale = D^-1/2``, the
        largest eigenvalue of ``D^-1 A``).

    Returns
    -------
    float
    """
    def apply(x):
        return A @ x if scale is None else scale * (A @ (scale * x))

    q = np.random.default_rng(0).random(A.shape[0])
    q /= np.sqrt(_dot(q, q))
    previous = np.zeros_like(q)
    alpha, beta = [], [0.0]
    for _ in range(min(steps, A.shape[0])):
        w = apply(q)
        a = _dot(q, w)
        w -= a * q + beta[-1] * previous
        alpha.append(a)
        b = np.sqrt(_dot(w, w))
        if not b > 1e-12 * abs(a):
            break
        beta.append(b)
        previous, q = q, w / b
    k = len(alpha)
    T = np.diag(alpha) + np.diag(beta[1:k], 1) + np.diag(beta[1:k], -1)
    return float(np.linalg.eigvalsh(T)[-1])


class Multigrid:
    """Conjugate gradients preconditioned by a multigrid V-cycle, for a symmetric positive definite K.

    The levels are smoothed aggregation built here from pyamg's aggregation and tentative prolongator
    (strength of connection ``STRENGTH_THETA``); the prolongator's
    Jacobi step and the smoother take their largest eigenvalues from our own Lanczos search
    (``largest_eigenvalue``), which calls no BLAS and starts from a fixed vector, and every level is
    kept in CSR. At 78K vertices the hierarchy builds in 0.06-0.08 s against 0.12 s for pyamg's
    ``smoothed_aggregation_solver`` with the same options, whose searches (Arnoldi, with BLAS) took
    half its time and left OpenBLAS's threads spinning on the second core, for the same iteration
    counts (``python -m lab.multigrid``). The cycle and the iteration
    are ours, so that everything a solve does is scipy's sparse products and numpy's vector operations:
    they release the GIL, so the coordinates are solved on threads at once, and none calls BLAS, whose
    threads would wait on the cores those use. The smoother is a Chebyshev polynomial of each level's
    Jacobi-scaled matrix ``D^-1 A`` rather than pyamg's default symmetric Gauss-Seidel: as many
    iterations (10-12 per coordinate to 1e-8 at 78K vertices, 12-15 at 500K) and cheaper ones (the three
    coordinates at 78K: 0.15 s against 0.36 s on one core, 0.08 s on two; at 500K 1.2 s against 2.7 s,
    and 0.8 s).

    Parameters
    ----------
    K : (n,n) sparse
    """

    def __init__(self, K):
        from pyamg.aggregation.aggregate import standard_aggregation
        from pyamg.aggregation.tentative import fit_candidates
        from pyamg.relaxation.chebyshev import chebyshev_polynomial_coefficients
        from pyamg.strength import symmetric_strength_of_connection

        self.K = sp.csr_matrix(K)
        A = self.K
        candidates = np.ones((A.shape[0], 1))
        self.levels = []
        while A.shape[0] > COARSE_MAX and len(self.levels) < LEVELS_MAX:
            aggregates = standard_aggregation(symmetric_strength_of_connection(A, theta=STRENGTH_THETA))[0]
            if aggregates.shape[1] in (0, A.shape[0]):
                break
            T, candidates = fit_candidates(aggregates, candidates)
            T = sp.csr_matrix(T)
            # The tentative prolongator smoothed by one damped Jacobi step, omega over the largest
            # eigenvalue of D^-1 A (as pyamg's smoothed aggregation does, with a search of our own).
            inverse_diagonal = 1.0 / A.diagonal()
            rho = largest_eigenvalue(A, SPECTRUM_STEPS, np.sqrt(inverse_diagonal))
            P = (T - sp.diags(inverse_diagonal * (PROLONGATION_OMEGA / rho)) @ (A @ T)).tocsr()
            R = P.T.tocsr()
            # The smoother is a polynomial of D^-1 A, whose interval reaches past the estimate of its
            # largest eigenvalue (a Lanczos estimate is below it).
            coefficients = -chebyshev_polynomial_coefficients(CHEBYSHEV_LOWER * rho, CHEBYSHEV_UPPER * rho,
                                                              CHEBYSHEV_DEGREE)[:-1]
            self.levels.append((A, R, P, (inverse_diagonal, coefficients)))
            A = (R @ A @ P).tocsr()
        self.coarse = np.linalg.pinv(A.toarray())

    def _smooth(self, A, smoother, r):
        """p(D^-1 A) D^-1 r, the smoother's correction for the residual r (Horner's rule; D: A's diagonal)."""
        inverse_diagonal, coefficients = smoother
        r = inverse_diagonal * r
        h = coefficients[0] * r
        for c in coefficients[1:]:
            h = c * r + inverse_diagonal * (A @ h)
        return h

    def cycle(self, b):
        """One V-cycle from zero: an approximation of ``K^-1 b`` (symmetric in b, so CG may use it)."""
        xs, bs = [], []
        for A, R, _, coefficients in self.levels:
            x = self._smooth(A, coefficients, b)
            xs.append(x)
            bs.append(b)
            b = R @ (b - A @ x)
        x = self.coarse @ b
        for (A, _, P, coefficients), xl, bl in zip(reversed(self.levels), reversed(xs), reversed(bs)):
            xl = xl + P @ x
            x = xl + self._smooth(A, coefficients, bl - A @ xl)
        return x

    def solve(self, b, x0, tol, maxiter, residuals=None):
        """Preconditioned conjugate gradients from x0 until ``|b - K x| <= tol |b|``.

        Parameters
        ----------
        b, x0 : (n,) float
        tol : float
        maxiter : int
        residuals : list, optional
            Receives the residual norms, one per iteration.

        Returns
        -------
        x : (n,) float64
        """
        x = np.array(x0, dtype=np.float64)
        r = b - self.K @ x
        target = tol * np.sqrt(_dot(b, b))
        z = self.cycle(r)
        p = z
        rz = _dot(r, z)
        for _ in range(maxiter):
            norm = np.sqrt(_dot(r, r))
            if residuals is not None:
                residuals.append(norm)
            if norm <= target:
                break
            Kp = self.K @ p
            alpha = rz / _dot(p, Kp)
            x += alpha * p
            r -= alpha * Kp
            z = self.cycle(r)
            rz, previous = _dot(r, z), rz
            p = z + (rz / previous) * p
        return x
