"""Closest points and signed distance against brute force over all triangles.

The reference distance below is computed independently of ``closest_on_triangles``: the distance to
the triangle's plane where the projection falls inside it, otherwise the nearest of its three edges.
"""

import numpy as np
import pytest
from meshes import MAKEHUMAN, grid, icosphere, random_rotation, require_makehuman

import garment_transfer.geometry.penetration as penetration
import garment_transfer.geometry.proximity as proximity
from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.proximity import TriangleSurface

REL = 1e-12


def _segment_distance(P, A, B):
    ab = B - A
    ll = np.einsum("...j,...j->...", ab, ab)
    t = np.clip(np.einsum("...j,...j->...", P - A, ab) / np.where(ll > 0, ll, 1.0), 0.0, 1.0)
    return np.linalg.norm(P - (A + t[..., None] * ab), axis=-1)


def reference_distances(P, V, F):
    """(p,m) distances from every point to every triangle, without the code under test."""
    A, B, C = (V[F[:, k]][None] for k in range(3))
    P = P[:, None]
    e1, e2 = B - A, C - A
    n = np.cross(e1, e2)
    nn = np.einsum("...j,...j->...", n, n)
    # Barycentric coordinates of the projection (Cramer's rule on the 2x2 normal equations).
    w = P - A
    a, b, c = (np.einsum("...j,...j->...", x, y) for x, y in ((e1, e1), (e1, e2), (e2, e2)))
    d, e = np.einsum("...j,...j->...", w, e1), np.einsum("...j,...j->...", w, e2)
    det = a * c - b * b
    ok = det > 0
    det = np.where(ok, det, 1.0)
    s, t = (c * d - b * e) / det, (a * e - b * d) / det
    inside = ok & (s >= 0) & (t >= 0) & (s + t <= 1)
    plane = np.abs(np.einsum("...j,...j->...", w, n)) / np.sqrt(np.where(nn > 0, nn, 1.0))
    edges = np.minimum(np.minimum(_segment_distance(P, A, B), _segment_distance(P, B, C)),
                       _segment_distance(P, C, A))
    return np.where(inside, np.minimum(plane, edges), edges)


def brute_force(P, V, F, chunk=16):
    return np.concatenate([reference_distances(P[i:i + chunk], V, F).min(axis=1)
                           for i in range(0, P.shape[0], chunk)])


def assert_exact(P, V, F, scale=1.0):
    """Every answer of TriangleSurface.closest is the brute-force distance and a consistent point."""
    closest, dist, tri, bary = TriangleSurface(V, F).closest(P)
    ref = brute_force(P, V, F)
    floor = REL * scale     # points on the surface: relative to the mesh size
    np.testing.assert_array_less(np.abs(dist - ref), REL * ref + floor)
    np.testing.assert_allclose(np.linalg.norm(P - closest, axis=1), dist, rtol=1e-14, atol=floor)
    # The barycentric coordinates put the point on the returned triangle.
    assert (bary >= 0).all()
    np.testing.assert_allclose(bary.sum(axis=1), 1.0, atol=1e-14)
    np.testing.assert_allclose(np.einsum("pk,pkj->pj", bary, V[F[tri]]), closest, atol=floor)
    return closest, dist, tri, bary


def test_makehuman_body_points_near_far_and_inside():
    root = require_makehuman()
    body = read_obj(root / "bodies" / "female_average.obj")
    garment = read_obj(root / "garments" / "female_casualsuit02" / "female_average.obj")
    rng = np.random.default_rng(0)
    V, F = body.V, body.F
    scale = float(np.ptp(V, axis=0).max())
    pick = rng.choice(garment.n_vertices, 300, replace=False)
    P = np.vstack([
        garment.V[pick],                                                  # where the garment is
        garment.V[pick[:100]] + rng.normal(scale=0.05 * scale, size=(100, 3)),
        V[rng.choice(body.n_vertices, 50)] + rng.normal(scale=1e-3, size=(50, 3)),   # on the skin
        V.mean(axis=0) + rng.normal(scale=0.1 * scale, size=(50, 3)),    # inside and around the trunk
    ])
    assert_exact(P, V, F, scale)


def test_points_on_vertices_and_edges():
    V, F = icosphere(2)
    rng = np.random.default_rng(1)
    e = F[:, [0, 1]]
    t = rng.uniform(size=(e.shape[0], 1))
    on_edges = V[e[:, 0]] * (1 - t) + V[e[:, 1]] * t
    P = np.vstack([V, on_edges, 0.5 * (V[F[:, 1]] + V[F[:, 2]]), V * 1.3, V * 0.7])
    closest, dist, tri, bary = assert_exact(P, V, F)
    n = V.shape[0]
    np.testing.assert_array_equal(dist[:n], 0.0)
    # On a vertex: a corner of the triangle, with exact one-hot coordinates.
    np.testing.assert_array_equal(np.sort(bary[:n], axis=1), np.tile([0.0, 0.0, 1.0], (n, 1)))
    np.testing.assert_array_equal(V[F[tri[:n]]][np.arange(n), np.argmax(bary[:n], axis=1)], V)
    # Radially out from a vertex of a convex mesh the closest point is that vertex.
    np.testing.assert_allclose(closest[-2 * n:-n], V, atol=1e-15)


def test_points_equidistant_from_two_triangles():
    # Two parallel triangles at z = +-1 (one above the other) and points on the plane between them;
    # a dihedral pair with points on its bisector.
    V = np.array([[0, 0, -1], [1, 0, -1], [0, 1, -1], [0, 0, 1], [1, 0, 1], [0, 1, 1],
                  [5, 0, 0], [6, 0, 0], [5, 1, 0], [5, 0, 1]], float)
    F = np.array([[0, 1, 2], [3, 5, 4], [6, 8, 7], [6, 9, 8]])
    rng = np.random.default_rng(2)
    st = rng.uniform(size=(200, 2))
    st = st[st.sum(axis=1) < 1]
    between = np.column_stack([st, np.zeros(st.shape[0])])
    u = rng.uniform(0.05, 0.9, size=100)
    bisector = np.column_stack([5 + 0.1 * u, u, -0.3 * np.ones(100)])
    _, dist, tri, _ = assert_exact(np.vstack([between, bisector]), V, F)
    np.testing.assert_allclose(dist[:st.shape[0]], 1.0, rtol=1e-15)
    assert set(tri[:st.shape[0]]) <= {0, 1}


def test_far_points_and_a_thin_part():
    # A closed thin slab (0.01 x 1 x 1e-5): points inside it, just off it, and very far away.
    x = np.array([0.0, 0.01])
    y = np.array([0.0, 1.0])
    z = np.array([0.0, 1e-5])
    corners = np.array([[a, b, c] for a in x for b in y for c in z])
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    F = np.array([[q[0], q[1], q[2]] for q in quads] + [[q[0], q[2], q[3]] for q in quads])
    rng = np.random.default_rng(3)
    inside = rng.uniform([0, 0, 0], [0.01, 1, 1e-5], size=(200, 3))
    near = inside + rng.normal(scale=1e-5, size=inside.shape)
    far = rng.normal(scale=1e6, size=(50, 3))
    assert_exact(np.vstack([inside, near, far]), corners, F)


def test_flat_triangles_are_segments():
    V = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 0, 1], [0, 1, 1], [1, 0, 1]], float)
    F = np.array([[0, 1, 2], [3, 4, 5]])     # a zero-area triangle along the x axis
    rng = np.random.default_rng(4)
    P = rng.uniform(-1, 3, size=(300, 3)) * [1, 1, 0.3]
    assert_exact(P, V, F)


def test_same_triangles_in_a_moved_and_rotated_frame():
    V, F = icosphere(2)
    rng = np.random.default_rng(5)
    P = np.vstack([V * 1.2, rng.normal(size=(500, 3))])   # vertex regions: many tied triangles
    R, t = random_rotation(rng), np.array([3.0, -2.0, 0.5])
    a = TriangleSurface(V, F).closest(P)
    b = TriangleSurface(V @ R.T + t, F).closest(P @ R.T + t)
    np.testing.assert_array_equal(a[2], b[2])
    np.testing.assert_allclose(b[0], a[0] @ R.T + t, atol=1e-12)


def convex_inside(P, V, F):
    """Inside a closed convex mesh: behind every face plane."""
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    return (np.einsum("pmj,mj->pm", P[:, None] - V[F[:, 0]][None], n) < 0).all(axis=1)


def sphere_points(V, rng, count=1500):
    D = rng.normal(size=(count, 3))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    r = rng.uniform(0.2, 1.8, size=count)
    # Along vertex and edge directions too, just inside and outside: the pseudonormal cases.
    F_dirs = np.vstack([V, 0.5 * (V + np.roll(V, 1, axis=0))])
    length = np.linalg.norm(F_dirs, axis=1, keepdims=True)
    F_dirs = F_dirs[length[:, 0] > 0.1] / length[length[:, 0] > 0.1]
    return np.vstack([D * r[:, None], F_dirs * 0.99, F_dirs * 1.01])


def test_signed_distance_sign_on_a_closed_sphere():
    V, F = icosphere(3)
    s = TriangleSurface(V, F)
    P = sphere_points(V, np.random.default_rng(6))
    sd, closest, normal, tri = s.signed_distance(P)
    inside = convex_inside(P, V, F)
    exact = np.abs(sd) > 1e-12
    np.testing.assert_array_equal((sd < 0)[exact], inside[exact])
    np.testing.assert_allclose(np.abs(sd), brute_force(P, V, F), rtol=REL, atol=REL)
    # Limited to a band: the same answer inside it, the right side (and infinity) beyond.
    band = 0.1
    sdb, closest_b, _, tri_b = s.signed_distance(P, within=band)
    near = np.abs(sd) < band * (1 - 1e-9)
    np.testing.assert_array_equal(sdb[near], sd[near])
    np.testing.assert_array_equal(tri_b[near], tri[near])
    far = np.abs(sd) > band * (1 + 1e-9)
    assert np.isinf(sdb[far]).all() and (tri_b[far] == -1).all() and np.isnan(closest_b[far]).all()
    np.testing.assert_array_equal(sdb[far] < 0, inside[far])


def test_signed_distance_sign_on_an_open_sphere():
    # A sphere with its cap cut off (a neck hole): points whose closest point is away from the rim
    # keep their side, beyond the band as well (the winding number is robust to the hole).
    V, F = icosphere(3)
    keep = V[F].mean(axis=1)[:, 2] < 0.8
    Fo = F[keep]
    rim = np.zeros(V.shape[0], bool)
    e = np.sort(np.concatenate([Fo[:, [0, 1]], Fo[:, [1, 2]], Fo[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    rim[uniq[count == 1].reshape(-1)] = True
    s = TriangleSurface(V, Fo)
    P = sphere_points(V, np.random.default_rng(7))
    P = P[P[:, 2] < 0.6]
    sd, _, _, tri = s.signed_distance(P)
    inside = convex_inside(P, V, F)
    clear = ~rim[Fo[tri]].any(axis=1) & (np.abs(sd) > 1e-12)
    assert clear.sum() > 1000
    np.testing.assert_array_equal((sd < 0)[clear], inside[clear])
    sdb = s.signed_distance(P, within=0.05)[0]
    far = np.isinf(sdb)
    assert far.sum() > 500
    np.testing.assert_array_equal(sdb[far] < 0, inside[far])


def test_side_of_a_few_far_points_equals_the_winding_number():
    # The vote for far groups takes the pseudonormal at the exact closest point, and the winding
    # number where the closest triangle touches an open rim: on a closed sphere, an open one (points
    # near the hole included) and the MakeHuman body, it must agree with the
    # winding number at every point off the surface.
    rng = np.random.default_rng(3)
    V, F = icosphere(3)
    cases = [(V, F), (V, F[V[F].mean(axis=1)[:, 2] < 0.8])]
    if (MAKEHUMAN / "bodies").is_dir():
        body = read_obj(MAKEHUMAN / "bodies" / "female_average.obj")
        cases.append((body.V, body.F))
    for k, (V, F) in enumerate(cases):
        scale = float(np.ptp(V, axis=0).max())
        P = np.vstack([V.mean(axis=0) + rng.normal(scale=0.4 * scale, size=(600, 3)),
                       V[rng.choice(V.shape[0], 400)] + rng.normal(scale=0.02 * scale, size=(400, 3))])
        s = TriangleSurface(V, F)
        P = P[np.abs(s.signed_distance(P)[0]) > 1e-6 * scale]
        few = s._inside_few(P)
        np.testing.assert_array_equal(few, s.inside(P))
        assert 0 < few.sum() < few.size
        assert s.topology.rim.any() == (k == 1)     # the MakeHuman body is closed


@pytest.mark.parametrize("bounded_min", [0, 10**9])
def test_fix_penetration_finds_vertices_deep_inside(monkeypatch, bounded_min):
    # A sheet through the middle of the sphere: most of its inside part is much deeper than the
    # band, where the bounded search does not measure; the fix must still push all of it out.
    monkeypatch.setattr(penetration, "BOUNDED_MIN", bounded_min)
    body_V, body_F = icosphere(3)
    sheet = grid(40, 40, size=3.0, wave=0.02)
    V = sheet.V - [1.5, 1.2, 0.0]
    surface = TriangleSurface(body_V, body_F)
    assert (surface.signed_distance(V)[0] < -0.5).sum() > 50
    out, info = penetration.fix_penetration(V, sheet.F, surface, offset=0.01)
    sd = surface.signed_distance(out)[0]
    assert info["inside_after"] == 0 and (sd < 0).sum() == 0
    assert info["inside_before"] == (surface.signed_distance(V)[0] < 0).sum()


def test_fix_penetration_same_with_and_without_the_bounded_search(monkeypatch):
    body_V, body_F = icosphere(3)
    sheet = grid(30, 30, size=1.2, wave=0.03)
    V = sheet.V - [0.6, 0.48, 0.0] + [0, 0, 0.9]
    surface = TriangleSurface(body_V, body_F)
    outs = []
    for bounded_min in (0, 10**9):
        monkeypatch.setattr(penetration, "BOUNDED_MIN", bounded_min)
        outs.append(penetration.fix_penetration(V, sheet.F, surface, offset=0.01))
    np.testing.assert_allclose(outs[0][0], outs[1][0], atol=1e-12)
    assert outs[0][1] == outs[1][1]


def test_far_sides_by_groups_equal_the_winding_number_of_each_point():
    # A wavy sheet through the sphere: far parts inside and outside, joined through the band.
    body_V, body_F = icosphere(3)
    sheet = grid(60, 60, size=3.0, wave=0.05)
    V = sheet.V - [1.5, 1.2, 0.1]
    A = penetration.vertex_adjacency(V.shape[0], sheet.F)
    s = TriangleSurface(body_V, body_F)
    each = s.signed_distance(V, within=0.05)[0]
    grouped = s.signed_distance(V, within=0.05, graph=A)[0]
    assert (each == -np.inf).sum() > 100 and (each == np.inf).sum() > 100
    np.testing.assert_array_equal(grouped, each)
    np.testing.assert_array_equal(np.isneginf(each), convex_inside(V, body_V, body_F) & np.isinf(each))
    out, info = penetration.fix_penetration(V, sheet.F, s, offset=0.01, adjacency=A)
    assert info["inside_after"] == 0 and (s.signed_distance(out)[0] < 0).sum() == 0


def test_large_queries_split_over_threads_give_the_one_piece_answer(monkeypatch):
    """Huge meshes: the per-point work runs in pieces on threads; the pieces give exactly the answer
    of one piece, and every array is one row per point (memory linear in the points)."""
    import garment_transfer.geometry.proximity as proximity

    V, F = icosphere(3)
    P = np.random.default_rng(3).normal(size=(5000, 3)) * 1.3
    surface = TriangleSurface(V, F)
    monkeypatch.setattr(proximity, "THREADS", 1)
    one = surface.signed_distance(P)
    monkeypatch.setattr(proximity, "THREADS", 3)
    monkeypatch.setattr(proximity, "THREAD_MIN", 100)
    pieces = surface.signed_distance(P)
    for a, b in zip(one, pieces):
        assert a.shape[0] == P.shape[0]
        assert np.array_equal(a, b)


def test_fix_penetration_measures_again_only_what_may_have_come_too_close(monkeypatch):
    # A vertex that moved less than its clearance beyond the offset is not measured again; measuring
    # every moved vertex gives exactly the same garment.
    body_V, body_F = icosphere(3)
    sheet = grid(40, 40, size=1.6, wave=0.03)
    V = sheet.V - [0.8, 0.64, 0.0] + [0, 0, 0.9]
    surface = TriangleSurface(body_V, body_F)
    measured = []
    near = penetration.signed_distance_near

    def counting(s, P, band, graph=None):
        measured.append(P.shape[0])
        return near(s, P, band, graph)

    monkeypatch.setattr(penetration, "signed_distance_near", counting)
    out, info = penetration.fix_penetration(V, sheet.F, surface, offset=0.01)
    fewer = list(measured)
    measured.clear()
    monkeypatch.setattr(penetration, "_still_clear", lambda low, offset, band: np.zeros(low.shape, bool))
    out_all, info_all = penetration.fix_penetration(V, sheet.F, surface, offset=0.01)
    np.testing.assert_array_equal(out, out_all)
    assert info == info_all and info["pushed_vertices"] > 20
    assert sum(fewer[1:]) < sum(measured[1:])


def test_fix_penetration_stops_spreading_pushes_of_rounding_size(monkeypatch):
    # Once every push left is within SETTLED of the offset, the final projection comes at once:
    # the garment differs from the one of all rounds by less than that share of the offset.
    body_V, body_F = icosphere(3)
    sheet = grid(40, 40, size=1.6, wave=0.03)
    V = sheet.V - [0.8, 0.64, 0.0] + [0, 0, 0.9]
    surface = TriangleSurface(body_V, body_F)
    offset = 0.01
    out, info = penetration.fix_penetration(V, sheet.F, surface, offset=offset, rounds=8)
    settled = penetration.SETTLED
    monkeypatch.setattr(penetration, "SETTLED", 0.0)
    out_all, info_all = penetration.fix_penetration(V, sheet.F, surface, offset=offset, rounds=8)
    assert info["rounds"] < info_all["rounds"]
    np.testing.assert_allclose(out, out_all, rtol=0, atol=8 * settled * offset)
    assert info["inside_after"] == info_all["inside_after"] == 0
    assert surface.signed_distance(out)[0].min() > offset * (1 - 1e-6)


def _near_pairs_cases():
    rng = np.random.default_rng(11)
    V, F = icosphere(3)
    # Points on vertices, on edges, just inside and outside, far away, in a cloud around.
    edges = 0.5 * (V[F[:, 0]] + V[F[:, 1]])
    P = np.vstack([V, edges, V * 0.97, V * 1.03, rng.normal(size=(300, 3)) * 3.0,
                   rng.normal(size=(300, 3)) * 0.6])
    cases = [(P, V, F, 0.05)]
    # A thin part: two close parallel sheets, points between and beside them.
    sheet = grid(12, 12, size=1.0)
    Vt = np.vstack([sheet.V, sheet.V + [0, 0, 0.002]])
    Ft = np.vstack([sheet.F, sheet.F + sheet.V.shape[0]])
    Pt = np.vstack([sheet.V + [0, 0, 0.001], rng.uniform(-0.2, 1.2, size=(400, 3)) * [1, 1, 0.05]])
    cases.append((Pt, Vt, Ft, 0.01))
    if (MAKEHUMAN / "bodies").is_dir():
        body = read_obj(MAKEHUMAN / "bodies" / "female_average.obj")
        pick = rng.choice(body.V.shape[0], 600, replace=False)
        Pm = np.vstack([body.V[pick] + rng.normal(scale=0.3, size=(600, 3)),
                        body.V.mean(axis=0) + rng.normal(scale=4.0, size=(300, 3))])
        cases.append((Pm, body.V, body.F, 0.2))
    return cases


def test_near_boxes_keep_every_triangle_and_point_closer_than_the_band(near_pairs_with_brute_force):
    from garment_transfer.geometry.proximity import near_boxes

    for P, V, F, within, ref, close_faces in near_pairs_with_brute_force:
        faces, points = near_boxes(P, V, F, within)
        close = ref < within
        assert close.any() and not close.all()
        np.testing.assert_array_equal(np.setdiff1d(np.flatnonzero(close_faces), faces), [])
        np.testing.assert_array_equal(np.setdiff1d(np.flatnonzero(close), points), [])
        # It rules out most of the rest: far points are not kept.
        assert points.size < P.shape[0]


@pytest.fixture(scope="module")
def near_pairs_with_brute_force():
    """``_near_pairs_cases`` with each one's brute-force distances (the slow part, made once): every point's
    distance to the surface, and which triangles some point is closer to than the band."""
    out = []
    for P, V, F, within in _near_pairs_cases():
        ref, close_faces = np.empty(P.shape[0]), np.zeros(F.shape[0], bool)
        for i in range(0, P.shape[0], 64):
            D = reference_distances(P[i:i + 64], V, F)
            ref[i:i + 64] = D.min(axis=1)
            close_faces |= (D < within).any(axis=0)
        out.append((P, V, F, within, ref, close_faces))
    return out


@pytest.mark.parametrize("full_share", [0.0, 2.0], ids=["the surface's tree", "a tree of the near triangles"])
def test_bounded_closest_points_equal_the_unbounded_ones_and_brute_force(monkeypatch, full_share,
                                                                         near_pairs_with_brute_force):
    # Either way a bounded search goes (most points near: the surface's own tree; else one of the near triangles).
    monkeypatch.setattr(proximity, "FULL_SEARCH_SHARE", full_share)
    for P, V, F, within, ref, _ in near_pairs_with_brute_force:
        s = TriangleSurface(V, F)
        bounded = s.closest(P, within=within)
        full = s.closest(P)
        near = ref < within * (1 - 1e-9)
        far = ref > within * (1 + 1e-9)
        assert near.sum() > 10 and far.sum() > 10
        for a, b in zip(bounded, full):
            np.testing.assert_array_equal(a[near], b[near])
        scale = float(np.ptp(V, axis=0).max())
        np.testing.assert_array_less(np.abs(bounded[1][near] - ref[near]), REL * ref[near] + REL * scale)
        assert np.isinf(bounded[1][far]).all() and (bounded[2][far] == -1).all()


def test_normals_of_a_few_vertices_equal_those_of_all():
    # A query computes the pseudonormals of only the vertices its closest points lie on; they equal
    # the ones computed for every vertex (open rims, a flat triangle and a real body included).
    V, F = icosphere(3)
    open_F = F[V[F].mean(axis=1)[:, 2] < 0.8]
    flat_V = np.vstack([V, V[F[0, 0]] + 1e-9 * (V[F[0, 1]] - V[F[0, 0]])])
    flat_F = np.vstack([F, [[F[0, 0], F[0, 1], V.shape[0]]]])
    cases = [(V, F), (V, open_F), (flat_V, flat_F)]
    if (MAKEHUMAN / "bodies").is_dir():
        body = read_obj(MAKEHUMAN / "bodies" / "female_average.obj")
        cases.append((body.V, body.F))
    for V_, F_ in cases:
        every = TriangleSurface(V_, F_).vertex_normals
        some = np.random.default_rng(1).choice(V_.shape[0], 200, replace=False)
        few = TriangleSurface(V_, F_)._vertex_normals_of(some)
        np.testing.assert_allclose(few, every[some], rtol=0, atol=1e-15)
        used = np.isin(some, F_)
        assert used.sum() > 50
        np.testing.assert_allclose(np.linalg.norm(few[used], axis=1), 1.0)
        assert not few[~used].any()
