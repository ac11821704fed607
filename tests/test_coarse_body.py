"""The decimated source body of the non-rigid fit's first stages, and the faster queries of the fit."""

from pathlib import Path

import numpy as np
import pytest
from meshes import icosphere, random_rotation

from garment_transfer.fitting import alignment, coarse, nonrigid
from garment_transfer.fitting.alignment import align
from garment_transfer.geometry.mesh import mesh_from_triangles
from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.proximity import TriangleSurface, closest_on_triangles

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def sphere():
    # 20,480 triangles, a little squashed so that its principal axes are distinct.
    V, F = icosphere(5)
    return V * np.array([1.0, 0.8, 0.6]), F


def test_a_rigid_motion_is_carried_exactly(sphere):
    # The decimated body moved rigidly, with that rotation at every vertex: each vertex of the source
    # lands where the same motion takes it (its attachment point moves with its triangle, its offset
    # from the surface turns with it).
    X, F = sphere
    body = coarse.CoarseBody.of(X, F, 2000)
    assert body is not None and body.F.shape[0] <= 2000 * coarse.FACES_SLACK
    assert np.abs(body.offset).max() > 1e-4          # the decimated surface is not the source's
    R = random_rotation(np.random.default_rng(4))
    t = np.array([0.3, -2.0, 1.5])
    Y = body.carry(body.X @ R.T + t, np.broadcast_to(R, (body.X.shape[0], 3, 3)))
    assert np.abs(Y - (X @ R.T + t)).max() < 1e-12
    # At rest, the source itself.
    assert np.abs(body.carry(body.X, np.broadcast_to(np.eye(3), (body.X.shape[0], 3, 3))) - X).max() < 1e-13


def test_the_regulariser_weight_follows_the_vertex_count_on_even_meshes():
    # Squared edge lengths sum to about the same at any resolution of one surface (each halving of
    # the edges quadruples their number), so on even meshes the factor is the ratio of the vertex counts.
    Vf, Ff = icosphere(5)
    Vc, Fc = icosphere(3)
    scale = coarse.regulariser_scale(Vf, Ff, Vc, Fc)
    assert scale == pytest.approx(Vc.shape[0] / Vf.shape[0], rel=0.03)
    assert coarse.regulariser_scale(Vf, Ff, Vf, Ff) == pytest.approx(1.0, rel=1e-12)


def test_a_mesh_that_cannot_be_decimated_is_fitted_whole(sphere):
    X, F = sphere
    # Small enough already.
    assert coarse.CoarseBody.of(X, F, F.shape[0]) is None
    # A triangle soup (every face its own vertices, as an unwelded export): libigl cannot collapse it.
    soup = X[F].reshape(-1, 3)
    assert coarse.CoarseBody.of(soup, np.arange(soup.shape[0]).reshape(-1, 3), 2000) is None
    # A non-manifold edge (a fin on one edge): libigl refuses it.
    fin = np.vstack([X, X[F[0]].mean(axis=0) + 0.1])
    assert coarse.CoarseBody.of(fin, np.vstack([F, [[F[0, 0], F[0, 1], X.shape[0]]]]), 2000) is None


def test_the_fit_through_the_decimated_body_is_the_whole_fit():
    # The demo mannequin banana (15,956 triangles) onto the pear (the same mesh, so each vertex's place
    # is known), decimated to 2,000 and 6,000 triangles for the first stages (``LEVELS``), and fitted
    # whole (every stage on it, as a body that cannot be decimated is). Measured: 7.07 and 7.03 mm mean
    # from where the vertices belong (the banana itself 9.11 mm: between mannequins the shapes alone
    # leave the vertices free to slide along the body), the two fits 0.18 mm apart on average.
    banana = read_obj(ROOT / "data" / "demo" / "bodies" / "banana.obj")
    pear = read_obj(ROOT / "data" / "demo" / "bodies" / "pear.obj")
    F = np.asarray(banana.F)
    height = np.ptp(pear.V, axis=0).max()
    coarse_fit = nonrigid.nonrigid_fit(banana.V, F, pear.V, F)
    every_stage = tuple(stage for _, stages in nonrigid.LEVELS for stage in stages)
    whole_fit = nonrigid.nonrigid_fit(banana.V, F, pear.V, F, levels=((None, every_stage),))
    unfitted = np.linalg.norm(banana.V - pear.V, axis=1).mean()
    for X in (coarse_fit, whole_fit):
        assert np.linalg.norm(X - pear.V, axis=1).mean() < 0.85 * unfitted
        assert TriangleSurface(pear.V, F).closest(X)[1].mean() < 1e-3 * height
    assert np.linalg.norm(coarse_fit - whole_fit, axis=1).mean() < 5e-4 * height


def test_levels_that_cannot_be_decimated_leave_their_stages_to_the_finer_one(sphere):
    X, F = sphere
    levels = ((2000, ((100.0, 1),)), (6000, ((10.0, 2),)), (None, ((1.0, 3),)))
    got = nonrigid.decimated_levels(X, F, levels)
    assert [len(level[0]) < X.shape[0] for level in got] == [True, True, False]
    assert [level[2] for level in got] == [((100.0, 1),), ((10.0, 2),), ((1.0, 3),)]
    assert got[0][4] is None and got[1][4].F.shape[0] == got[0][1].shape[0]
    assert got[2][3] == 1.0 and 0 < got[1][3] < 1 and 0 < got[0][3] < got[1][3]
    # 5,120 triangles: not worth 6,000, decimated to 2,000; its 6,000's stages run on the source.
    V, G = icosphere(4)
    got = nonrigid.decimated_levels(V, G, levels)
    assert [level[2] for level in got] == [((100.0, 1),), ((10.0, 2), (1.0, 3))]
    # A triangle soup: every stage on the source, stiff to soft.
    soup = X[F].reshape(-1, 3)
    got = nonrigid.decimated_levels(soup, np.arange(soup.shape[0]).reshape(-1, 3), levels)
    assert len(got) == 1 and got[0][2] == ((100.0, 1), (10.0, 2), (1.0, 3)) and got[0][4] is None
    with pytest.raises(ValueError, match="must end with the source"):
        nonrigid.decimated_levels(X, F, levels[:2])


def test_closest_points_are_those_of_the_exact_query(sphere):
    X, F = sphere
    surface = TriangleSurface(X, F)
    P = np.random.default_rng(1).normal(size=(3000, 3))
    C, d, tri = alignment.closest_points(surface, P)
    C0, d0, tri0, _ = surface.closest(P)
    assert np.abs(d - d0).max() < 1e-12
    assert np.abs(C - C0).max() < 1e-12
    # Where the answer is on an edge or corner the triangle may be another one holding it (not the
    # lowest-numbered one): its own closest point is the same.
    corners = X[F[tri]]
    assert np.abs(closest_on_triangles(P, corners[:, 0], corners[:, 1], corners[:, 2])[0] - C0).max() < 1e-12
    assert (tri != tri0).any() and (tri == tri0).any()


def test_alignment_without_refinement_is_the_samples_pose():
    # The demo mannequin turned, moved and in centimetres: without the refinement against the
    # surfaces, the pose is the sample-to-sample ICP's, within a small share of the height; with it,
    # exact (the default).
    body = read_obj(ROOT / "data" / "demo" / "bodies" / "banana.obj", name="banana")
    R = random_rotation(np.random.default_rng(7))
    moved = mesh_from_triangles(100.0 * body.V @ R.T + np.array([5.0, 1.0, -3.0]), body.F, name="moved")
    height = np.ptp(body.V, axis=0).max()
    rough, _ = align(body, moved, refine=False)
    exact, _ = align(body, moved)
    assert rough.scale == exact.scale == pytest.approx(0.01)
    rough_error = np.abs(rough.apply(moved.V) - body.V).max()
    exact_error = np.abs(exact.apply(moved.V) - body.V).max()
    assert rough_error < 0.01 * height
    assert exact_error < 1e-3 * height and exact_error < 0.5 * rough_error
