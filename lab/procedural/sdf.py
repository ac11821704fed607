"""Signed distance primitives and a surface-nets polygoniser (numpy only).

Distances are negative inside. The primitives are exact or close to exact near their surface,
which is all the polygoniser and the projection onto a surface need.
"""

from __future__ import annotations

import numpy as np


def smooth_min(a, b, k):
    """Polynomial smooth minimum (a smooth union of two distance fields with blend radius k)."""
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b * (1.0 - h) + a * h - k * h * (1.0 - h)


def round_cone(P, a, b, ra, rb):
    """Exact distance to the convex hull of two spheres (centre a radius ra, centre b radius rb).

    Parameters
    ----------
    P : (n,3) float
    a, b : (3,) float
    ra, rb : float

    Returns
    -------
    d : (n,) float
    """
    a = np.asarray(a, float)
    ba = np.asarray(b, float) - a
    l2 = ba @ ba
    rr = ra - rb
    a2 = l2 - rr * rr
    il2 = 1.0 / l2
    pa = P - a
    y = pa @ ba
    z = y - l2
    x2 = np.sum((pa * l2 - y[:, None] * ba) ** 2, axis=1)
    y2 = y * y * l2
    z2 = z * z * l2
    k = np.sign(rr) * rr * rr * x2
    far = np.sign(z) * a2 * z2 > k
    near = np.sign(y) * a2 * y2 < k
    side = (np.sqrt(np.maximum(x2 * a2 * il2, 0.0)) + y * rr) * il2 - ra
    return np.where(far, np.sqrt(x2 + z2) * il2 - rb,
                    np.where(near, np.sqrt(x2 + y2) * il2 - ra, side))


def ellipsoid(P, centre, radii):
    """Approximate distance to an axis-aligned ellipsoid (exact on the surface, good near it)."""
    q = (P - np.asarray(centre, float)) / np.asarray(radii, float)
    k0 = np.linalg.norm(q, axis=1)
    k1 = np.linalg.norm(q / np.asarray(radii, float), axis=1)
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)


def gradient(f, P, eps=1e-4):
    """Central-difference gradient of a scalar field f at points P (n,3) -> (n,3)."""
    G = np.empty_like(P)
    for i in range(3):
        e = np.zeros(3)
        e[i] = eps
        G[:, i] = (f(P + e) - f(P - e)) / (2 * eps)
    return G


def surface_nets(f, lo, hi, h):
    """Polygonise the zero level set of f on a regular grid with naive surface nets.

    Parameters
    ----------
    f : callable (n,3) -> (n,)
        Signed distance, negative inside; positive on the whole grid boundary.
    lo, hi : (3,) float
        Grid corners.
    h : float
        Grid spacing.

    Returns
    -------
    V : (n,3) float64
        One vertex per cell that the surface crosses.
    Q : (q,4) int64
        Quads, outward-facing, one per grid edge that the surface crosses.
    """
    lo = np.asarray(lo, float)
    shape = np.ceil((np.asarray(hi, float) - lo) / h).astype(int) + 1
    axes = [lo[i] + h * np.arange(shape[i]) for i in range(3)]
    G = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    D = f(G.reshape(-1, 3)).reshape(tuple(shape))
    # Exact zeros would make an edge "crossed" from neither side; nudge them outwards.
    D = np.where(D == 0.0, 1e-12, D)
    inside = _resolve_ambiguous_faces(D)
    ncell = shape - 1
    cell_id = np.arange(int(np.prod(ncell))).reshape(tuple(ncell))
    acc = np.zeros((int(np.prod(ncell)), 3))
    cnt = np.zeros(int(np.prod(ncell)))
    quads = []
    for axis in range(3):
        sl0 = [slice(None)] * 3
        sl1 = [slice(None)] * 3
        sl0[axis] = slice(0, -1)
        sl1[axis] = slice(1, None)
        cross = inside[tuple(sl0)] != inside[tuple(sl1)]
        idx = np.argwhere(cross)
        d0 = D[tuple(sl0)][cross]
        d1 = D[tuple(sl1)][cross]
        t = np.clip(d0 / np.where(d0 == d1, 1.0, d0 - d1), 0.0, 1.0)
        p = lo + h * idx
        p[:, axis] += h * t
        # The four cells around the edge, counter-clockwise about +axis.
        u, v = (axis + 1) % 3, (axis + 2) % 3
        cells = []
        for du, dv in ((-1, -1), (0, -1), (0, 0), (-1, 0)):
            c = idx.copy()
            c[:, u] += du
            c[:, v] += dv
            cells.append(cell_id[c[:, 0], c[:, 1], c[:, 2]])
        cells = np.stack(cells, axis=1)
        for j in range(4):
            np.add.at(acc, cells[:, j], p)
            np.add.at(cnt, cells[:, j], 1.0)
        flip = ~inside[tuple(sl0)][cross]
        cells[flip] = cells[flip][:, ::-1]
        quads.append(cells)
    Q = np.concatenate(quads)
    used = np.flatnonzero(cnt > 0)
    remap = -np.ones(cnt.shape[0], np.int64)
    remap[used] = np.arange(used.shape[0])
    V = acc[used] / cnt[used, None]
    return V, remap[Q]


def _resolve_ambiguous_faces(D, max_rounds=20):
    """Inside mask of the grid values, with no grid face whose corners alternate in sign.

    Such a face (a saddle at grid scale, usually where the surface grazes a grid point) would
    give surface nets an edge shared by four quads. The corner closest to the surface changes side:
    a move of less than its tiny distance to the surface.
    """
    inside = D < 0
    absd = np.abs(D)
    for _ in range(max_rounds):
        changed = False
        for axis in range(3):
            u, v = [a for a in range(3) if a != axis]
            c = []
            for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                sl = [slice(None)] * 3
                sl[u] = slice(du, inside.shape[u] - 1 + du)
                sl[v] = slice(dv, inside.shape[v] - 1 + dv)
                c.append(tuple(sl))
            s = [inside[sl] for sl in c]
            amb = (s[0] == s[2]) & (s[1] == s[3]) & (s[0] != s[1])
            if not amb.any():
                continue
            changed = True
            mags = np.stack([absd[sl] for sl in c])
            pick = np.argmin(mags, axis=0)
            for k in range(4):
                sel = amb & (pick == k)
                if sel.any():
                    view = inside[c[k]]
                    view[sel] = ~view[sel]
                    inside[c[k]] = view
        if not changed:
            return inside
    return inside
