"""Procedural A-pose mannequins of one fixed topology, shaped by a few body measurements.

The body is an implicit surface: a torso lofted through elliptical cross-sections (hip, belly,
waist, bust, chest, shoulders) joined smoothly to a neck, head, arms and legs made of sphere-hulls.
The banana preset is polygonised once (surface nets); every other shape is reached by walking the
measurements from banana to that shape in small steps and projecting the same vertices onto each
intermediate surface, so all bodies share vertices and triangles.

Units are metres, Z up, the body stands on z = 0 and faces -Y.
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass, replace

import numpy as np

from .sdf import ellipsoid, gradient, round_cone, smooth_min, surface_nets

# Grid spacing of the template polygonisation: about 16K triangles on the banana body.
TEMPLATE_SPACING = 0.017
# Steps of the walk from the banana body to another shape: small enough that a vertex never
# jumps to another part of the surface.
MORPH_STEPS = 10


@dataclass(frozen=True)
class Measurements:
    """Body measurements in metres (circumferences unless noted).

    Attributes
    ----------
    height : float
        Floor to top of head.
    bust, underbust, waist, belly, hip : float
        Torso girths (belly at navel height, hip at the widest point of the seat).
    thigh, calf, upper_arm, neck : float
        Limb and neck girths.
    shoulder_width : float
        Distance between the shoulder points (acromions).
    belly_forward : float
        How far the belly's centre sits in front of the waist's (a protruding belly).
    """

    height: float = 1.70
    bust: float = 0.86
    underbust: float = 0.78
    waist: float = 0.74
    belly: float = 0.80
    hip: float = 0.90
    thigh: float = 0.52
    calf: float = 0.34
    upper_arm: float = 0.27
    neck: float = 0.33
    shoulder_width: float = 0.39
    belly_forward: float = 0.0


PRESETS = {
    # Straight: bust, waist and hip close together (the paper's source body).
    "banana": Measurements(),
    # Wide hips and thighs, narrow shoulders (the paper's target body).
    "pear": Measurements(bust=0.84, underbust=0.75, waist=0.72, belly=0.86, hip=1.08, thigh=0.63,
                         calf=0.37, upper_arm=0.28, shoulder_width=0.355, belly_forward=0.01),
    "slim": Measurements(height=1.74, bust=0.80, underbust=0.70, waist=0.64, belly=0.70, hip=0.86,
                         thigh=0.48, calf=0.32, upper_arm=0.24, neck=0.31, shoulder_width=0.375),
    "heavy": Measurements(height=1.68, bust=1.10, underbust=1.00, waist=1.00, belly=1.08, hip=1.14,
                          thigh=0.68, calf=0.41, upper_arm=0.34, neck=0.38, shoulder_width=0.42,
                          belly_forward=0.03),
    "apple": Measurements(bust=0.98, underbust=0.92, waist=0.96, belly=1.04, hip=0.96, thigh=0.55,
                          calf=0.36, upper_arm=0.30, neck=0.35, shoulder_width=0.40, belly_forward=0.04),
    "hourglass": Measurements(bust=0.96, underbust=0.76, waist=0.66, belly=0.75, hip=0.99, thigh=0.58,
                              calf=0.35, upper_arm=0.27, shoulder_width=0.385),
}


# Bodies between two presets: every measurement interpolated (name: (preset, preset, share of the
# second)). They are not training bodies of the demo; the garment fit model meets them unseen.
BETWEEN = {
    "pear_heavy": ("pear", "heavy", 0.5),
    "slim_apple": ("slim", "apple", 0.5),
}


def measurements(shape) -> Measurements:
    """A Measurements from a preset or in-between name (``PRESETS``, ``BETWEEN``), a Measurements, or a
    dict of overrides of banana."""
    if isinstance(shape, Measurements):
        return shape
    if isinstance(shape, str):
        if shape in BETWEEN:
            a, b, t = BETWEEN[shape]
            return _interpolate(PRESETS[a], PRESETS[b], t)
        if shape not in PRESETS:
            raise ValueError(f"shape: unknown preset {shape!r}; expected one of {sorted(PRESETS) + sorted(BETWEEN)}")
        return PRESETS[shape]
    if isinstance(shape, dict):
        return replace(PRESETS["banana"], **shape)
    raise ValueError(f"shape: expected a preset name, Measurements or dict, got {type(shape).__name__}")


def _ellipse_perimeter_factor(k):
    """Perimeter of the ellipse with semi-axes (1, k) (Ramanujan's approximation)."""
    return np.pi * (3 * (1 + k) - np.sqrt((3 + k) * (1 + 3 * k)))


def _half_axes(girth, depth_ratio):
    a = girth / _ellipse_perimeter_factor(depth_ratio)
    return a, a * depth_ratio


class Body:
    """The implicit body of one set of measurements.

    Parameters
    ----------
    m : Measurements
    """

    def __init__(self, m: Measurements):
        self.m = m
        H = m.height
        self.H = H
        hip_a, hip_b = _half_axes(m.hip, 0.74 * (0.90 / m.hip) ** 0.6)
        # Torso keyframes: z, half-width, half-depth, centre y (negative = forward).
        rows = [
            (0.455 * H, *_half_axes(0.93 * m.hip, 0.78 * (0.90 / m.hip) ** 0.6), 0.010),
            (0.500 * H, hip_a, hip_b, 0.012),
            (0.575 * H, *_half_axes(m.belly, 0.72), 0.004 - m.belly_forward),
            (0.620 * H, *_half_axes(m.waist, 0.70), 0.0 - 0.4 * m.belly_forward),
            (0.680 * H, *_half_axes(m.underbust, 0.70), -0.004),
            (0.720 * H, *_half_axes(m.bust, 0.76), -0.012),
            (0.765 * H, *_half_axes(0.96 * m.bust, 0.66), 0.0),
            (0.810 * H, 0.5 * m.shoulder_width - 0.045, 0.060, 0.005),
        ]
        self.keys = np.array(rows, float)
        self.torso_round = 0.04

        neck_r = m.neck / (2 * np.pi)
        self.neck = ((0.0, 0.010, 0.79 * H), (0.0, 0.012, 0.885 * H), neck_r * 1.08, neck_r)
        self.head = ((0.0, 0.0, 0.935 * H), (0.072, 0.092, 0.065 * H))
        sx = 0.5 * m.shoulder_width - 0.02
        self.shoulders = ((-sx, 0.006, 0.800 * H), (sx, 0.006, 0.800 * H), 0.062)

        # Arms in A-pose, 48 degrees from vertical.
        ua_r = m.upper_arm / (2 * np.pi)
        ang = np.radians(48.0)
        arm_dir = np.array([np.sin(ang), 0.0, -np.cos(ang)])
        # A full chest pushes the arms out, or the armpit folds onto itself.
        arm_x = max(0.5 * m.shoulder_width - 0.03, _half_axes(0.96 * m.bust, 0.66)[0] - 0.005)
        self.arms = []
        for side in (-1.0, 1.0):
            d = arm_dir * np.array([side, 1.0, 1.0])
            sh = np.array([side * arm_x, 0.008, 0.795 * H])
            el = sh + d * 0.175 * H
            wr = el + d * 0.150 * H
            tip = wr + d * 0.100 * H
            self.arms.append([(sh, el, ua_r * 1.08, 0.036 * ua_r / 0.043),
                              (el, wr, 0.036 * ua_r / 0.043, 0.031),
                              (wr, tip, 0.031, 0.026)])

        # Legs: thighs far enough apart that there is a gap below the crotch.
        th_r = m.thigh / (2 * np.pi)
        calf_r = m.calf / (2 * np.pi)
        hx = max(th_r + 0.014, hip_a - 0.92 * th_r)
        self.legs = []
        for side in (-1.0, 1.0):
            hipj = np.array([side * hx, 0.010, 0.470 * H])
            knee = np.array([side * (hx + 0.020), 0.004, 0.285 * H])
            calf = np.array([side * (hx + 0.028), 0.016, 0.200 * H])
            ankle = np.array([side * (hx + 0.036), 0.020, 0.050 * H])
            heel = np.array([side * (hx + 0.036), 0.030, 0.036])
            toe = np.array([side * (hx + 0.050), -0.150, 0.026])
            self.legs.append([(hipj, knee, th_r, 0.058),
                              (knee, calf, 0.058, calf_r),
                              (calf, ankle, calf_r, 0.034),
                              (heel, toe, 0.036, 0.026)])

    def torso_axes(self, z):
        """Half-width a, half-depth b and centre y of the torso cross-section at heights z (n,)."""
        k = self.keys
        zk = k[:, 0]
        zc = np.clip(z, zk[0], zk[-1])
        seg = np.clip(np.searchsorted(zk, zc) - 1, 0, len(zk) - 2)
        z0, z1 = zk[seg], zk[seg + 1]
        t = (zc - z0) / (z1 - z0)
        out = []
        for col in (1, 2, 3):
            p = k[:, col]
            # Cubic Hermite with finite-difference tangents (Catmull-Rom on uneven knots).
            m_ = np.gradient(p, zk)
            h00 = 2 * t**3 - 3 * t**2 + 1
            h10 = t**3 - 2 * t**2 + t
            h01 = -2 * t**3 + 3 * t**2
            h11 = t**3 - t**2
            dz = z1 - z0
            out.append(h00 * p[seg] + h10 * dz * m_[seg] + h01 * p[seg + 1] + h11 * dz * m_[seg + 1])
        return out

    def torso(self, P):
        a, b, cy = self.torso_axes(P[:, 2])
        r = self.torso_round
        x = P[:, 0]
        y = P[:, 1] - cy
        a, b = a - r, b - r
        q = np.sqrt((x / a) ** 2 + (y / b) ** 2)
        gq = np.sqrt((x / a**2) ** 2 + (y / b**2) ** 2)
        d_plane = (q - 1.0) * q / np.maximum(gq, 1e-9)
        zk = self.keys[:, 0]
        d_z = np.maximum(zk[0] + r - P[:, 2], P[:, 2] - zk[-1] + r)
        outside = np.sqrt(np.maximum(d_plane, 0) ** 2 + np.maximum(d_z, 0) ** 2)
        return outside + np.minimum(np.maximum(d_plane, d_z), 0.0) - r

    def sdf(self, P):
        """Signed distance (approximate away from the surface), negative inside.

        Parameters
        ----------
        P : (n,3) float

        Returns
        -------
        d : (n,) float
        """
        P = np.asarray(P, float)
        core = self.torso(P)
        core = smooth_min(core, round_cone(P, *self.shoulders[:2], self.shoulders[2], self.shoulders[2]),
                          0.03)
        neck = round_cone(P, *self.neck)
        head = ellipsoid(P, *self.head)
        core = smooth_min(core, smooth_min(neck, head, 0.03), 0.03)
        d = core
        for arm in self.arms:
            limb = round_cone(P, *arm[0])
            limb = smooth_min(limb, round_cone(P, *arm[1]), 0.02)
            limb = smooth_min(limb, round_cone(P, *arm[2]), 0.015)
            d = np.minimum(d, smooth_min(core, limb, 0.035))
        for leg in self.legs:
            limb = round_cone(P, *leg[0])
            limb = smooth_min(limb, round_cone(P, *leg[1]), 0.03)
            limb = smooth_min(limb, round_cone(P, *leg[2]), 0.03)
            limb = smooth_min(limb, round_cone(P, *leg[3]), 0.02)
            d = np.minimum(d, smooth_min(core, limb, 0.03))
        return d


def project(f, V, iterations=4):
    """Move points onto the zero level set of f along its gradient (Newton steps).

    Parameters
    ----------
    f : callable (n,3) -> (n,)
    V : (n,3) float

    Returns
    -------
    (n,3) float64
    """
    V = np.array(V, float)
    for _ in range(iterations):
        d = f(V)
        g = gradient(f, V)
        V -= (d / np.maximum(np.sum(g * g, axis=1), 1e-12))[:, None] * g
    return V


def _neighbours(n, F):
    """(n,n) sparse averaging over each vertex's edge neighbours."""
    import scipy.sparse as sp

    from garment_transfer.geometry.penetration import vertex_adjacency

    A = vertex_adjacency(n, F)
    return sp.diags(1.0 / np.asarray(A.sum(axis=1)).ravel()) @ A


def relax(f, V, F, iterations=3, step=0.5):
    """Even out a mesh on the surface f = 0: tangential Laplacian steps, each reprojected.

    Parameters
    ----------
    f : callable
    V : (n,3) float
    F : (m,3) int

    Returns
    -------
    (n,3) float64
    """
    W = _neighbours(V.shape[0], F)
    for _ in range(iterations):
        g = gradient(f, V)
        n = g / np.maximum(np.linalg.norm(g, axis=1), 1e-12)[:, None]
        L = W @ V - V
        L -= np.sum(L * n, axis=1)[:, None] * n
        V = project(f, V + step * L, iterations=2)
    return V


@functools.lru_cache(maxsize=1)
def template():
    """The banana body polygonised once: the topology every mannequin shares.

    Returns
    -------
    V : (n,3) float64
    F : (m,3) int64
        Outward-facing triangles.
    """
    body = Body(PRESETS["banana"])
    V, Q = surface_nets(body.sdf, (-0.75, -0.30, -0.04), (0.75, 0.25, 1.76), TEMPLATE_SPACING)
    # Split each quad along its shorter diagonal once, here, so the triangles never depend on shape.
    d02 = np.linalg.norm(V[Q[:, 0]] - V[Q[:, 2]], axis=1)
    d13 = np.linalg.norm(V[Q[:, 1]] - V[Q[:, 3]], axis=1)
    s = (d02 <= d13)[:, None]
    F = np.concatenate([np.where(s, Q[:, [0, 1, 2]], Q[:, [0, 1, 3]]),
                        np.where(s, Q[:, [0, 2, 3]], Q[:, [1, 2, 3]])]).astype(np.int64)
    V = project(body.sdf, V)
    V = relax(body.sdf, V, F, iterations=10)
    return V, F


def _interpolate(m0: Measurements, m1: Measurements, t: float) -> Measurements:
    a, b = asdict(m0), asdict(m1)
    return Measurements(**{k: (1 - t) * a[k] + t * b[k] for k in a})


def mannequin(shape="banana"):
    """A closed A-pose body of the shared topology.

    Parameters
    ----------
    shape : str, Measurements or dict
        A preset name (see PRESETS), measurements, or overrides of the banana measurements.

    Returns
    -------
    V : (n,3) float64
        Vertices in metres, Z up, feet on z = 0, facing -Y.
    F : (m,3) int64
        Outward-facing triangles, the same for every shape.
    """
    m = measurements(shape)
    V, F = template()
    V = V.copy()
    m0 = PRESETS["banana"]
    if m != m0:
        prev = m0.height
        for step in range(1, MORPH_STEPS + 1):
            body = Body(_interpolate(m0, m, step / MORPH_STEPS))
            # Heights scale about the floor: a good first guess before projecting.
            V[:, 2] *= body.H / prev
            prev = body.H
            V = project(body.sdf, V, iterations=3)
            V = relax(body.sdf, V, F, iterations=1)
    return V, F


def body_sdf(shape="banana"):
    """The signed distance field of a shape's implicit body; its mesh lies on the zero level set.

    Returns
    -------
    callable (n,3) float -> (n,) float
    """
    body = Body(measurements(shape))
    return lambda P: body.sdf(np.asarray(P, float))
