"""The shape-basis fit: the source body as a blend of its own shapes (shape keys, other bodies of its
mesh, a body model's sliders), fitted to a target with a similarity."""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp

from ..errors import TopologyMismatchError
from ..geometry.mesh import Mesh, same_mesh, triangle_normals
from ..geometry.proximity import TriangleSurface
from .alignment import coherent_order, principal_frame, surface_moments, surface_samples
from .nonrigid import global_similarity, pairs_from_target, pairs_to_target, rodrigues

log = logging.getLogger(__name__)


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
#: spread the target over many of them (wrong regional weights, measured in lab/notes/registration-study.md).
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


def weight_bounds(bounds, k, name="shape basis"):
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
    lo, hi = weight_bounds(bounds, k)
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
    scale, R, t = global_similarity(X0, F, surface, P_global)
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
        C, ok1, d1, Nt = pairs_to_target(Sv @ Y, triangle_normals(Y, F[stri])[0], surface, normal_cos, max_dist,
                                          order_s)
        B, ok2, d2 = pairs_from_target(Y, F, P, Np, normal_cos, max_dist, order_p)
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
        Rd = rodrigues(omega)
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
