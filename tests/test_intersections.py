"""Exact intersection counts: constructed crossings with known answers, the touching convention,
the floating-point filter against exact arithmetic, the broad phase against brute force."""

import itertools

import numpy as np
import pytest
from meshes import icosphere

from garment_transfer.geometry.intersections import (
    box_pairs,
    crossings,
    edge_triangle_pairs,
    mesh_edges,
    minimum_distance,
    segment_distances,
    segment_meets_triangle_exact,
    segments_meet_triangles,
    self_intersections,
)
from garment_transfer.geometry.predicates import orient3d_filtered, segment_sides, triangle_planes
from garment_transfer.geometry.proximity import closest_on_triangles

TRI = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
TRI_F = np.array([[0, 1, 2]])


def segment_hits(p, q, V=TRI, F=TRI_F):
    pairs, _ = edge_triangle_pairs(np.array([p, q], float), np.array([[0, 1]]), V, F)
    return pairs.shape[0]


@pytest.mark.parametrize("p, q, hits", [
    ((0.2, 0.2, -1), (0.2, 0.2, 1), 1),          # through the interior
    ((0.5, 0.0, -1), (0.5, 0.0, 1), 1),          # through an edge
    ((0.0, 0.0, -1), (0.0, 0.0, 1), 1),          # through a corner
    ((0.2, 0.2, 0.0), (0.2, 0.2, 1), 1),         # an end touching the interior
    ((1.0, 0.0, 0.0), (2.0, 0.0, 1), 1),         # an end touching a corner
    ((-1.0, 0.2, 0), (2.0, 0.2, 0), 1),          # in the plane, across
    ((-1.0, -1.0, 0), (2.0, -1.0, 0), 0),        # in the plane, beside
    ((0.6, 0.6, -1), (0.6, 0.6, 1), 0),          # just past the hypotenuse
    ((2.0, 2.0, -1), (2.0, 2.0, 1), 0),          # far
    ((0.2, 0.2, 0.5), (0.3, 0.2, 1), 0),         # above, not reaching
])
def test_segment_triangle_convention(p, q, hits):
    assert segment_hits(p, q) == hits


def test_one_ulp_decides():
    tiny = 5e-324   # the smallest positive double: only exact arithmetic sees it
    assert segment_hits((0.2, 0.2, tiny), (0.2, 0.2, 1)) == 0
    assert segment_hits((0.2, 0.2, -tiny), (0.2, 0.2, 1)) == 1
    # The hypotenuse x + y = 1 seen exactly: 0.5 + 0.5 is on it, the next double beyond is off.
    assert segment_hits((0.5, 0.5, -1), (0.5, 0.5, 1)) == 1
    assert segment_hits((0.5, np.nextafter(0.5, 1), -1), (0.5, np.nextafter(0.5, 1), 1)) == 0


def test_through_a_shared_edge_and_vertex():
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    two = np.array([[0, 1, 2], [0, 2, 3]])
    seg = np.array([[0.5, 0.5, -1], [0.5, 0.5, 1]])   # through the diagonal: both triangles
    pairs, _ = edge_triangle_pairs(seg, np.array([[0, 1]]), square, two)
    assert pairs.tolist() == [[0, 0], [0, 1]]
    fan_V = np.vstack([[0.0, 0.0, 0.0], np.c_[np.cos(np.arange(6) * np.pi / 3),
                                              np.sin(np.arange(6) * np.pi / 3), np.zeros(6)]])
    fan_F = np.array([[0, 1 + k, 1 + (k + 1) % 6] for k in range(6)])
    pairs, _ = edge_triangle_pairs(np.array([[0, 0, -1.0], [0, 0, 1.0]]), np.array([[0, 1]]), fan_V, fan_F)
    assert pairs.shape[0] == 6   # through the common corner: all six


def crossed_squares():
    """A horizontal square and a vertical one through it (hand-counted below)."""
    A = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    FA = np.array([[0, 1, 2], [0, 2, 3]])          # diagonal y = x
    B = np.array([[-0.5, 0.1, -1], [0.5, 0.1, -1], [0.5, 0.1, 1], [-0.5, 0.1, 1]], float)
    FB = np.array([[0, 1, 2], [0, 2, 3]])          # diagonal z = 2x
    return A, FA, B, FB


def test_counts_on_crossed_squares():
    A, FA, B, FB = crossed_squares()
    c = crossings(A, FA, B, FB)
    # A's diagonal meets B at (0.1, 0.1, 0); B's two sides x = +-0.5 and its diagonal meet A.
    assert (c["a_edges_through_b"], c["a_edge_pairs"]) == (1, 1)
    assert (c["b_edges_through_a"], c["b_edge_pairs"]) == (3, 3)
    assert sorted(map(tuple, c["b_pairs"])) == [(0, 2), (0, 3), (1, 2)]
    swapped = crossings(B, FB, A, FA)
    assert (swapped["a_edge_pairs"], swapped["b_edge_pairs"]) == (3, 1)
    # The same two squares as one mesh: four self-intersections; lifted apart, none.
    V = np.vstack([A, B])
    F = np.vstack([FA, FB + 4])
    assert self_intersections(V, F)[0] == 4
    assert self_intersections(np.vstack([A, B + [0, 0, 5]]), F)[0] == 0


def test_self_intersections_ignore_neighbours():
    V, F = icosphere(3)
    assert self_intersections(V, F)[0] == 0
    flat = np.stack(np.meshgrid(np.arange(20.0), np.arange(20.0)), -1).reshape(-1, 2)
    flat = np.c_[flat, np.zeros(len(flat))]
    idx = np.arange(400).reshape(20, 20)
    Ff = np.concatenate([np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:]], -1).reshape(-1, 3),
                         np.stack([idx[:-1, :-1], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 3)])
    # Exactly coplanar neighbours: every candidate goes through the exact path and none meets.
    count, _, _ = self_intersections(flat, Ff)
    assert count == 0


def test_separated_and_overlapping_spheres():
    V, F = icosphere(2)
    far = crossings(V, F, V + [2.5, 0, 0], F)
    assert far["a_edge_pairs"] == far["b_edge_pairs"] == 0
    near = crossings(V, F, V + [1.0, 0.3, 0.2], F)
    assert near["a_edge_pairs"] > 0 and near["b_edge_pairs"] > 0
    # Swapping the roles swaps the two counts.
    back = crossings(V + [1.0, 0.3, 0.2], F, V, F)
    assert (back["a_edge_pairs"], back["b_edge_pairs"]) == (near["b_edge_pairs"], near["a_edge_pairs"])


def test_filter_agrees_with_exact_arithmetic():
    rng = np.random.default_rng(3)
    k = 3000
    P, Q, A, B, C = (rng.normal(size=(k, 3)) for _ in range(5))
    # Some degenerate ones: segment ends on the triangle's plane, on its corners and edges.
    P[:300] = A[:300]
    Q[300:600] = 0.5 * (B[300:600] + C[300:600])
    w = rng.random((300, 3))
    w /= w.sum(axis=1, keepdims=True)
    P[600:900] = w[:, :1] * A[600:900] + w[:, 1:2] * B[600:900] + w[:, 2:] * C[600:900]
    meet, _ = segments_meet_triangles(P, Q, A, B, C)
    exact = np.array([segment_meets_triangle_exact(*x) for x in zip(P, Q, A, B, C)])
    assert np.array_equal(meet, exact)
    assert 0 < meet.sum() < k


def test_sides_of_kept_planes_are_the_filtered_orientation():
    rng = np.random.default_rng(5)
    k = 4000
    P, Q, A, B, C = (rng.normal(size=(k, 3)) for _ in range(5))
    rows = rng.permutation(k)                                       # segment i against triangle rows[i]
    P[:500] = A[rows[:500]] + 1e-17 * rng.normal(size=(500, 3))     # ends next to the plane
    P[:250] = A[rows[:250]]                                         # and on it
    Q[500:800] = 0.5 * (B[rows[500:800]] + C[rows[500:800]])
    flat = rows[800:900]                                            # triangles of no area, exactly
    A[flat] = 0.0
    C[flat] = 2.0 * B[flat]
    s1, s2 = segment_sides(P, Q, triangle_planes(A, B, C), rows)
    # The filter's floating-point evaluation with the corner and the point swapped, bit for bit...
    np.testing.assert_array_equal(s1, -orient3d_filtered(P, B[rows], C[rows], A[rows]))
    np.testing.assert_array_equal(s2, -orient3d_filtered(Q, B[rows], C[rows], A[rows]))
    # ... whose certain signs are the point's orientation against the triangle; what it cannot tell is 0.
    for s, X in ((s1, P), (s2, Q)):
        ref = orient3d_filtered(A[rows], B[rows], C[rows], X)
        both = (s != 0) & (ref != 0)
        assert both.sum() > 3000 and np.array_equal(s[both], ref[both])
        assert np.all(s[800:900] == 0)
    assert np.all(s1[:250] == 0)


def test_general_position_against_parametric_solution():
    rng = np.random.default_rng(4)
    k = 2000
    P, Q, A, B, C = (rng.normal(size=(k, 3)) for _ in range(5))
    meet, _ = segments_meet_triangles(P, Q, A, B, C)
    # Solve P + t (Q - P) = A + u (B - A) + v (C - A) in floating point; random data is far from
    # the boundaries, so the answer is clear.
    M = np.stack([Q - P, A - B, A - C], axis=2)
    t, u, v = np.linalg.solve(M, (A - P)[..., None])[..., 0].T
    param = (t >= 0) & (t <= 1) & (u >= 0) & (v >= 0) & (u + v <= 1)
    margin = np.minimum.reduce([np.abs(t), np.abs(1 - t), np.abs(u), np.abs(v), np.abs(1 - u - v)])
    clear = margin > 1e-9
    assert np.array_equal(meet[clear], param[clear])


def test_box_pairs_brute_force():
    rng = np.random.default_rng(5)
    lo_a = rng.random((300, 3))
    hi_a = lo_a + rng.random((300, 3)) * 0.1
    lo_b = rng.random((200, 3))
    hi_b = lo_b + rng.random((200, 3)) * 0.3
    hi_b[0] = lo_b[0] + 1.0   # one huge box
    got = set(map(tuple, box_pairs(lo_a, hi_a, lo_b, hi_b)))
    want = {(i, j) for i, j in itertools.product(range(300), range(200))
            if np.all(lo_a[i] <= hi_b[j]) and np.all(lo_b[j] <= hi_a[i])}
    assert got == want
    assert len(box_pairs(lo_a, hi_a, lo_b, hi_b)) == len(want)   # each pair once


def test_mesh_edges():
    assert mesh_edges(np.array([[0, 1, 2], [2, 1, 3]])).tolist() == [[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]]


def test_minimum_distance_brute_force():
    V, F = icosphere(1)
    W = V * 0.7 + [1.9, 0.2, -0.1]
    F2 = F
    got = minimum_distance(V, F, W, F2)
    best = np.inf
    for P, (U, G) in ((V, (W, F2)), (W, (V, F))):
        T = U[G]
        Pr = np.repeat(P, len(G), axis=0)
        Tr = np.tile(T, (len(P), 1, 1))
        Qc, _ = closest_on_triangles(Pr, Tr[:, 0], Tr[:, 1], Tr[:, 2])
        best = min(best, np.linalg.norm(Pr - Qc, axis=1).min())
    Ea, Eb = mesh_edges(F), mesh_edges(F2)
    i, j = np.meshgrid(np.arange(len(Ea)), np.arange(len(Eb)), indexing="ij")
    i, j = i.ravel(), j.ravel()
    best = min(best, segment_distances(V[Ea[i, 0]], V[Ea[i, 1]], W[Eb[j, 0]], W[Eb[j, 1]]).min())
    assert got == pytest.approx(best, rel=1e-12)
    assert 0.1 < got < 0.3
    assert minimum_distance(V, F, V + [0.5, 0, 0], F) == 0.0


def test_segment_distances_known():
    d = segment_distances(np.array([[0, 0, 0.0], [0, 0, 0]]), np.array([[1, 0, 0.0], [1, 0, 0]]),
                          np.array([[0.5, 1, 2.0], [3, 0, 0]]), np.array([[0.5, -1, 2.0], [4, 0, 0]]))
    assert d == pytest.approx([2.0, 2.0])
