"""Small meshes with known answers, shared by the core tests."""

import numpy as np
import pytest

from garment_transfer.geometry.mesh import mesh_from_polygons
from lab.paths import SHARED_MAKEHUMAN, makehuman_folder

MAKEHUMAN = makehuman_folder() or SHARED_MAKEHUMAN


def require_makehuman():
    """The MakeHuman fixtures folder ($GARMENT_TRANSFER_MAKEHUMAN or ../shared); skips the test where there is none."""
    if not (MAKEHUMAN / "bodies").is_dir():
        pytest.skip(f"MakeHuman fixtures not found at {MAKEHUMAN}")
    return MAKEHUMAN


def icosphere(subdivisions=2, radius=1.0, centre=(0.0, 0.0, 0.0)):
    """A closed, outward-oriented sphere: (V (n,3), F (m,3))."""
    t = (1 + 5 ** 0.5) / 2
    V = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t],
                  [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    F = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                  [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                  [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    for _ in range(subdivisions):
        n = V.shape[0]
        e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(e[:, 0] * n + e[:, 1], return_inverse=True)
        mids = V[uniq // n] + V[uniq % n]
        mids /= np.linalg.norm(mids, axis=1, keepdims=True)
        m = F.shape[0]
        inv = inv.reshape(3, m).T + n
        a, b, c = F.T
        ab, bc, ca = inv.T
        F = np.concatenate([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1),
                            np.stack([ca, bc, c], 1), np.stack([ab, bc, ca], 1)])
        V = np.vstack([V, mids])
    return V * radius + np.asarray(centre), F


def grid(nx=6, ny=5, size=1.0, wave=0.0):
    """A rectangular sheet of quads in the xy plane (optionally with a z wave): a Mesh."""
    x, y = np.meshgrid(np.linspace(0, size, nx), np.linspace(0, size * 0.8, ny))
    z = wave * np.sin(3 * x) * np.cos(2 * y)
    V = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    idx = np.arange(nx * ny).reshape(ny, nx)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], axis=-1).reshape(-1, 4)
    return mesh_from_polygons(V, quads, name="grid")


def random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return q


def arms_down(V, angle=np.radians(40)):
    """MakeHuman (Y up, X lateral) with the arms swung down about the shoulders, blended over the
    shoulder so that the mesh stays in one piece."""
    V = V.copy()
    for side in (1, -1):
        x = side * V[:, 0]
        w = np.clip((x - 1.3) / 0.6, 0, 1) * (V[:, 1] > 0.0)
        a = angle * w
        dx, dy = x - 1.5, V[:, 1] - 4.9
        nx = 1.5 + np.cos(a) * dx + np.sin(a) * dy
        ny = 4.9 - np.sin(a) * dx + np.cos(a) * dy
        V[:, 0] = np.where(w > 0, side * nx, V[:, 0])
        V[:, 1] = np.where(w > 0, ny, V[:, 1])
    return V


def in_pieces(V, F):
    """A mesh cut into two pieces at x = 0, as a pattern's pieces (or a split along UV seams) come out of other
    tools: each vertex the two pieces share is written again, after the others, for the triangles with x > 0.

    Returns
    -------
    V2 : (n+k,3) float, F2 : (m,3) int
        The pieces: ``V2[:n] == V``, the last k the copies.
    seam : (k,) int
        The shared vertices.
    twin : (k,) int
        Each one's copy.
    """
    F = np.array(F, dtype=np.int64)
    right = np.asarray(V)[F].mean(axis=1)[:, 0] > 0
    seam = np.intersect1d(np.unique(F[right]), np.unique(F[~right]))
    copy = np.full(len(V), -1)
    copy[seam] = len(V) + np.arange(seam.size)
    F[right] = np.where(copy[F[right]] >= 0, copy[F[right]], F[right])
    return np.vstack([V, np.asarray(V)[seam]]), F, seam, copy[seam]


def catmull_clark(mesh):
    """One step of Catmull-Clark subdivision of a core Mesh (each polygon into quads around its centre; the
    corners, sides and centres placed by the scheme's rules, a side on the border at its middle and a border
    corner kept where it is), as Blender's Subdivision Surface makes it, to be read back as a new Mesh."""
    from garment_transfer.geometry.mesh import mesh_from_polygon_arrays

    V, fv, fs = mesh.V, mesh.face_vertices, mesh.face_start
    n, sizes = V.shape[0], np.diff(fs)
    p = sizes.shape[0]
    face = np.repeat(np.arange(p), sizes)
    centre = np.zeros((p, 3))
    np.add.at(centre, face, V[fv])
    centre /= sizes[:, None]
    nxt = np.arange(fv.shape[0]) + 1
    nxt[fs[1:] - 1] = fs[:-1]
    u, v = fv, fv[nxt]
    key = np.minimum(u, v) * n + np.maximum(u, v)
    sides, side_of, uses = np.unique(key, return_inverse=True, return_counts=True)
    a, b = sides // n, sides % n
    face_sum = np.zeros((sides.shape[0], 3))
    np.add.at(face_sum, side_of, centre[face])
    border = uses == 1
    side_point = np.where(border[:, None], 0.5 * (V[a] + V[b]), (V[a] + V[b] + face_sum) / (2 + uses[:, None]))
    # Corners: (Q + 2R + (k - 3)P) / k, Q the mean of the centres around, R of the sides' middles, k the valence.
    k = np.bincount(np.r_[a, b], minlength=n).astype(float)
    R = np.zeros((n, 3))
    np.add.at(R, np.r_[a, b], np.r_[0.5 * (V[a] + V[b]), 0.5 * (V[a] + V[b])])
    Q = np.zeros((n, 3))
    np.add.at(Q, fv, centre[face])
    faces_at = np.bincount(fv, minlength=n)[:, None]
    on_border = np.zeros(n, dtype=bool)
    on_border[np.r_[a[border], b[border]]] = True
    corner = (Q / faces_at + 2 * R / k[:, None] + (k[:, None] - 3) * V) / k[:, None]
    corner[on_border] = V[on_border]
    W = np.vstack([corner, side_point, centre])
    prev = np.arange(fv.shape[0]) - 1
    prev[fs[:-1]] = fs[1:] - 1
    quads = np.stack([fv, n + side_of, n + sides.shape[0] + face, n + side_of[prev]], axis=1)
    return mesh_from_polygon_arrays(W, quads.ravel(), np.arange(0, 4 * quads.shape[0] + 1, 4),
                                    name=f"{mesh.name} subdivided")
