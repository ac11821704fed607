"""Procedural garments built around the source (banana) mannequin, ready to drape.

Three constructions cover the styles:

- *tubes* (skirts, strapless dresses): rings of quads around the torso axis whose radius follows
  the body (hanging from the hips below them) plus ease, flare and design detail (pleats, gathers,
  tiers, flounces) as a function of angle and height;
- *trousers* (trousers, shorts): a tube from the waist to the crotch that splits into two leg tubes
  sharing a crotch seam;
- *shells* (tops, T-shirts, shift and wrap dresses): an offset of a garment-shaped implicit surface
  (torso, sleeves) polygonised with surface nets and cut open at hem, neck and cuffs.

Every garment starts outside the body by at least ``CLEARANCE`` and comes with the vertices a real
garment hangs from (waistband, top band, shoulders), to be pinned while draping.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .mannequin import PRESETS, Body
from .sdf import gradient, round_cone, smooth_min, surface_nets

log = logging.getLogger(__name__)

# Initial distance between garment and body: more than Blender's default collision distance
# (0.015 m for the collider plus 0.015 m for the cloth) is not needed, less makes the solver start inside.
CLEARANCE = 0.012


@dataclass
class Garment:
    """A garment mesh on the source body.

    Attributes
    ----------
    name : str
    V : (n,3) float64
        Vertex positions (metres, Z up, same frame as the mannequin).
    polygons : (p,4) int64
        Quads.
    pin : (k,) int64
        Vertices to pin while draping (what the garment hangs from).
    """

    name: str
    V: np.ndarray
    polygons: np.ndarray
    pin: np.ndarray


def _source_body():
    return Body(PRESETS["banana"])


def push_out(body: Body, V, clearance=CLEARANCE, iterations=4):
    """Move vertices closer than ``clearance`` to the body (or inside it) out along the gradient.

    Parameters
    ----------
    body : Body
    V : (n,3) float

    Returns
    -------
    (n,3) float64
    """
    V = np.array(V, float)
    for _ in range(iterations):
        d = body.sdf(V)
        close = d < clearance
        if not close.any():
            break
        g = gradient(body.sdf, V[close])
        g /= np.maximum(np.linalg.norm(g, axis=1), 1e-12)[:, None]
        V[close] += (clearance - d[close] + 1e-4)[:, None] * g
    return V


# --------------------------------------------------------------------------- tubes

def _hanging_axes(body: Body, z, z_top):
    """Torso half-axes at heights z (n,) for a garment hanging from z_top: below the widest
    point under z_top a hanging cloth cannot follow the body inwards, so take the running max."""
    zs = np.linspace(z.min(), z_top, 200)
    a, b, cy = body.torso_axes(zs)
    # Running maximum from the top down.
    a_run = np.maximum.accumulate(a[::-1])[::-1]
    b_run = np.maximum.accumulate(b[::-1])[::-1]
    return np.interp(z, zs, a_run), np.interp(z, zs, b_run), np.interp(z, zs, cy)


def _ring_grid(n_rows, n_around):
    """Quads of a tube of n_rows rings of n_around vertices (ring r holds r*n_around + j),
    outward-facing for rings ordered top to bottom and angles increasing counter-clockwise seen from above."""
    r = np.arange(n_rows - 1)[:, None]
    j = np.arange(n_around)[None, :]
    a = r * n_around + j
    b = r * n_around + (j + 1) % n_around
    c = b + n_around
    d = a + n_around
    return np.stack([a, d, c, b], axis=-1).reshape(-1, 4).astype(np.int64)


def tube_garment(name, z_top, z_hem, n_around, n_rows, ease=0.015, flare=0.0, detail=None,
                 follow_body_to=None, pin_rows=1):
    """A tube of quads around the torso.

    Parameters
    ----------
    z_top, z_hem : float
        Heights of the top edge and the hem (metres).
    n_around, n_rows : int
        Vertices per ring and number of rings.
    ease : float
        Extra radius over the body (metres).
    flare : float or callable
        Extra radius per metre below ``follow_body_to`` (or a function of depth (n,) -> (n,)).
    detail : callable or None
        ``detail(theta (r,k), z (r,k), s (r,k)) -> (r,k)`` extra radius (pleats, gathers...),
        s = 0 at the top and 1 at the hem.
    follow_body_to : float or None
        Height down to which the tube follows the body's shape (a fitted bodice); below it the
        tube hangs. Default: the top edge.
    """
    body = _source_body()
    s = np.linspace(0.0, 1.0, n_rows)
    z = z_top + (z_hem - z_top) * s
    theta = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    zf = z_top if follow_body_to is None else follow_body_to
    a_fit, b_fit, cy_fit = body.torso_axes(z)
    a_h, b_h, cy_h = _hanging_axes(body, z, zf)
    below = z < zf
    a = np.where(below, a_h, a_fit)
    b = np.where(below, b_h, b_fit)
    cy = np.where(below, cy_h, cy_fit)
    depth = np.maximum(zf - z, 0.0)
    extra = flare(depth) if callable(flare) else flare * depth
    Th, S = np.meshgrid(theta, s)
    Z = np.broadcast_to(z[:, None], Th.shape)
    R = (ease + extra)[:, None] + (0.0 if detail is None else detail(Th, Z, S))
    # theta = 0 is the front (-Y); increasing theta turns counter-clockwise seen from above.
    X = (a[:, None] + R) * np.sin(Th)
    Y = cy[:, None] - (b[:, None] + R) * np.cos(Th)
    V = np.stack([X, Y, Z], axis=-1).reshape(-1, 3)
    V = push_out(body, V)
    Q = _ring_grid(n_rows, n_around)
    pin = np.arange(pin_rows * n_around, dtype=np.int64)
    return Garment(name, V, Q, pin)


def _pleats(count, depth, start=0.0):
    """Knife pleats: a sawtooth in angle, opening up below ``start`` (fraction of the length)."""
    def detail(th, z, s):
        saw = (th * count / (2 * np.pi)) % 1.0
        grow = np.clip((s - start) / 0.15, 0.0, 1.0)
        return depth * grow * (saw - 0.5)
    return detail


def _gathers(count, depth, start=0.0):
    def detail(th, z, s):
        grow = np.clip((s - start) / 0.1, 0.0, 1.0) * (0.4 + 0.6 * s)
        return depth * grow * np.sin(count * th)
    return detail


def _tiers(n_tiers, step, count, depth):
    """Tiered skirt: each tier wider than the last, with gathers that restart at each seam."""
    def detail(th, z, s):
        k = np.minimum(np.floor(s * n_tiers), n_tiers - 1)
        local = s * n_tiers - k
        return step * k + depth * (0.3 + 0.7 * local) * np.sin(count * th + 0.7 * k) * (k > 0)
    return detail


def _flounce(start, width, count, depth):
    """A flounce: a wider, wavy band below ``start`` (fraction of the length)."""
    def detail(th, z, s):
        t = np.clip((s - start) / (1.0 - start), 0.0, 1.0)
        on = t > 0
        return on * (width * t + depth * t * np.sin(count * th))
    return detail


def _sum(*fs):
    return lambda th, z, s: sum(f(th, z, s) for f in fs)


# --------------------------------------------------------------------------- trousers

def trousers_garment(name, z_top, z_hem, n_around=64, rows_top=10, rows_leg=30, crotch_points=5,
                     ease=0.018, leg_flare=0.0, detail=None):
    """Trousers or shorts: a waist-to-crotch tube that splits into two legs along a crotch seam.

    Parameters
    ----------
    z_top, z_hem : float
        Waistband and hem heights (metres).
    n_around : int
        Vertices of the waist ring (even).
    rows_top, rows_leg : int
        Rings above and below the crotch.
    crotch_points : int
        Vertices on the crotch seam between the front and back centres.
    """
    body = _source_body()
    H = body.H
    z_crotch = 0.445 * H
    theta = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    zs = np.linspace(z_top, z_crotch, rows_top)
    a, b, cy = _hanging_axes(body, zs, 0.50 * H)
    a_fit, b_fit, cy_fit = body.torso_axes(zs)
    above_hip = zs > 0.50 * H
    a = np.where(above_hip, a_fit, a)
    b = np.where(above_hip, b_fit, b)
    cy = np.where(above_hip, cy_fit, cy)
    Th = theta[None, :]
    X = (a[:, None] + ease) * np.sin(Th)
    Y = cy[:, None] - (b[:, None] + ease) * np.cos(Th)
    top = np.stack([X, Y, np.broadcast_to(zs[:, None], X.shape)], axis=-1).reshape(-1, 3)
    quads = [_ring_grid(rows_top, n_around)]
    V = [top]
    last = (rows_top - 1) * n_around
    half = n_around // 2
    front, back = last, last + half
    # Crotch seam from the back centre to the front centre, under the body.
    yb, yf = top[back, 1], top[front, 1]
    t = np.linspace(0, 1, crotch_points + 2)[1:-1]
    seam = np.stack([np.zeros_like(t), yb + (yf - yb) * t, np.full_like(t, z_crotch - 0.01)], axis=1)
    seam_ids = top.shape[0] + np.arange(crotch_points)
    V.append(seam)
    nv = top.shape[0] + crotch_points
    leg_len = z_crotch - z_hem
    for side in (1.0, -1.0):
        leg = body.legs[0 if side < 0 else 1]
        # Half ring going from the front centre round the outside to the back centre.
        if side > 0:
            half_ids = last + np.arange(0, half + 1)
        else:
            half_ids = last + np.concatenate([[0], np.arange(n_around - 1, half - 1, -1)])
        first = np.concatenate([half_ids, seam_ids])
        if side < 0:
            first = first[::-1]
        V_all = np.concatenate(V)
        P0 = V_all[first]
        hip_j = leg[0][0]
        centre0 = np.array([hip_j[0], hip_j[1], z_crotch])
        ang = np.arctan2(P0[:, 1] - centre0[1], P0[:, 0] - centre0[0])
        k = first.shape[0]
        rings = []
        for r in range(1, rows_leg):
            s = r / (rows_leg - 1)
            z = z_crotch - s * leg_len
            c = _leg_centre(leg, z)
            rad = _leg_radius(body, leg, z) + ease + leg_flare * s * leg_len
            w = np.clip(1.0 - s / 0.2, 0.0, 1.0)[..., None]
            circle = np.stack([c[0] + rad * np.cos(ang), c[1] + rad * np.sin(ang), np.full(k, z)], axis=1)
            # Blend from the crotch ring's own shape into circles over the first fifth of the leg.
            drop = np.array([0.0, 0.0, z - z_crotch])
            rings.append(w * (P0 + drop) + (1 - w) * circle)
        leg_V = np.concatenate(rings)
        ids = np.concatenate([first[None, :], nv + np.arange((rows_leg - 1) * k).reshape(rows_leg - 1, k)])
        a_ = ids[:-1, :]
        b_ = np.roll(ids[:-1, :], -1, axis=1)
        c_ = np.roll(ids[1:, :], -1, axis=1)
        d_ = ids[1:, :]
        q = np.stack([a_, d_, c_, b_], axis=-1).reshape(-1, 4)
        quads.append(q)
        V.append(leg_V)
        nv += leg_V.shape[0]
    V = np.concatenate(V)
    if detail is not None:
        V = detail(V)
    V = push_out(body, V)
    Q = np.concatenate(quads).astype(np.int64)
    return Garment(name, V, Q, np.arange(n_around, dtype=np.int64))


def _leg_centre(leg, z):
    pts = [leg[0][0], leg[0][1], leg[1][1], leg[2][1]]
    zs = np.array([p[2] for p in pts])[::-1]
    xs = np.array([p[0] for p in pts])[::-1]
    ys = np.array([p[1] for p in pts])[::-1]
    return np.array([np.interp(z, zs, xs), np.interp(z, zs, ys)])


def _leg_radius(body, leg, z):
    """Radius of the leg at height z, measured on the body along +/-x from the leg's centre."""
    c = _leg_centre(leg, z)
    out = np.array([1.0 if c[0] > 0 else -1.0, 0.0])
    r = np.linspace(0.0, 0.2, 401)
    P = np.stack([c[0] + out[0] * r, np.full_like(r, c[1]), np.full_like(r, z)], axis=1)
    d = body.sdf(P)
    inside = np.flatnonzero(d < 0)
    return float(r[inside[-1]]) if inside.size else 0.05


# --------------------------------------------------------------------------- shells

def shell_garment(name, z_hem, sleeve=0.0, ease=0.02, neck=0.085, flare=0.0, h=0.022,
                  detail=None, front_dip=0.0, pin_shoulders=True):
    """A top or dress as a cut-open offset surface around torso (and arms).

    Parameters
    ----------
    z_hem : float
        Hem height (metres).
    sleeve : float
        Sleeve length from the shoulder joint along the arm (0: sleeveless, armholes).
    ease : float
        Offset from the body (metres).
    neck : float
        Radius of the neck opening.
    flare : float
        Extra radius per metre below the hip.
    h : float
        Polygonisation spacing (metres).
    detail : callable or None
        ``detail(P (n,3)) -> (n,)`` extra offset (a wave for drapes and gathers).
    front_dip : float
        How much lower the neckline sits at the front (a V or scoop).
    """
    body = _source_body()
    H = body.H
    z_hip = 0.50 * H
    keys = body.keys

    def field(P):
        z = P[:, 2]
        a, b, cy = body.torso_axes(np.maximum(z, z_hip))
        below = np.maximum(z_hip - z, 0.0)
        a = a + ease + flare * below
        b = b + ease + flare * below
        x, y = P[:, 0], P[:, 1] - cy
        q = np.sqrt((x / a) ** 2 + (y / b) ** 2)
        gq = np.sqrt((x / a**2) ** 2 + (y / b**2) ** 2)
        d = (q - 1.0) * q / np.maximum(gq, 1e-9)
        top = keys[-1, 0] + ease
        d = np.maximum(d, z - top)
        d = np.maximum(d, z_hem - 0.05 - z)
        sh = body.shoulders
        d = smooth_min(d, round_cone(P, sh[0], sh[1], sh[2] + ease, sh[2] + ease), 0.04)
        neck_d = round_cone(P, *body.neck[:2], body.neck[2] + ease, body.neck[3] + ease)
        d = smooth_min(d, neck_d, 0.03)
        if sleeve > 0:
            for arm in body.arms:
                a0, a1, r0, r1 = arm[0]
                u = (a1 - a0) / np.linalg.norm(a1 - a0)
                end = a0 + u * (sleeve + 0.04)
                r_end = r0 + (r1 - r0) * min(1.0, (sleeve + 0.04) / np.linalg.norm(a1 - a0))
                d = smooth_min(d, round_cone(P, a0, end, r0 + ease + 0.01, r_end + ease + 0.015), 0.05)
        if detail is not None:
            d = d - detail(P)
        return d

    lo = (-0.75, -0.35, z_hem - 0.12)
    hi = (0.75, 0.30, keys[-1, 0] + 0.25)
    V, Q = surface_nets(field, lo, hi, h)
    C = V[Q].mean(axis=1)
    keep = C[:, 2] > z_hem
    neck_c = np.array([0.0, body.neck[0][1]])
    rho = np.linalg.norm(C[:, :2] - neck_c, axis=1)
    z_neck = keys[-1, 0] - 0.01 - front_dip * np.clip(-(C[:, 1] - neck_c[1]) / neck, 0, 1) ** 2
    keep &= ~((rho < neck) & (C[:, 2] > z_neck))
    keep &= ~(C[:, 2] > keys[-1, 0] + 0.06)
    for arm in body.arms:
        a0, a1 = arm[0][0], arm[0][1]
        u = (a1 - a0) / np.linalg.norm(a1 - a0)
        along = (C - a0) @ u
        radial = np.linalg.norm((C - a0) - along[:, None] * u, axis=1)
        arm_side = (C[:, 0] * a0[0] > 0) & (np.abs(C[:, 0]) > abs(a0[0]) - 0.02)
        if sleeve > 0:
            keep &= ~(arm_side & (along > sleeve) & (radial < 0.12))
        else:
            # Armhole: everything around the arm beyond the shoulder joint.
            keep &= ~(arm_side & (along > -0.005) & (radial < arm[0][2] + ease + 0.04))
    Q = Q[keep]
    Q, V = _largest_piece(Q, V)
    V = _smooth_boundary(V, Q)
    V = push_out(body, V)
    top_band = (V[:, 2] > keys[-1, 0] - 0.05) & (np.abs(V[:, 0]) > 0.06) & (np.abs(V[:, 0]) < 0.17)
    pin = np.flatnonzero(top_band) if pin_shoulders else np.zeros(0, np.int64)
    return Garment(name, V, Q.astype(np.int64), pin.astype(np.int64))


def _largest_piece(Q, V):
    """Keep the largest connected piece of quads and drop unused vertices."""
    from garment_transfer.geometry.mesh import connected_pieces

    F = np.concatenate([Q[:, [0, 1, 2]], Q[:, [0, 2, 3]]])
    _, label = connected_pieces(V.shape[0], F)
    lab = label[Q[:, 0]]
    best = np.bincount(lab).argmax()
    Q = Q[lab == best]
    used = np.unique(Q)
    remap = -np.ones(V.shape[0], np.int64)
    remap[used] = np.arange(used.shape[0])
    return remap[Q], V[used]


def _boundary_edges(Q, n):
    """(k,2) edges of the quads Q that only one quad uses."""
    e = np.concatenate([Q[:, [0, 1]], Q[:, [1, 2]], Q[:, [2, 3]], Q[:, [3, 0]]])
    key = np.sort(e, axis=1)
    _, inv, cnt = np.unique(key[:, 0] * n + key[:, 1], return_inverse=True, return_counts=True)
    return e[cnt[inv] == 1]


def _smooth_boundary(V, Q, iterations=10):
    """Smooth the staircase left by cutting a grid surface: average boundary vertices along the
    boundary loops."""
    V = V.copy()
    be = _boundary_edges(Q, V.shape[0])
    n = V.shape[0]
    acc_idx = np.concatenate([be[:, 0], be[:, 1]])
    nb_idx = np.concatenate([be[:, 1], be[:, 0]])
    bverts = np.unique(acc_idx)
    for _ in range(iterations):
        s = np.zeros((n, 3))
        c = np.zeros(n)
        np.add.at(s, acc_idx, V[nb_idx])
        np.add.at(c, acc_idx, 1.0)
        V[bverts] = 0.5 * V[bverts] + 0.5 * s[bverts] / c[bverts, None]
    return V


# --------------------------------------------------------------------------- catalogue

def _fitted(build, fit, name, *args, ease=None, flare=None, leg_flare=None, **kwargs):
    """Call a garment builder with its ease and flare changed for a fit variant."""
    defaults = {tube_garment: 0.015, shell_garment: 0.02, trousers_garment: 0.018}
    ease = defaults[build] if ease is None else ease
    key = "leg_flare" if build is trousers_garment else "flare"
    spread = (leg_flare if build is trousers_garment else flare) or 0.0
    if fit in FITS:
        add_ease, grow, add_flare = FITS[fit]
        ease = max(ease + add_ease, 0.006)
        spread = ((lambda f: lambda t: grow * f(t) + add_flare * t)(spread) if callable(spread)
                  else max(grow * spread + add_flare, 0.0))
        name = f"{name}_{fit}"
    return build(name, *args, ease=ease, **{key: spread}, **kwargs)


def _catalogue(fit="regular"):
    def tube(*a, **k):
        return _fitted(tube_garment, fit, *a, **k)

    def shell(*a, **k):
        return _fitted(shell_garment, fit, *a, **k)

    def trousers(*a, **k):
        return _fitted(trousers_garment, fit, *a, **k)

    H = PRESETS["banana"].height
    waist = 0.625 * H
    hip = 0.50 * H
    knee = 0.30 * H
    bust_top = 0.745 * H
    wave = lambda n, amp, z0: (lambda P: amp * np.sin(n * np.arctan2(P[:, 0], -P[:, 1]))  # noqa: E731
                               * np.clip((z0 - P[:, 2]) / 0.3, 0, 1))
    return {
        # 15 basic styles for training.
        "straight_skirt": lambda: tube("straight_skirt", waist, knee + 0.04, 72, 34, ease=0.012,
                                               flare=0.03),
        "aline_skirt": lambda: tube("aline_skirt", waist, knee, 80, 36, flare=0.22),
        "circle_skirt": lambda: tube("circle_skirt", waist, knee + 0.10, 120, 30,
                                             flare=lambda t: 0.9 * t + 0.8 * t * t),
        "pleated_skirt": lambda: tube("pleated_skirt", waist, knee + 0.05, 144, 34, flare=0.12,
                                              detail=_pleats(24, 0.022, start=0.12)),
        "mini_skirt": lambda: tube("mini_skirt", waist - 0.03, 0.43 * H, 72, 18, flare=0.15),
        "maxi_skirt": lambda: tube("maxi_skirt", waist, 0.07 * H, 96, 50, flare=0.16),
        "tiered_skirt": lambda: tube("tiered_skirt", waist, knee - 0.05, 128, 44, flare=0.08,
                                             detail=_tiers(3, 0.035, 36, 0.008)),
        "flounce_skirt": lambda: tube("flounce_skirt", waist, knee - 0.04, 128, 40, flare=0.05,
                                              detail=_flounce(0.72, 0.09, 18, 0.03)),
        "gathered_skirt": lambda: tube("gathered_skirt", waist, knee, 144, 38, flare=0.15,
                                               detail=_gathers(40, 0.01, start=0.05)),
        "tube_dress": lambda: tube("tube_dress", bust_top, knee + 0.02, 96, 56, ease=0.012,
                                           flare=0.05, follow_body_to=hip, pin_rows=2),
        "slip_dress": lambda: tube("slip_dress", bust_top, 0.22 * H, 96, 56, ease=0.015,
                                           flare=0.28, follow_body_to=0.68 * H, pin_rows=2),
        "tank_top": lambda: shell("tank_top", 0.52 * H, sleeve=0.0, ease=0.02),
        "sweater": lambda: shell("sweater", 0.49 * H, sleeve=0.40, ease=0.03, neck=0.08),
        "trousers": lambda: trousers("trousers", waist - 0.02, 0.05 * H, rows_leg=44,
                                             leg_flare=0.04),
        "culottes": lambda: trousers("culottes", waist - 0.02, knee - 0.02, rows_leg=26,
                                             leg_flare=0.25),
        # More basic styles, for training only.
        "pencil_skirt": lambda: tube("pencil_skirt", waist, knee + 0.02, 72, 34, ease=0.008, flare=0.0),
        "drop_waist_skirt": lambda: tube("drop_waist_skirt", hip + 0.04, knee - 0.06, 96, 30, flare=0.3),
        "box_pleat_skirt": lambda: tube("box_pleat_skirt", waist, knee + 0.02, 120, 34, flare=0.1,
                                        detail=_pleats(12, 0.03, start=0.05)),
        "midi_skirt": lambda: tube("midi_skirt", waist, 0.20 * H, 96, 44, flare=0.2),
        "crop_top": lambda: shell("crop_top", 0.60 * H, sleeve=0.08, ease=0.02),
        "long_sleeve_top": lambda: shell("long_sleeve_top", 0.51 * H, sleeve=0.5, ease=0.022),
        "tunic": lambda: shell("tunic", 0.42 * H, sleeve=0.1, ease=0.03, flare=0.15),
        "bermudas": lambda: trousers("bermudas", waist - 0.02, 0.33 * H, rows_leg=18, leg_flare=0.06),
        "wide_trousers": lambda: trousers("wide_trousers", waist - 0.02, 0.05 * H, rows_leg=44,
                                          leg_flare=0.3),
        "bandeau_dress": lambda: tube("bandeau_dress", bust_top, 0.36 * H, 96, 44, ease=0.012,
                                      flare=0.12, follow_body_to=hip + 0.05, pin_rows=2),
        # 5 complex styles for testing (named as in the paper).
        "shift_dress": lambda: shell("shift_dress", knee + 0.03, sleeve=0.0, ease=0.03,
                                             flare=0.10, front_dip=0.05,
                                             detail=wave(12, 0.006, hip)),
        "formal_dress": lambda: tube("formal_dress", bust_top, 0.06 * H, 112, 64, ease=0.012,
                                             flare=lambda t: 0.08 * t + 0.3 * np.maximum(t - 0.45, 0),
                                             follow_body_to=waist - 0.05, pin_rows=2,
                                             detail=_sum(_flounce(0.78, 0.12, 22, 0.035),
                                                         _gathers(30, 0.006, start=0.3))),
        "wrap_dress": lambda: shell("wrap_dress", knee - 0.02, sleeve=0.12, ease=0.025,
                                            flare=0.22, front_dip=0.14,
                                            detail=lambda P: 0.01 * np.sin(
                                                14 * np.arctan2(P[:, 0], -P[:, 1]) + 9 * P[:, 2])
                                            * np.clip((waist - P[:, 2]) / 0.2, 0, 1)),
        "shorts": lambda: trousers("shorts", waist - 0.02, 0.40 * H, rows_top=12, rows_leg=12,
                                           n_around=80, leg_flare=0.12,
                                           detail=_cuff_pleats(0.40 * H)),
        "tshirt": lambda: shell("tshirt", 0.50 * H, sleeve=0.16, ease=0.025, neck=0.09),
    }


def _cuff_pleats(z_hem):
    """Turned-up cuffs: a bulge near the hem of each leg."""
    def detail(V):
        V = V.copy()
        near = np.clip(1.0 - (V[:, 2] - z_hem) / 0.05, 0.0, 1.0) * (V[:, 2] < z_hem + 0.05)
        r = np.array([V[:, 0] - np.sign(V[:, 0]) * 0.11, V[:, 1] - 0.01]).T
        r /= np.maximum(np.linalg.norm(r, axis=1), 1e-9)[:, None]
        V[:, :2] += 0.012 * near[:, None] * r
        return V
    return detail


TRAIN_GARMENTS = ("straight_skirt", "aline_skirt", "circle_skirt", "pleated_skirt", "mini_skirt",
                  "maxi_skirt", "tiered_skirt", "flounce_skirt", "gathered_skirt", "tube_dress",
                  "slip_dress", "tank_top", "sweater", "trousers", "culottes")
TEST_GARMENTS = ("shift_dress", "formal_dress", "wrap_dress", "shorts", "tshirt")
EXTRA_STYLES = ("pencil_skirt", "drop_waist_skirt", "box_pleat_skirt", "midi_skirt", "crop_top",
                "long_sleeve_top", "tunic", "bermudas", "wide_trousers", "bandeau_dress")
#: Fit variants of the training styles: (ease added, flare multiplied, flare added per metre).
FITS = {"loose": (0.025, 1.6, 0.05), "tight": (-0.008, 0.4, 0.0)}
#: Training garments beyond the demo's: loose and tight variants of its 15 styles, 10 more styles.
EXTRA_GARMENTS = tuple(f"{g}_{f}" for g in TRAIN_GARMENTS for f in FITS) + EXTRA_STYLES


def garment(name) -> Garment:
    """Build one of the catalogue's garments on the source body (deterministic).

    Parameters
    ----------
    name : str
        One of TRAIN_GARMENTS, TEST_GARMENTS or EXTRA_GARMENTS.
    """
    style, fit = name, "regular"
    for f in FITS:
        if name.endswith("_" + f) and name[:-len(f) - 1] in TRAIN_GARMENTS:
            style, fit = name[:-len(f) - 1], f
    cat = _catalogue(fit)
    if style not in cat or (fit != "regular" and style not in TRAIN_GARMENTS):
        raise ValueError(f"name: unknown garment {name!r}; expected one of "
                         f"{sorted(set(cat) | set(EXTRA_GARMENTS))}")
    g = cat[style]()
    log.debug("garment %s: %d vertices, %d quads", name, g.V.shape[0], g.polygons.shape[0])
    return g
