"""Every reading of a mesh's polygons: both splits of a quad, every triangle of an n-gon, every diagonal; the
checks made on them hold for any triangulation a user's tool makes, and the pass clears them."""

import itertools

import numpy as np
import pytest
from meshes import grid

from garment_transfer.geometry.broad_phase import RADIX_FROM, BoxGrid, box_pairs, stable_order
from garment_transfer.geometry.clearance import separate
from garment_transfer.geometry.intersections import crossings, minimum_distance, self_intersections
from garment_transfer.geometry.mesh import mesh_from_polygons, mesh_from_triangles
from garment_transfer.geometry.predicates import edge_triangle_pairs
from garment_transfer.geometry.readings import merge_readings, readings_of, split_readings, triangle_readings
from garment_transfer.geometry.self_check import SelfCheck, overlapping


def triangulations(polygon):
    """Every triangulation of a convex polygon's corners (a list of (k-2,3) arrays)."""
    k = len(polygon)
    if k == 3:
        return [np.array([polygon])]
    out = []
    for apex in range(1, k - 1):   # the triangle on the side (0, k-1) has its third corner at apex
        left, right = polygon[:apex + 1], polygon[apex:]
        for a in (triangulations(left) if len(left) >= 3 else [np.zeros((0, 3), int)]):
            for b in (triangulations(right) if len(right) >= 3 else [np.zeros((0, 3), int)]):
                out.append(np.vstack([a, b, [[polygon[0], polygon[apex], polygon[-1]]]]))
    return out


def test_a_quad_is_read_both_ways_and_a_pentagon_every_way():
    m = mesh_from_polygons(np.eye(3)[[0, 1, 2, 0, 1]] + np.arange(5)[:, None] * [0, 0, 1e-3],
                           [[0, 1, 2, 3, 4]])
    R = readings_of(m)
    assert R.n_triangles == 10 and R.n_edges == 10
    assert sorted(map(tuple, np.sort(R.E[R.diagonal_of >= 0], axis=1).tolist())) == [
        (0, 2), (0, 3), (1, 3), (1, 4), (2, 4)]
    # Every triangle of every triangulation of the pentagon is one of its readings' triangles.
    tris = {tuple(sorted(t)) for t in R.F.tolist()}
    for T in triangulations([0, 1, 2, 3, 4]):
        assert {tuple(sorted(t)) for t in T.tolist()} <= tris
    q = readings_of(grid(2, 2))
    assert q.n_triangles == 4 and q.n_edges == 6 and (q.diagonal_of >= 0).sum() == 2
    assert np.array_equal(q.split, grid(2, 2).F)


def test_one_split_read_by_polygons_finds_the_self_intersections_of_its_triangles():
    # A sheet of quads and a pentagon and triangles crumpled onto itself: the mesh's own triangles checked with
    # the polygons' boxes find exactly what a check of those triangles alone finds.
    rng = np.random.default_rng(11)
    sheet = grid(9, 8, wave=0.3)
    quads = sheet.face_vertices.reshape(-1, 4).tolist()
    polygons = quads[:40] + [quads[40][:3], [quads[40][0], *quads[40][2:]], quads[41] + [quads[50][2]]]
    polygons += quads[42:50] + quads[51:]
    V = sheet.V + rng.normal(scale=0.12, size=sheet.V.shape)
    m = mesh_from_polygons(V, polygons)
    R = split_readings(m)
    assert split_readings(m) is R                                          # kept for the mesh's arrays
    assert np.array_equal(np.sort(R.E, axis=0), np.sort(triangle_readings(m.F).E, axis=0))
    assert {tuple(t) for t in R.F.tolist()} == {tuple(t) for t in m.F.tolist()} and R.n_triangles == m.n_triangles
    assert np.all(np.diff(R.face) >= 0) and np.array_equal(R.split, m.F)

    def as_vertices(R, pairs):
        return {(tuple(sorted(R.E[e])), tuple(sorted(R.F[t]))) for e, t in pairs.tolist()}

    T = triangle_readings(m.F)
    found = as_vertices(R, SelfCheck(V, R).all(V))
    assert len(found) > 20 and found == as_vertices(T, SelfCheck(V, T).all(V))
    assert self_intersections(V, R)[0] == self_intersections(V, T)[0] == len(found)


def test_a_crossing_under_the_other_split_of_a_quad_is_counted():
    # A quad folded along its diagonal 0-2, ridge up, over a spike of the body: split along 0-2 (the shorter
    # diagonal, the core's own split) the cloth clears the spike; split along 1-3 the spike pokes through it.
    V = np.array([[-1.0, 0, 0.3], [0, -1, 0], [1.0, 0, 0.3], [0, 1.05, 0]])
    garment = mesh_from_polygons(V, [[0, 1, 2, 3]])
    spike = mesh_from_polygons(np.array([[-0.3, -0.3, -0.5], [0.3, -0.3, -0.5], [0.3, 0.3, -0.5],
                                         [-0.3, 0.3, -0.5], [0.0, 0.02, 0.15]]),
                               [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4], [3, 2, 1, 0]])
    own = crossings(garment.V, garment.F, spike.V, spike.F)
    assert own["a_edge_pairs"] + own["b_edge_pairs"] == 0
    every = crossings(garment.V, readings_of(garment), spike.V, readings_of(spike))
    assert every["a_edges_through_b"] == 1                     # the diagonal 1-3 through the spike
    assert every["b_edges_through_a"] >= 1                     # and the spike's edges through the other split
    assert minimum_distance(garment.V, garment.F, spike.V, spike.F) > 0
    assert minimum_distance(garment.V, readings_of(garment), spike.V, readings_of(spike)) == 0.0
    # The same quad, read by a user's tool along the other diagonal, crosses exactly there.
    other = mesh_from_triangles(V, [[0, 1, 3], [1, 2, 3]])
    assert crossings(other.V, other.F, spike.V, spike.F)["a_edges_through_b"] == 1


def test_a_body_quad_poking_through_under_its_other_split_is_counted():
    # The body's quad, not the garment's, is non-planar: along its diagonal 0-2 it is a valley under the
    # cloth, along 1-3 a ridge that rises through it.
    body = mesh_from_polygons(np.array([[-1.0, 0, -0.3], [0, -1, 0.2], [1.0, 0, -0.3], [0, 1, 0.2]]),
                              [[0, 1, 2, 3]])
    cloth = mesh_from_polygons(np.array([[-0.6, -0.3, 0.0], [0.6, -0.3, 0], [0.6, 0.3, 0], [-0.6, 0.3, 0]]),
                               [[0, 1, 2, 3]])
    assert np.array_equal(np.sort(body.F, axis=1), [[0, 1, 2], [0, 2, 3]])          # the core's own split
    own = crossings(cloth.V, cloth.F, body.V, body.F)
    assert own["a_edge_pairs"] + own["b_edge_pairs"] == 0
    c = crossings(cloth.V, readings_of(cloth), body.V, readings_of(body))
    # The cloth's sides y = +-0.3 and both its diagonals meet the ridge where it rises above z = 0 (|x| < 0.4).
    assert c["a_edges_through_b"] == 4 and c["b_edge_pairs"] == 0


def test_a_diagonal_and_a_triangle_of_one_polygon_are_not_a_self_intersection():
    # A flat pentagon: its diagonal 0-2 and triangle 1-3-4 cross in its plane but are never in one reading.
    angles = np.linspace(0, 2 * np.pi, 6)[:-1]
    m = mesh_from_polygons(np.stack([np.cos(angles), np.sin(angles), 0 * angles], 1), [[0, 1, 2, 3, 4]])
    R = readings_of(m)
    d = np.flatnonzero((R.E == [0, 2]).all(axis=1))[0]
    t = np.flatnonzero((np.sort(R.F, axis=1) == [1, 3, 4]).all(axis=1))[0]
    assert edge_triangle_pairs(m.V, R.E[[d]], m.V, R.F[[t]])[0].shape[0] == 1     # they meet
    assert self_intersections(m.V, R)[0] == 0


def random_quads(seed, n=7, noise=0.25):
    """A crumpled sheet of quads (it crosses itself) and a shape of it moved here and there."""
    rng = np.random.default_rng(seed)
    m = grid(n, n, wave=0.4)
    V = m.V + rng.normal(scale=noise / n, size=m.V.shape)
    # Folded over onto itself at x = 0.5, the two halves a little apart: the noise makes them cross.
    V[:, 2] += np.where(V[:, 0] > 0.5, 0.02, 0.0)
    V[:, 0] = np.where(V[:, 0] > 0.5, 1.0 - V[:, 0], V[:, 0])
    return m.with_vertices(V), rng


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_self_check_on_polygons_equals_edges_against_triangles(seed):
    m, rng = random_quads(seed)
    R = readings_of(m)
    check = SelfCheck(m.V, R)
    full = check.all(m.V)
    brute, _ = edge_triangle_pairs(m.V, R.E, m.V, R.F, same_mesh=True, edge_diagonal_of=R.diagonal_of,
                                   triangle_face=R.face)
    assert full.shape[0] > 0
    np.testing.assert_array_equal(full, brute)
    moved = rng.random(m.n_vertices) < 0.2
    W = m.V.copy()
    W[moved] += rng.normal(scale=0.1, size=(int(moved.sum()), 3))
    again = check.again(W, full, moved)
    brute, _ = edge_triangle_pairs(W, R.E, W, R.F, same_mesh=True, edge_diagonal_of=R.diagonal_of,
                                   triangle_face=R.face)
    np.testing.assert_array_equal(again, brute)


def test_overlapping_boxes_of_edges_and_triangles_as_brute_force_finds_them():
    rng = np.random.default_rng(5)
    # Coordinates on a coarse lattice: many boxes touch exactly (closed boxes overlap there).
    V = rng.integers(0, 6, size=(40, 3)).astype(np.float64)
    corners = rng.integers(0, 40, size=(5, 3000))
    lo_e, hi_e = V[corners[:2]].min(axis=0), V[corners[:2]].max(axis=0)
    lo_t, hi_t = V[corners[2:]].min(axis=0), V[corners[2:]].max(axis=0)
    want = np.flatnonzero(np.all((lo_e <= hi_t) & (lo_t <= hi_e), axis=1))
    assert 0 < want.size < 3000
    np.testing.assert_array_equal(overlapping(V, corners), want)
    which = np.sort(rng.choice(3000, 700, replace=False))
    np.testing.assert_array_equal(overlapping(V, corners, which), np.intersect1d(which, want))


def test_binned_boxes_moved_are_found_where_they_are():
    rng = np.random.default_rng(4)
    lo = rng.random((300, 3))
    hi = lo + rng.random((300, 3)) * 0.1
    g = BoxGrid(lo, hi)
    moved = rng.choice(300, 40, replace=False)
    lo2, hi2 = lo.copy(), hi.copy()
    lo2[moved] += rng.normal(scale=0.5, size=(40, 3))       # some leave the grid's first extent
    hi2[moved] = lo2[moved] + 0.05
    g.update(moved, lo2[moved], hi2[moved])
    qlo = rng.random((200, 3)) * 1.5 - 0.25
    qhi = qlo + 0.1
    got = {tuple(p) for p in g.query(qlo, qhi).tolist()}
    want = {(i, j) for i, j in itertools.product(range(200), range(300))
            if np.all(qlo[i] <= hi2[j]) and np.all(lo2[j] <= qhi[i])}
    assert got == want and len(g.query(qlo, qhi)) == len(want)
    assert {tuple(p) for p in box_pairs(qlo, qhi, lo2, hi2).tolist()} == want


def test_binned_boxes_of_every_size_touching_and_points_pair_as_brute_force_does():
    rng = np.random.default_rng(7)
    # Sizes over two orders of magnitude (a body's fingers and its back), points (no size), and boxes that only
    # touch: a face exactly on another's (closed boxes overlap there), in coordinates far from the origin.
    size = 10.0 ** rng.uniform(-2, 0, (400, 1)) * rng.random((400, 3))
    lo = 1e3 + rng.random((400, 3))
    hi = lo + size
    hi[:20] = lo[:20]
    lo[20:40, 0] = hi[40:60, 0]
    hi[20:40, 0] = lo[20:40, 0] + size[20:40, 0]
    g = BoxGrid(lo, hi)
    want = {(i, j) for i, j in itertools.combinations(range(400), 2)
            if np.all(lo[i] <= hi[j]) and np.all(lo[j] <= hi[i])}
    got = g.self_pairs()
    assert {tuple(p) for p in got.tolist()} == want and len(got) == len(want)
    assert np.all(got[:, 0] < got[:, 1])
    both = {tuple(p) for p in g.query(lo, hi).tolist()}
    assert both == want | {(j, i) for i, j in want} | {(i, i) for i in range(400)}
    assert len(BoxGrid(lo[:1], hi[:1]).self_pairs()) == 0 and len(g.query(lo[:0], hi[:0])) == 0


@pytest.mark.parametrize("top, dtype", [(top, np.int64) for top in (1, 300, 1 << 16, 70_000, 1 << 31, 1 << 40)]
                         + [(top, np.int32) for top in (300, 1 << 16, 70_000, (1 << 31) - 1)])
def test_stable_order_is_numpys_stable_sort(top, dtype):
    rng = np.random.default_rng(top % 1000)
    for n in (0, 5, RADIX_FROM - 1, RADIX_FROM + 7, 200_000):
        keys = rng.integers(0, top, n).astype(dtype)
        if n > 10:
            keys[: n // 3] = np.sort(keys[: n // 3])       # runs, as a grid's merged entries have
            keys[-1] = top - 1                               # the largest key, exactly on a digit's boundary
        np.testing.assert_array_equal(stable_order(keys), np.argsort(keys, kind="stable"))
    negative = np.array([3, -1, 2, -1] * (RADIX_FROM // 2), dtype=dtype)
    np.testing.assert_array_equal(stable_order(negative), np.argsort(negative, kind="stable"))


def test_merged_readings_keep_each_part():
    a, b = readings_of(grid(3, 3)), readings_of(grid(2, 4))
    m = merge_readings([(9, a), (8, b)])
    assert m.n_faces == a.n_faces + b.n_faces and m.n_triangles == a.n_triangles + b.n_triangles
    assert np.array_equal(m.E[a.n_edges:], b.E + 9)
    assert np.array_equal(m.diagonal_of[a.n_edges:][b.diagonal_of >= 0], b.diagonal_of[b.diagonal_of >= 0] + a.n_faces)


def test_the_pass_clears_the_other_split_too():
    # The folded quad of the first test, on a sheet of quads over the plane: after the pass, neither split
    # of any quad crosses the plane, and the cloth moved only up.
    m = grid(5, 5, size=2.0)
    V = m.V - [1.0, 0.8, 0.0]
    V[:, 2] = 0.15
    V[12, 2] = -0.02                       # the middle vertex dips through the plane
    cloth = m.with_vertices(V)
    plane = mesh_from_polygons(np.array([[-3.0, -3, 0], [3, -3, 0], [3, 3, 0], [-3, 3, 0]]), [[0, 1, 2, 3]])
    G, B = readings_of(cloth), readings_of(plane)
    assert crossings(V, G, plane.V, B)["a_edge_pairs"] > 0
    out, info = separate(V, G, plane.V, B, offset=0.05)
    c = crossings(out, G, plane.V, B)
    assert c["a_edge_pairs"] == c["b_edge_pairs"] == 0 and info["crossings_after"] == 0
    assert np.all(out[:, 2] >= V[:, 2] - 1e-12)
    assert minimum_distance(out, G, plane.V, B) > 0
