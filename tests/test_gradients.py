import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from meshes import grid, icosphere, random_rotation, require_makehuman

from garment_transfer.geometry.gradients import deformation_gradients, triangle_frames
from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.poisson import METRIC_CAP, PoissonSolver, edge_operator, triangle_metrics
from garment_transfer.pipeline.metrics import discrete_curvature


def test_identity_on_unchanged_mesh():
    V, F = icosphere(2)
    Q, degenerate = deformation_gradients(V, V, F)
    assert not degenerate.any()
    np.testing.assert_allclose(Q, np.broadcast_to(np.eye(3), Q.shape), atol=1e-12)


def test_similarity_gives_exactly_its_matrix():
    rng = np.random.default_rng(1)
    V, F = icosphere(1)
    A = 1.7 * random_rotation(rng)
    Q, _ = deformation_gradients(V, V @ A.T + [3.0, -1.0, 2.0], F)
    np.testing.assert_allclose(Q, np.broadcast_to(A, Q.shape), atol=1e-12)


def test_affine_map_is_exact_on_every_triangle_plane():
    # A general affine map (shear, unequal scales) is determined by a triangle only in its plane:
    # Q maps both edges exactly, and equals A wherever A is a similarity on that plane (here: a
    # flat sheet in the xy plane under a map that keeps z -> z).
    rng = np.random.default_rng(2)
    V, F = icosphere(1)
    A = np.array([[1.3, 0.4, -0.2], [0.1, 0.8, 0.3], [-0.3, 0.2, 1.5]])
    assert np.linalg.det(A) > 0
    Y = V @ A.T + rng.normal(size=3)
    Q, _ = deformation_gradients(V, Y, F)
    X, _ = triangle_frames(V, F)
    np.testing.assert_allclose(np.einsum("mij,mjk->mik", Q, X[:, :, :2]),
                               np.einsum("ij,mjk->mik", A, X[:, :, :2]), atol=1e-12)
    sheet = grid(5, 4)
    B = np.array([[1.3, 0.4, 0.0], [-0.2, 0.8, 0.0], [0.0, 0.0, 1.0]])
    Qs, _ = deformation_gradients(sheet.V, sheet.V @ B.T, sheet.F)
    # In-plane block equals B's; the normal column is scaled by sqrt(det) (the frame's normal
    # is normalised by sqrt of the area): exact known answer.
    np.testing.assert_allclose(Qs[:, :2, :2], np.broadcast_to(B[:2, :2], (Qs.shape[0], 2, 2)), atol=1e-12)
    np.testing.assert_allclose(Qs[:, 2, 2], np.sqrt(np.linalg.det(B[:2, :2])), atol=1e-12)


def test_kept_rest_frames_answer_as_fresh_ones(monkeypatch):
    # The rest shape's frames are kept between calls: the answers equal those computed afresh, a rest
    # shape moved in place (same array, new numbers) is not mistaken for the kept one, and what a
    # caller gets back it may change without changing the next answer.
    import garment_transfer.geometry.gradients as gradients

    rng = np.random.default_rng(7)
    V, F = icosphere(2)
    X = V + 0.01 * rng.normal(size=V.shape)
    Y = V * [1.2, 0.9, 1.1]
    first, deg = deformation_gradients(X, Y, F)
    deg[:] = True
    kept, deg_kept = deformation_gradients(X, Y, F)
    np.testing.assert_array_equal(first, kept)
    assert not deg_kept.any()
    X[:] = V
    moved, _ = deformation_gradients(X, Y, F)
    monkeypatch.setattr(gradients, "REST_KEPT_TRIANGLES", -1)
    fresh, _ = deformation_gradients(X, Y, F)
    np.testing.assert_array_equal(moved, fresh)
    assert np.abs(moved - kept).max() > 1e-3


def test_degenerate_triangle_is_flagged_and_finite():
    V = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]], float)
    F = np.array([[0, 1, 2], [0, 1, 3]])
    Q, degenerate = deformation_gradients(V, V * 2, F)
    assert degenerate.tolist() == [True, False]
    assert np.all(np.isfinite(Q))
    np.testing.assert_array_equal(Q[0], np.eye(3))


def test_edge_operator_rows_sum_to_zero_and_laplacian_is_psd():
    V, F = icosphere(1)
    G = edge_operator(V.shape[0], F)
    np.testing.assert_allclose(np.asarray(G.sum(axis=1)).ravel(), 0.0)
    K = (G.T @ G).toarray()
    np.testing.assert_allclose(K, K.T)
    assert np.linalg.eigvalsh(K).min() > -1e-9


@pytest.mark.parametrize("energy", ["gradients", "edges"])
def test_poisson_rebuilds_a_mesh_from_its_own_gradients(energy):
    rng = np.random.default_rng(3)
    V, F = icosphere(2)
    Y = V * [1.0, 1.3, 0.7] + 0.05 * np.sin(4 * V) + rng.normal(size=3)
    Q, _ = deformation_gradients(V, Y, F)
    solver = PoissonSolver(V, F, anchor_weight=1e-3, energy=energy)
    out = solver.solve(Q, Y)
    assert np.max(np.abs(out - Y)) / np.max(np.abs(Y)) < 1e-9


def test_poisson_factor_is_reused_for_many_targets():
    V, F = icosphere(2)
    solver = PoissonSolver(V, F, anchor_weight=1e-2)
    for s in (0.8, 1.2, 1.5):
        Y = V * s
        Q, _ = deformation_gradients(V, Y, F)
        assert np.max(np.abs(solver.solve(Q, Y) - Y)) < 1e-9


def test_poisson_rebuilds_a_real_garment_female_average_to_pear():
    root = require_makehuman()
    a = read_obj(root / "garments" / "female_casualsuit01" / "female_average.obj")
    b = read_obj(root / "garments" / "female_casualsuit01" / "female_pear.obj")
    Q, _ = deformation_gradients(a.V, b.V, a.F)
    out = PoissonSolver(a.V, a.F, anchor_weight=1e-3).solve(Q, b.V)
    assert np.max(np.abs(out - b.V)) / np.max(np.abs(b.V)) < 1e-9


def test_poisson_anchor_weight_must_be_positive():
    V, F = icosphere(0)
    with pytest.raises(ValueError, match="anchor_weight"):
        PoissonSolver(V, F, anchor_weight=0.0)
    with pytest.raises(ValueError, match="energy"):
        PoissonSolver(V, F, anchor_weight=1e-3, energy="cotangent")


def _sheet_with_thin_column():
    """A flat sheet whose middle column of quads is squeezed to 1:20 slivers, the vertex columns on
    either side of them, a target field that keeps it flat and anchors that ask for a bump and a shear
    (which it cannot follow exactly)."""
    sheet = grid(12, 12)
    V, F = sheet.V.copy(), sheet.F
    xs = np.unique(V[:, 0])
    V[np.isclose(V[:, 0], xs[6]), 0] = xs[5] + 0.004
    thin = np.isclose(V[:, 0], xs[5]) | np.isclose(V[:, 0], xs[5] + 0.004)
    anchors = V.copy()
    anchors[:, 2] += 0.05 * np.sin(np.pi * V[:, 0]) * np.sin(np.pi * V[:, 1] / 0.8)
    anchors[:, 0] += 0.03 * V[:, 1] ** 2
    return V, F, thin, anchors


def test_gradient_energy_keeps_thin_triangles_from_folding():
    # The strain the anchors leave: with the paper's edge energy a sliver's short edge is cheap to turn,
    # so the slivers fold; the finite-element energy holds them as stiff as the rest.
    V, F, thin, anchors = _sheet_with_thin_column()
    Q = np.broadcast_to(np.eye(3), (F.shape[0], 3, 3))
    r0 = discrete_curvature(V, F)
    turn = {e: np.abs(discrete_curvature(PoissonSolver(V, F, 1e-2, energy=e).solve(Q, anchors), F) - r0)
            for e in ("gradients", "edges")}
    assert turn["edges"][thin].mean() > 100 * turn["edges"][~thin].mean()
    assert turn["gradients"][thin].mean() < 0.01 * turn["edges"][thin].mean()
    assert turn["gradients"][thin].mean() < 10 * turn["gradients"][~thin].mean()


def test_gradient_energy_does_not_depend_on_which_vertex_comes_first():
    V, F, _, anchors = _sheet_with_thin_column()
    Q = np.eye(3) + 0.1 * np.random.default_rng(0).normal(size=(F.shape[0], 3, 3))
    turned = F[:, [1, 2, 0]]
    a, b = (PoissonSolver(V, f, 1e-2).solve(Q, anchors) for f in (F, turned))
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-10)
    # The paper's energy measures two of the three edges: which two changes the answer.
    a, b = (PoissonSolver(V, f, 1e-2, energy="edges").solve(Q, anchors) for f in (F, turned))
    assert np.abs(a - b).max() > 1e-3


def test_triangle_metric_is_the_finite_element_metric_and_matches_the_edges_on_the_median_triangle():
    V, F = icosphere(2)  # every angle acute: the clamping does nothing
    M = triangle_metrics(V, F, np.ones(F.shape[0]))
    x1 = V[F[:, 0]]
    E = np.stack([V[F[:, 1]] - x1, V[F[:, 2]] - x1], axis=2)
    EtE = np.einsum("mki,mkj->mij", E, E)
    area = 0.5 * np.linalg.norm(np.cross(E[:, :, 0], E[:, :, 1]), axis=1)
    c = np.median(np.trace(EtE, axis1=1, axis2=2) / (2 * area))
    np.testing.assert_allclose(M, c * area[:, None, None] * np.linalg.inv(EtE), rtol=1e-12)
    # A gradient error G in a triangle's plane leaves the edge residuals R = G E and costs tr(R M R^T);
    # the paper's energy is |G e1|^2 + |G e2|^2. For a uniform scaling error (G the projection on the
    # plane) the two agree on the median triangle.
    fem = np.einsum("mki,mij,mkj->m", E, M, E)
    paper = np.einsum("mki,mki->m", E, E)
    assert np.median(fem / paper) == pytest.approx(1.0, rel=1e-3)


def test_triangle_metric_weighs_every_edge_positively_and_caps_thin_triangles():
    # An obtuse triangle (its negative cotangent clamped), a nearly degenerate one, a zero-weight one.
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [2, 0, 0], [1.0, 1e-7, 0], [1.0, 0.2, 0]])
    F = np.array([[0, 1, 2], [1, 3, 2], [1, 4, 3], [0, 4, 5], [0, 4, 6]])
    M = triangle_metrics(V, F, np.ones(F.shape[0]))
    assert np.isfinite(M).all()
    np.testing.assert_allclose(M, np.swapaxes(M, 1, 2), atol=0)
    # Edge weights: k1 = -M01 (edge 2-3), k3 = M00 + M01 (edge 1-2), k2 = M11 + M01 (edge 1-3).
    k = np.stack([-M[:, 0, 1], M[:, 1, 1] + M[:, 0, 1], M[:, 0, 0] + M[:, 0, 1]], axis=1)
    assert (k >= 0).all()
    # The obtuse angle at vertex 6 (the triangle's third): the edge 0-4 opposite it gets nothing.
    assert k[4, 2] == 0 and k[4, 0] > 0 and k[4, 1] > 0
    # The thin triangle's largest weight is the cap: METRIC_CAP times the median cotangent, scaled as
    # every weight is (the right isosceles triangle's cotangent of 45 degrees, 1, gives the scale).
    cot = []
    for f in F:
        for i in range(3):
            u, v = V[f[(i + 1) % 3]] - V[f[i]], V[f[(i + 2) % 3]] - V[f[i]]
            cot.append(max(0.0, u @ v / np.linalg.norm(np.cross(u, v))))
    np.testing.assert_allclose(np.sort(k[0]), np.array([0, 1, 1]) * k[0].max(), atol=1e-12)
    assert k[3].max() == pytest.approx(METRIC_CAP * np.median(cot) * k[0].max(), rel=1e-9)
    assert not triangle_metrics(V, F, np.array([1.0, 1.0, 1.0, 0.0, 1.0]))[3].any()

def _garment_pair():
    """A garment on two bodies: MakeHuman's suit when the fixtures are there, else a waved sheet."""
    from meshes import MAKEHUMAN

    if (MAKEHUMAN / "garments").is_dir():
        a = read_obj(MAKEHUMAN / "garments" / "female_casualsuit01" / "female_average.obj")
        b = read_obj(MAKEHUMAN / "garments" / "female_casualsuit01" / "female_pear.obj")
        return a.V, a.F, b.V
    sheet = grid(120, 120, size=1.0, wave=0.02)
    V = sheet.V
    return V, sheet.F, V * [1.1, 0.9, 1.0] + 0.03 * np.sin(6 * V[:, [1, 2, 0]])


def test_multigrid_solve_equals_the_factor():
    # Anchors off the answer (a smooth pull and noise), per-vertex weights: the iteration has work to do.
    V, F, Y = _garment_pair()
    rng = np.random.default_rng(5)
    Q, _ = deformation_gradients(V, Y, F)
    anchors = Y + 0.02 * np.sin(3 * Y) + rng.normal(scale=1e-3, size=Y.shape)
    weight = rng.uniform(1e-4, 1e-2, size=V.shape[0])
    exact = PoissonSolver(V, F, weight).solve(Q, anchors)
    multigrid = PoissonSolver(V, F, weight, method="multigrid")
    assert multigrid.factor is None
    out = multigrid.solve(Q, anchors)
    assert multigrid.factor is None           # converged: no factor was made
    size = np.ptp(Y, axis=0).max()
    assert np.abs(out - anchors).max() > 1e-3 * size
    assert np.abs(out - exact).max() < 1e-7 * size


def test_multigrid_on_threads_equals_one_thread(monkeypatch):
    # The coordinates are independent systems: solved at once on threads or one after the other, the
    # answer is the same to the last bit.
    from garment_transfer.geometry import poisson

    V, F, Y = _garment_pair()
    Q, _ = deformation_gradients(V, Y, F)
    anchors = Y + 0.02 * np.sin(3 * Y)
    solver = PoissonSolver(V, F, 1e-3, method="multigrid")
    monkeypatch.setattr(poisson, "SOLVE_THREADS", 3)
    threaded = solver.solve(Q, anchors)
    monkeypatch.setattr(poisson, "SOLVE_THREADS", 1)
    np.testing.assert_array_equal(threaded, solver.solve(Q, anchors))


def test_multigrid_cycle_is_a_symmetric_positive_preconditioner():
    # Conjugate gradients needs u . M v = v . M u and v . M v > 0 of its preconditioner M (one V-cycle).
    V, F, _ = _garment_pair()
    hierarchy = PoissonSolver(V, F, 1e-3, method="multigrid").hierarchy
    rng = np.random.default_rng(2)
    u, v = rng.normal(size=(2, V.shape[0]))
    Mu, Mv = hierarchy.cycle(u), hierarchy.cycle(v)
    assert abs(u @ Mv - v @ Mu) <= 1e-10 * abs(u @ Mv)
    assert v @ Mv > 0 and u @ Mu > 0


def test_multigrid_that_does_not_converge_falls_back_to_the_factor(caplog):
    V, F, Y = _garment_pair()
    Q, _ = deformation_gradients(V, Y, F)
    anchors = Y + 0.02 * np.sin(3 * Y)
    solver = PoissonSolver(V, F, 1e-3, method="multigrid")
    solver.hierarchy.solve = lambda b, x0=None, **kw: x0          # never moves from the start
    with caplog.at_level("WARNING", logger="garment_transfer.geometry.poisson"):
        out = solver.solve(Q, anchors)
    assert "did not converge" in caplog.text
    np.testing.assert_allclose(out, PoissonSolver(V, F, 1e-3).solve(Q, anchors), rtol=0, atol=1e-12)


def test_solver_method_by_size_and_reuse():
    from garment_transfer.geometry import poisson

    assert poisson.choose_method(5_000, reused=False) == "factor"
    assert poisson.choose_method(poisson.MULTIGRID_MIN_VERTICES, reused=False) == "multigrid"
    assert poisson.choose_method(poisson.FACTOR_MAX_VERTICES, reused=True) == "factor"
    assert poisson.choose_method(poisson.FACTOR_MAX_VERTICES + 1, reused=True) == "multigrid"
    V, F = icosphere(0)
    with pytest.raises(ValueError, match="method"):
        PoissonSolver(V, F, 1e-3, method="cholesky")


def test_nested_dissection_is_a_permutation_whose_factor_solves_exactly():
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from garment_transfer.geometry import poisson

    V, F, Y = _garment_pair()
    n = V.shape[0]
    G = edge_operator(n, F)
    K = (G.T @ G + 1e-3 * sp.eye(n)).tocsc()
    order = poisson.nested_dissection(V, K)
    np.testing.assert_array_equal(np.sort(order), np.arange(n))
    b = np.random.default_rng(2).normal(size=(n, 3))
    x = poisson.OrderedFactor(K, order).solve(b)
    np.testing.assert_allclose(K @ x, b, atol=1e-9 * np.abs(b).max())
    np.testing.assert_allclose(x, spla.splu(K).solve(b), atol=1e-9 * np.abs(x).max())
    # Every block of the order is a leaf, a half or a separator: the separators (numbered after both
    # halves) keep the factor's fill near a minimum-degree order's, not a band's.
    lu = poisson.OrderedFactor(K, order).lu
    natural = spla.splu(K, permc_spec="NATURAL", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    assert lu.L.nnz < 0.5 * natural.L.nnz
    # Degenerate input: every vertex at one point still gives a permutation.
    same = poisson.nested_dissection(np.zeros((n, 3)), K)
    np.testing.assert_array_equal(np.sort(same), np.arange(n))


def test_largest_eigenvalue_is_exact_with_as_many_steps_as_rows():
    from garment_transfer.geometry.poisson import largest_eigenvalue

    rng = np.random.default_rng(3)
    M = rng.normal(size=(30, 30))
    A = sp.csr_matrix(M @ M.T + np.eye(30))
    assert largest_eigenvalue(A, 30) == pytest.approx(np.linalg.eigvalsh(A.toarray())[-1], rel=1e-9)
    # Scaled by D^-1/2 on both sides: the largest eigenvalue of D^-1 A (a Jacobi step's).
    d = A.diagonal()
    exact = np.max(np.linalg.eigvals(A.toarray() / d[:, None]).real)
    assert largest_eigenvalue(A, 30, 1 / np.sqrt(d)) == pytest.approx(exact, rel=1e-9)


def test_largest_eigenvalue_of_a_garment_system_is_estimated_from_below():
    # Ten steps on a real system: below the largest eigenvalue (the smoother's interval reaches past
    # it by CHEBYSHEV_UPPER) and close to it; the same answer every time.
    from garment_transfer.geometry import poisson

    V, F, _ = _garment_pair()
    K = PoissonSolver(V, F, 1e-3, method="multigrid").K
    exact = spla.eigsh(K, k=1, which="LA", return_eigenvectors=False)[0]
    estimate = poisson.largest_eigenvalue(K, poisson.SPECTRUM_STEPS)
    assert 0.8 * exact < estimate <= exact * (1 + 1e-12)
    assert poisson.CHEBYSHEV_UPPER * estimate > exact
    assert poisson.largest_eigenvalue(K, poisson.SPECTRUM_STEPS) == estimate


def test_multigrid_levels_are_galerkin_products():
    # Each coarse level is R A P of the level above with R = P^T, so the V-cycle is symmetric; the levels
    # shrink down to a small coarsest system solved directly.
    V, F, _ = _garment_pair()
    hierarchy = PoissonSolver(V, F, 1e-3, method="multigrid").hierarchy
    levels = hierarchy.levels
    assert len(levels) >= 2
    for (A, R, P, _), below in zip(levels, levels[1:] + [(None,) * 4]):
        assert abs(R - P.T).max() == 0
        coarse = below[0] if below[0] is not None else np.linalg.pinv(hierarchy.coarse)
        np.testing.assert_allclose(sp.csr_matrix(coarse).toarray() if sp.issparse(coarse) else coarse,
                                   (R @ A @ P).toarray(), rtol=0, atol=1e-9 * abs(A).max())
        assert P.shape[1] < P.shape[0] / 2
