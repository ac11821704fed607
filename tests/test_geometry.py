import numpy as np
from meshes import grid, icosphere, require_makehuman

from garment_transfer.geometry.binding import bind, carry
from garment_transfer.geometry.embedding import body_to_cloth, cloth_to_body, embed, unembed
from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.penetration import fix_penetration, penetration
from garment_transfer.geometry.proximity import TriangleSurface, closest_on_triangles
from garment_transfer.pipeline.metrics import discrete_curvature, mdc, per_vertex_change, surface_distance


def brute_force_distance(P, V, F):
    out = np.empty(P.shape[0])
    for i, p in enumerate(P):
        Q, _ = closest_on_triangles(np.repeat(p[None], F.shape[0], 0), V[F[:, 0]], V[F[:, 1]], V[F[:, 2]])
        out[i] = np.linalg.norm(Q - p, axis=1).min()
    return out


def test_closest_point_regions_of_one_triangle():
    A, B, C = np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    P = np.array([[0.2, 0.2, 1.0], [-1, -1, 0], [2, -0.5, 0], [0.5, 0.5, 0.5], [-1, 0.5, 0]])
    Q, bary = closest_on_triangles(P, *[np.repeat(x[None], 5, 0) for x in (A, B, C)])
    np.testing.assert_allclose(Q, [[0.2, 0.2, 0], [0, 0, 0], [1, 0, 0], [0.5, 0.5, 0], [0, 0.5, 0]])
    np.testing.assert_allclose(bary.sum(axis=1), 1.0)


def test_closest_matches_brute_force_on_the_makehuman_body():
    root = require_makehuman()
    body = read_obj(root / "bodies" / "female_average.obj")
    garment = read_obj(root / "garments" / "female_casualsuit02" / "female_average.obj")
    rng = np.random.default_rng(0)
    P = garment.V[::7] + rng.normal(scale=0.2, size=garment.V[::7].shape)
    _, d, _, _ = TriangleSurface(body.V, body.F).closest(P)
    np.testing.assert_allclose(d, brute_force_distance(P, body.V, body.F), atol=1e-12)


def test_signed_distance_on_a_closed_sphere():
    V, F = icosphere(3)
    s = TriangleSurface(V, F)
    rng = np.random.default_rng(1)
    D = rng.normal(size=(500, 3))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    r = rng.uniform(0.2, 1.8, size=500)
    sd = s.signed_distance(D * r[:, None])[0]
    far = np.abs(r - 1) > 0.02   # the polyhedron is within 1.2% of the sphere
    assert np.array_equal(sd[far] < 0, r[far] < 1)


def test_penetration_counted_on_closed_and_open_bodies():
    V, F = icosphere(3)
    P = np.array([[0, 0, 0.5], [0, 0.3, 0.2], [0, 0, 1.5], [2, 0, 0], [0.9, 0, 0]])
    ratio, depth, inside = penetration(P, TriangleSurface(V, F))
    assert inside.tolist() == [True, True, False, False, True]
    assert abs(ratio - 0.6) < 1e-12
    assert abs(depth - (1 - np.sqrt(0.13))) < 0.01   # the point at (0, 0.3, 0.2)
    # Open the sphere at the top (a neck hole): points near the rest of the surface keep their side.
    keep = V[F].mean(axis=1)[:, 2] < 0.8
    ratio_open, _, inside_open = penetration(P, TriangleSurface(V, F[keep]))
    assert inside_open.tolist() == [True, True, False, False, True]


def test_fix_penetration_leaves_nothing_inside_and_keeps_folds():
    body_V, body_F = icosphere(3)
    sheet = grid(30, 30, size=1.2, wave=0.03)
    V = sheet.V - [0.6, 0.48, 0.0] + [0, 0, 0.9]    # a wavy sheet cutting through the sphere's cap
    surface = TriangleSurface(body_V, body_F)
    assert (surface.signed_distance(V)[0] < 0).sum() > 20
    out, info = fix_penetration(V, sheet.F, surface, offset=0.01)
    sd = surface.signed_distance(out)[0]
    assert info["inside_after"] == 0 and (sd < 0).sum() == 0
    assert sd.min() > 0.0099 - 1e-9
    # Vertices far from the sphere do not move.
    far = np.linalg.norm(V, axis=1) > 1.4
    np.testing.assert_allclose(out[far], V[far], atol=1e-9)


def test_mdc_of_a_mesh_with_itself_is_zero_and_a_hinge_is_hand_computed():
    sheet = grid(5, 5, wave=0.1)
    assert mdc(sheet.V, sheet.V, sheet.F) == 0.0
    # Two triangles sharing edge (0,1); folding the second by 90 degrees.
    V = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0]], float)
    F = np.array([[0, 1, 2], [1, 0, 3]])
    W = V.copy()
    W[3] = [0.5, 0, -1]
    # Flat: r = 1 at all four vertices. Folded: n1 = (0,0,1), n2 = (0,1,0) at 0 and 1 -> r = 0.
    np.testing.assert_allclose(discrete_curvature(V, F), [1, 1, 1, 1])
    np.testing.assert_allclose(discrete_curvature(W, F), [0, 0, 1, 1], atol=1e-12)
    assert abs(mdc(V, W, F) - 0.5) < 1e-12


def test_surface_distance_and_change():
    V, F = icosphere(2)
    assert surface_distance(V, F, V, F) == 0.0
    d = surface_distance(V * 1.1, F, V, F)
    assert 0.09 < d < 0.11
    np.testing.assert_allclose(per_vertex_change(V, V + [0, 0, 2]), 2.0)


def test_embedding_round_trip_of_a_constant_field():
    body_V, body_F = icosphere(2)
    cloth_V, cloth_F = icosphere(3, radius=1.05)
    index, covered = body_to_cloth(body_V, body_F, cloth_V, cloth_F)
    assert index.shape == (body_F.shape[0],) and covered.all()
    C = np.broadcast_to(np.diag([1.0, 2.0, 3.0]), (cloth_F.shape[0], 3, 3))
    B = embed(C, index)
    for k in (1, 4):
        idx, w = cloth_to_body(body_V, body_F, cloth_V, cloth_F, k=k)
        assert idx.shape == (cloth_F.shape[0], k)
        np.testing.assert_allclose(w.sum(axis=1), 1.0)
        np.testing.assert_allclose(unembed(B, idx, w), C)


def test_coverage_mask_marks_far_body_triangles():
    body_V, body_F = icosphere(2)
    cloth = grid(6, 6, size=0.5)
    cloth_V = cloth.V - [0.25, 0.2, 0] + [0, 0, 1.02]    # a patch over the north pole
    _, covered = body_to_cloth(body_V, body_F, cloth_V, cloth.F)
    north = body_V[body_F].mean(axis=1)[:, 2]
    assert covered[north > 0.97].all()
    assert not covered[north < 0].any()


def test_binding_carries_points_exactly_under_a_similarity():
    V, F = icosphere(2)
    rng = np.random.default_rng(4)
    P = rng.normal(size=(50, 3))
    P = P / np.linalg.norm(P, axis=1, keepdims=True) * 1.1
    b = bind(P, V, F)
    np.testing.assert_allclose(carry(b, V, F), P, atol=1e-12)
    np.testing.assert_allclose(carry(b, 2.0 * V + 1.0, F), 2.0 * P + 1.0, atol=1e-12)


def test_carry_is_the_offset_in_the_frame_of_the_triangle_on_any_shape():
    # The carried point is, by definition, the surface point plus the offset in the triangle's frame
    # [e1 e2 n] with n = e1 x e2 / sqrt|e1 x e2|; on a shape that is not affine, for more points than
    # triangles and for fewer, and again with the binding's kept matrix.
    from garment_transfer.geometry.gradients import triangle_frames

    V, F = icosphere(2)
    rng = np.random.default_rng(5)
    W = V * [1.0, 0.7, 1.3] + 0.2 * np.sin(3.0 * V[:, [1, 2, 0]])
    for count in (F.shape[0] * 3, 40):
        P = rng.normal(size=(count, 3)) * 0.8
        b = bind(P, V, F)
        tris = F[b.triangle]
        Y, _ = triangle_frames(W, tris)
        ref = np.einsum("pk,pkj->pj", b.bary, W[tris]) + np.einsum("pij,pj->pi", Y, b.local)
        for _ in range(2):
            np.testing.assert_allclose(carry(b, W, F), ref, rtol=0, atol=1e-13)


def test_closest_on_threads_equals_one_piece(monkeypatch):
    import garment_transfer.geometry.proximity as proximity

    V, F = icosphere(2)
    P = np.random.default_rng(5).normal(size=(1000, 3))
    monkeypatch.setattr(proximity, "THREAD_MIN", 10**9)
    whole = TriangleSurface(V, F).closest(P)
    monkeypatch.setattr(proximity, "THREAD_MIN", 128)
    monkeypatch.setattr(proximity, "THREADS", 3)
    parts = TriangleSurface(V, F).closest(P)
    for a, b in zip(whole, parts):
        np.testing.assert_array_equal(a, b)


def test_edge_length_and_degenerate_equal_the_separate_functions():
    from garment_transfer.geometry.mesh import degenerate_triangles, edge_length_and_degenerate, edge_lengths_mean

    rng = np.random.default_rng(4)
    V = rng.normal(size=(300, 3))
    F = rng.integers(0, 300, size=(900, 3))
    F[:40, 2] = F[:40, 1]                                  # zero area
    V[F[40:60, 2]] = 0.5 * (V[F[40:60, 0]] + V[F[40:60, 1]])  # collinear corners
    h, degenerate = edge_length_and_degenerate(V, F)
    assert h == edge_lengths_mean(V, F)
    np.testing.assert_array_equal(degenerate, degenerate_triangles(V, F))
    assert degenerate[:40].all() and degenerate.sum() >= 40
    h0, none = edge_length_and_degenerate(V, F[:0])
    assert h0 == 0.0 and none.shape == (0,)


def test_cross_rows_is_numpys_cross_bit_for_bit():
    from garment_transfer.geometry.mesh import cross_rows

    rng = np.random.default_rng(7)
    for n in (0, 1, 1000):
        a = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-8, 8, size=(n, 1))
        b = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-8, 8, size=(n, 1))
        np.testing.assert_array_equal(cross_rows(a, b), np.cross(a, b))
        np.testing.assert_array_equal(cross_rows(b, -a), np.cross(b, -a))
    np.testing.assert_array_equal(cross_rows(np.eye(3), np.roll(np.eye(3), -1, axis=0)), np.roll(np.eye(3), 1, axis=0))
