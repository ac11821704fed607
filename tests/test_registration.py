"""Registration of the source body onto target bodies of another mesh, units and axes."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from meshes import arms_down, icosphere, require_makehuman

from garment_transfer.errors import RegistrationError, TopologyMismatchError
from garment_transfer.fitting import alignment, cache, nonrigid, registration, shape_basis
from garment_transfer.fitting.alignment import Similarity, align
from garment_transfer.fitting.registration import register
from garment_transfer.geometry.mesh import mesh_from_triangles, triangle_normals
from garment_transfer.geometry.obj import read_obj, write_obj
from garment_transfer.geometry.proximity import TriangleSurface
from garment_transfer.pipeline.any_body import transfer_to_any_body
from garment_transfer.pipeline.transfer import transfer_garment
from lab.registration import remesh

ROOT = Path(__file__).resolve().parents[1]


def rotation(ax, ay, az):
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


@pytest.fixture(scope="module")
def source():
    return read_obj(require_makehuman() / "bodies" / "female_average.obj", name="female_average")


@pytest.fixture(scope="module")
def pear():
    return read_obj(require_makehuman() / "bodies" / "female_pear.obj", name="female_pear")


@pytest.fixture(scope="module")
def pear_remeshed(pear):
    U, G = remesh(pear.V, pear.F, 5000)
    return mesh_from_triangles(U, G, name="female_pear_5k")


@pytest.fixture(scope="module")
def pear_registration(source, pear_remeshed):
    return register(source, pear_remeshed, cache=False)


def test_similarity_inverse_is_exact():
    S = Similarity(2.5, rotation(0.3, -1.1, 2.0), np.array([1.0, -2.0, 0.5]))
    P = np.random.default_rng(0).normal(size=(50, 3))
    assert np.allclose(S.inverse().apply(S.apply(P)), P, atol=1e-12)


@pytest.mark.parametrize("scale, snapped", [(0.6, False), (0.1, True), (25.4, True)])
def test_alignment_recovers_scale_rotation_translation(source, scale, snapped):
    R = rotation(0.4, 2.1, -0.7)
    t = np.array([3.0, -1.5, 12.0])
    moved = mesh_from_triangles(scale * source.V @ R.T + t, source.F, name="moved")
    alignment, info = align(source, moved)
    assert info["snapped"] == snapped
    assert alignment.scale == pytest.approx(1.0 / scale, rel=1e-9)
    back = alignment.apply(moved.V)
    height = np.ptp(source.V, axis=0).max()
    # Trimmed point-to-surface ICP converges linearly: a tenth of a millimetre on this body.
    assert np.abs(back - source.V).max() < 1e-4 * height
    assert np.abs(alignment.R - R.T).max() < 1e-4


def test_alignment_is_never_a_mirror(source):
    # female_average onto a re-mesh of male_average in Blender's frame (metres, Z up): when the two
    # principal frames came with opposite handedness, a mirror candidate won and the fit put the left
    # hand on the right one, within 5 mm of the surface.
    male = read_obj(require_makehuman() / "bodies" / "male_average.obj")
    zup = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    U, G = remesh(0.1 * male.V @ zup.T, male.F, 5000)
    alignment, _ = align(source.with_vertices(0.1 * source.V @ zup.T), mesh_from_triangles(U, G))
    assert np.linalg.det(alignment.R) == pytest.approx(1.0)
    assert np.abs(alignment.R - np.eye(3)).max() < 0.05


def standing_points(toes, feet=True):
    """Points evenly over a standing figure 10 high along z (two legs, a torso, a head) with two feet
    ahead of the shins along ``toes``, or without feet."""
    across = np.cross([0.0, 0.0, 1.0], toes)
    P = []
    a = np.linspace(0.0, 2 * np.pi, 60, endpoint=False)
    parts = ((-1.2, 0.4, 0.0, 5.0), (1.2, 0.4, 0.0, 5.0), (0.0, 1.6, 5.0, 8.5), (0.0, 0.5, 8.5, 10.0))
    for centre, radius, z0, z1 in parts:
        A, Z = np.meshgrid(a, np.linspace(z0, z1, 40))
        ring = np.cos(A.ravel())[:, None] * toes + np.sin(A.ravel())[:, None] * across
        P.append(centre * across + radius * ring + np.outer(Z.ravel(), [0, 0, 1]))
    if feet:
        u, v, w = (g.ravel() for g in np.meshgrid(np.linspace(-0.4, 1.6, 20), np.linspace(-0.4, 0.4, 9),
                                                  np.linspace(0.0, 0.4, 5)))
        for side in (-1.2, 1.2):
            P.append(side * across + u[:, None] * toes + v[:, None] * across + np.outer(w, [0, 0, 1]))
    return np.concatenate(P)


def test_toe_shift_is_how_far_the_feet_lie_ahead_and_nothing_without_feet():
    # Two feet of 20 x 9 x 5 points from 0.4 behind the shin's axis to 1.6 ahead (their mean 0.6 ahead), with the
    # 4 rings of each leg's 60 points at their height (mean 0): the lowest 5% of the height 10; the shins above
    # have their mean on the axes. So the feet lie 1800 * 0.6 / 2280 ahead: a share of 10.
    expected = 1800 * 0.6 / 2280 / 10
    for angle in (0.0, 2.0, 4.0):
        toes = np.array([np.cos(angle), np.sin(angle), 0.0])
        P = standing_points(toes)
        for axis in ((0, 0, 1.0), (0, 0, -1.0)):
            assert alignment.toe_shift(P, np.array(axis), toes) == pytest.approx(expected, abs=1e-12)
            assert alignment.toe_shift(P, np.array(axis), -toes) == pytest.approx(-expected, abs=1e-12)
            across = np.cross([0.0, 0, 1], toes)
            assert alignment.toe_shift(P, np.array(axis), across) is None          # nothing ahead sideways
    assert alignment.toe_shift(standing_points(np.array([1.0, 0, 0]), feet=False), np.array([0, 0, 1.0]),
                               np.array([1.0, 0, 0])) is None


@pytest.mark.parametrize("name", ["heavy", "apple"])
def test_a_heavy_body_of_another_family_is_not_fitted_back_to_front(source, mannequins, name):
    # The closest pose of female_average on these two mannequins was turned round (their belly fits her
    # back about as well as her front): the suits came out back to front, with 874 crossings at the
    # ankles the crossing pass could not clear. The toes decide.
    target = mannequins[name]
    reg = register(source, target, cache=False)
    up, front = np.array([0.0, 0.0, 1.0]), np.array([0.0, -1.0, 0.0])     # the mannequins: Z up, facing -y
    fitted = alignment.surface_samples(reg.V, source.F, 4000, seed=0)[0]
    given = alignment.surface_samples(target.V, target.F, 4000, seed=0)[0]
    assert alignment.toe_shift(given, up, front) > 0
    assert alignment.toe_shift(fitted, up, front) > 0
    # Her nose (the front of her head, +z in MakeHuman's frame) lands on the front of the target's head.
    head = source.V[:, 1] > source.V[:, 1].max() - 2.0
    nose = np.flatnonzero(head)[np.argmax(source.V[head, 2])]
    assert reg.V[nose, 1] < target.V[target.V[:, 2] > 1.45, 1].mean() - 0.05
    assert reg.quality["turned_round"] == 1.0 and reg.quality["toes_source"] * reg.quality["toes_target"] > 0


def test_units_scale_snaps_only_near_a_unit_ratio():
    assert alignment.units_scale(9.3) == (pytest.approx(10.0), True)
    assert alignment.units_scale(1.07) == (pytest.approx(1.0), True)
    assert alignment.units_scale(0.0254 * 0.95) == (pytest.approx(0.0254), True)
    assert alignment.units_scale(1 / 25.4) == (pytest.approx(1 / 25.4), True)
    value, snapped = alignment.units_scale(6.0)
    assert not snapped and value == 6.0


def test_registration_onto_remeshed_target_meets_the_goals(pear, pear_remeshed, pear_registration):
    # Decimetres: 3 mm = 0.03, 8 mm = 0.08 (the goals on a 1.7 m body). The p95 measured 6.2 mm when
    # every edge stopped softening at weight 20 on this coarse target, 3.7 mm with only the edges
    # finer than its facets held (COARSE_FINE).
    err = np.linalg.norm(pear_registration.V - pear.V, axis=1)
    assert err.mean() <= 0.03
    assert np.quantile(err, 0.95) <= 0.05
    q = pear_registration.quality
    assert q["from_target_p95_share"] < registration.LIMITS["p95"]
    assert not pear_registration.cached


def test_transfer_through_registration_is_near_the_true_target(source, pear, pear_remeshed,
                                                               pear_registration):
    garment = read_obj(require_makehuman() / "garments" / "female_sportsuit01" / "female_average.obj")
    truth = transfer_garment(source, pear, garment, method="direct").V
    result, reg = transfer_to_any_body(source, pear_remeshed, garment, registration=pear_registration,
                                       method="direct")
    assert reg is pear_registration
    diff = np.linalg.norm(result.V - truth, axis=1)
    # 3 mm, the goal (3.35 mm measured when every edge of the fit stopped softening at weight 20 on
    # this 5K-triangle target, 2.71 mm with only the edges finer than its facets held).
    assert diff.mean() <= 0.03
    inside = TriangleSurface(pear_remeshed.V, pear_remeshed.F).signed_distance(result.V)[0] < 0
    assert inside.sum() == 0 == result.penetrating_vertices
    assert "registration" in result.info


def test_arap_step_with_one_weight_per_edge_equals_the_scalar_weight(source):
    # The per-edge regulariser (coarse targets, COARSE_FINE) with every edge at one weight is the
    # scalar step; the data terms pull a part of the body away so the step is not the identity.
    rng = np.random.default_rng(3)
    fit = nonrigid.ArapFit(source.V, source.F)
    X = source.V + 0.01 * rng.normal(size=source.V.shape)
    C = source.V + np.array([0.05, 0.0, 0.0]) * (source.V[:, 1:2] > 3.0)
    ws = np.ones(source.n_vertices)
    Bt = nonrigid.sp.csr_matrix((0, source.n_vertices))
    none = np.zeros(0)
    a = fit.solve(X, 20.0, ws, C, Bt, none, np.zeros((0, 3)))
    b = fit.solve(X, np.full(fit.i.shape[0], 20.0), ws, C, Bt, none, np.zeros((0, 3)))
    assert np.abs(a - X).max() > 1e-3
    assert np.abs(a - b).max() < 1e-10
    # Stiffer on one half: that half moves less towards C than with the soft weight everywhere.
    top = source.V[:, 1] > 3.0
    stiff = np.where(top[fit.i] & top[fit.j], 2000.0, 20.0)
    c = fit.solve(X, stiff, ws, C, Bt, none, np.zeros((0, 3)))
    moved = lambda Y: np.linalg.norm(Y[top] - C[top], axis=1).mean()  # noqa: E731
    assert moved(c) > moved(a)


def test_edges_finer_than_a_coarse_target_are_the_hands_feet_and_face(source, pear_remeshed):
    # On a 5K-triangle re-mesh the target's facets are 1-1.8x the source's edges on the torso and
    # limbs, 2-15x on the hands, feet and face (MakeHuman: +-X lateral, Y up; decimetres).
    fit = nonrigid.ArapFit(source.V, source.F)
    surface = TriangleSurface(pear_remeshed.V, pear_remeshed.F)
    fine = nonrigid.finer_than_target(source.V, source.F, fit.i, fit.j, surface)
    mid = 0.5 * (source.V[fit.i] + source.V[fit.j])
    height = (mid[:, 1] - source.V[:, 1].min()) / np.ptp(source.V[:, 1])
    hands = np.abs(mid[:, 0]) > 3.9
    legs = (height > 0.1) & (height < 0.4)
    torso = (height > 0.5) & (height < 0.75) & (np.abs(mid[:, 0]) < 1.2)
    assert fine[hands].mean() > 0.9
    assert fine[height > 0.9].mean() > 0.5
    assert fine[legs].mean() < 0.1 and fine[torso].mean() < 0.35
    # Against the source itself nothing is finer than the target.
    own = TriangleSurface(source.V, source.F)
    assert nonrigid.finer_than_target(source.V, source.F, fit.i, fit.j, own).mean() < 0.02


def test_global_fit_keeps_the_height_of_a_thinner_body(source):
    # The source made 15% narrower and shallower (same height) and moved: the similarity must keep
    # the height and put the soles on the soles. Fitted to closest points instead, it shrinks the
    # whole body towards the thinner one (its legs then sit too high).
    thin = source.V * np.array([0.85, 1.0, 0.85]) + np.array([0.3, -0.5, 0.2])
    surface = TriangleSurface(thin, source.F)
    P = alignment.surface_samples(thin, source.F, 8000, seed=0)[0]
    Y = nonrigid.global_fit(source.V, source.F, surface, P)
    height = np.ptp(thin[:, 1])
    assert np.ptp(Y[:, 1]) == pytest.approx(height, rel=1e-3)
    assert abs(Y[:, 1].min() - thin[:, 1].min()) < 1e-3 * height


def test_registration_onto_a_thinner_body_of_the_same_height(source):
    # female_slim_banana is female_average's height: on its 5K-triangle re-mesh the fit measured
    # 6.8 mm mean vertex error when the global scale came from closest points (1.8% too small),
    # 2.7 mm with the scale from the heights, 2.5 mm with the soft stages on the torso and limbs.
    # Decimetres: 0.035 = 3.5 mm.
    banana = read_obj(require_makehuman() / "bodies" / "female_slim_banana.obj", name="female_slim_banana")
    U, G = remesh(banana.V, banana.F, 5000)
    reg = register(source, mesh_from_triangles(U, G, name="female_slim_banana_5k"), cache=False)
    err = np.linalg.norm(reg.V - banana.V, axis=1)
    assert err.mean() <= 0.035
    assert np.ptp(reg.V[:, 1]) == pytest.approx(np.ptp(banana.V[:, 1]), rel=2e-3)


def test_registration_onto_a_wider_body_keeps_its_correspondence(source, pear):
    # female_pear is wider at the hips and thighs: the closest-point fit reached them by sliding the
    # tapered limbs along the target (0.91 mm mean vertex error, a garment 3.24 mm from its transfer
    # through the true body); held at their heights it measured 0.69 and 2.48 mm. Decimetres.
    U, G = remesh(pear.V, pear.F, 50000)
    target = mesh_from_triangles(U, G, name="female_pear_50k")
    reg = register(source, target, cache=False)
    assert np.linalg.norm(reg.V - pear.V, axis=1).mean() <= 0.008
    garment = read_obj(require_makehuman() / "garments" / "female_casualsuit01" / "female_average.obj")
    truth = transfer_garment(source, pear, garment, method="direct").V
    result, _ = transfer_to_any_body(source, target, garment, registration=reg, method="direct")
    assert np.linalg.norm(result.V - truth, axis=1).mean() <= 0.028


def test_part_similarity_recovers_a_scaled_turned_hand(source):
    # The right hand (MakeHuman: +X lateral) and a similarity of it: scale 1.2 (a male hand is a
    # female one scaled by 1.21), turned 0.2 rad, moved; the fit starts from another similarity.
    idx = np.flatnonzero(source.V[:, 0] > 3.9)
    local = np.full(source.n_vertices, -1)
    local[idx] = np.arange(idx.size)
    Fp = local[source.F]
    Fp = Fp[(Fp >= 0).all(axis=1)]
    Y0 = source.V[idx]
    truth = Similarity(1.2, rotation(0.2, -0.1, 0.15), np.array([0.3, -0.2, 0.1])).apply(Y0)
    P, tri, _ = alignment.surface_samples(truth, Fp, 20000, seed=1)
    Np = triangle_normals(truth, Fp)[0][tri]
    start = Similarity(1.1, rotation(0.15, -0.05, 0.1), np.array([0.25, -0.1, 0.0])).apply(Y0)
    Y, scale = nonrigid.part_similarity(Y0, Fp, np.ones(idx.size, bool), start, P, Np, iterations=50)
    assert scale == pytest.approx(1.2, rel=1e-6)
    assert np.abs(Y - truth).max() < 1e-6 * np.ptp(Y0, axis=0).max()


@pytest.mark.parametrize("size", [50000])
def test_registration_onto_a_remeshed_male_body(source, size):
    # Another family (female_average onto male_average): the vertex correspondence of MakeHuman's
    # male shape is not found from shape alone on the torso and legs (docs/registration.md), but the
    # hands, 24% of the vertices, change by a similarity and must follow it (10 mm before the part
    # fits, 0.4 mm measured with them). Decimetres: 0.1 = 10 mm.
    male = read_obj(require_makehuman() / "bodies" / "male_average.obj", name="male_average")
    U, G = remesh(male.V, male.F, size)
    reg = register(source, mesh_from_triangles(U, G, name="male_average_50k"), cache=False)
    err = np.linalg.norm(reg.V - male.V, axis=1)
    hands = np.abs(source.V[:, 0]) > 3.9
    assert err[hands].mean() <= 0.02
    assert err.mean() <= 0.10
    assert reg.quality["from_target_p95_share"] < registration.LIMITS["p95"]


def test_mitten_hands_of_another_family_are_not_fitted_as_parts(source):
    # The procedural mannequin (metres, mitten hands) onto MakeHuman: a similarity of its hand onto
    # MakeHuman's fingers moves it 6% of the height and, kept, flips 2% of the triangles (refused).
    mannequin = read_obj(ROOT / "data" / "demo" / "bodies" / "banana.obj", name="mannequin_banana")
    reg = register(mannequin, source, cache=False)
    assert reg.quality["distorted"] < 0.005
    assert reg.quality["units_scale"] == pytest.approx(0.1)


def test_same_mesh_is_not_registered(source, pear):
    garment = read_obj(require_makehuman() / "garments" / "female_sportsuit01" / "female_average.obj")
    result, reg = transfer_to_any_body(source, pear, garment, method="surface")
    assert reg is None and "registration" not in result.info


def test_a_sphere_is_refused_naming_the_figure(source):
    V, F = icosphere(4, radius=8.0)
    with pytest.raises(RegistrationError, match="sphere.*aspect ratio"):
        register(source, mesh_from_triangles(V, F, name="sphere"), cache=False)


def test_a_body_without_feet_is_fitted_and_said_to_be_undecided(source, pear, caplog):
    # Cut off above the ankles: nothing tells its front from its back but the closest fit.
    height = np.ptp(pear.V[:, 1])
    keep = np.all(pear.V[pear.F, 1] > pear.V[:, 1].min() + 0.12 * height, axis=1)
    used, F = np.unique(pear.F[keep], return_inverse=True)
    cut = mesh_from_triangles(pear.V[used], F.reshape(-1, 3), name="pear_without_feet")
    assert alignment.toe_shift(alignment.surface_samples(cut.V, cut.F, 4000)[0], np.array([0.0, 1, 0]),
                               np.array([0.0, 0, 1])) is None
    with caplog.at_level("WARNING", logger="garment_transfer.fitting.registration"):
        reg = register(source, cut, cache=False, check=False)
    assert "toes_target" not in reg.quality and reg.quality["turned_round"] == 0.0
    said = [r.getMessage() for r in caplog.records]
    assert any("pear_without_feet: no feet found" in m and "back to front" in m for m in said)
    caplog.clear()
    with caplog.at_level("WARNING", logger="garment_transfer.fitting.registration"):
        register(source, pear.with_vertices(pear.V + 1.0, name="pear_moved"), cache=False, check=False)
    assert not caplog.records                                   # feet on both: nothing to say


def test_another_pose_is_refused_naming_the_figure(source, tmp_path):
    target = mesh_from_triangles(arms_down(source.V), source.F, name="arms_down")
    with pytest.raises(RegistrationError, match=r"arms_down: registration failed: the .*(percentile|largest"
                                                r"|stretched).*limit"):
        register(source, target, cache=tmp_path)
    assert list(tmp_path.iterdir()) == []       # a refused fit is not cached


def test_cache_round_trip_and_off_switch(source, pear_remeshed, pear_registration, tmp_path, monkeypatch):
    settings = {"levels": [[faces, [list(s) for s in stages]] for faces, stages in nonrigid.LEVELS]}
    key = cache.cache_key(source, pear_remeshed, settings, registration.ALGORITHM_VERSION)
    cache.save_cached(str(tmp_path), key, *pear_registration.cache_entry())
    hit = register(source, pear_remeshed, cache=str(tmp_path))
    assert hit.cached
    assert np.array_equal(hit.V, pear_registration.V)
    assert hit.quality == pytest.approx(pear_registration.quality)
    assert np.allclose(hit.alignment.R, pear_registration.alignment.R)
    # Another target (one vertex moved) misses the cache.
    V = pear_remeshed.V.copy()
    V[0, 0] += 1e-9
    assert cache.cache_key(source, pear_remeshed.with_vertices(V), {}, 1) != \
        cache.cache_key(source, pear_remeshed, {}, 1)
    monkeypatch.setenv("GARMENT_TRANSFER_CACHE", "off")
    assert cache.cache_folder() is None
    monkeypatch.setenv("GARMENT_TRANSFER_CACHE", str(tmp_path / "c"))
    assert cache.cache_folder() == str(tmp_path / "c")
    monkeypatch.delenv("GARMENT_TRANSFER_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache.cache_folder() == str(tmp_path / "xdg" / "garment_transfer" / "registration")


def test_cache_file_is_plain_npz(pear_registration, tmp_path):
    cache.save_cached(str(tmp_path), "k", *pear_registration.cache_entry())
    with np.load(tmp_path / "k.npz", allow_pickle=False) as z:
        assert set(z.files) == {"V", "V_source_frame", "meta"}
        assert json.loads(str(z["meta"]))["quality"]["height"] > 0


def run(*args, env=None):
    return subprocess.run([sys.executable, "-m", "garment_transfer", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=600, env=env)


def test_cli_register_and_transfer_any_target(source, pear_remeshed, tmp_path):
    import os

    # The target in metres and Z up: another family's conventions.
    Rz = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    target = tmp_path / "pear_m_zup.obj"
    write_obj(target, pear_remeshed.with_vertices(0.1 * pear_remeshed.V @ Rz.T + [0.5, 0.0, 0.0]))
    env = dict(os.environ, GARMENT_TRANSFER_CACHE=str(tmp_path / "cache"), PYTHONPATH=str(ROOT))
    src = require_makehuman() / "bodies" / "female_average.obj"
    out = tmp_path / "fit.obj"
    p = run("register", "--source-body", src, "--target-body", target, "--out", out, "--json", env=env)
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    assert data["alignment"]["scale"] == 10.0 and not data["cached"]
    fitted = read_obj(out)
    assert fitted.n_vertices == source.n_vertices
    assert np.array_equal(fitted.face_vertices, source.face_vertices)
    assert np.ptp(fitted.V[:, 2]) > np.ptp(fitted.V[:, 1])      # Z up, as the target

    garment = require_makehuman() / "garments" / "female_sportsuit01" / "female_average.obj"
    result = tmp_path / "on_pear.obj"
    p = run("transfer", "--source-body", src, "--target-body", target, "--garment", garment,
            "--out", result, "--json", env=env)
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    assert data["registered"] and data["info"]["registration"]["cached"]
    assert data["penetrating_vertices"] == 0
    assert "from_target_p95" in data["info"]["registration"]["quality"]
    moved = read_obj(result)
    assert np.ptp(moved.V[:, 2]) > np.ptp(moved.V[:, 1])


def test_cli_register_refusal_writes_nothing(tmp_path):
    sphere = tmp_path / "sphere.obj"
    V, F = icosphere(3, radius=8.0)
    write_obj(sphere, mesh_from_triangles(V, F))
    out = tmp_path / "fit.obj"
    src = require_makehuman() / "bodies" / "female_average.obj"
    p = run("register", "--source-body", src, "--target-body", sphere, "--out", out, "--no-cache")
    assert p.returncode == 1
    assert "sphere.obj" in p.stderr and "aspect ratio" in p.stderr
    assert not out.exists() and [f.name for f in tmp_path.iterdir()] == ["sphere.obj"]


# --- shape basis (a linear shape space of the source body fitted before the non-rigid stages) ---

@pytest.fixture(scope="module")
def mannequins():
    """The demo's procedural mannequins: one mesh in six shapes (metres, Z up)."""
    return {n: read_obj(ROOT / "data" / "demo" / "bodies" / f"{n}.obj", name=n)
            for n in ("banana", "pear", "heavy", "slim", "apple")}


def shuffled_and_moved(V, F, name, seed=3):
    """The same surface as another mesh: vertex order shuffled, in decimetres and Y up."""
    perm = np.random.default_rng(seed).permutation(V.shape[0])
    inv = np.empty_like(perm)
    inv[perm] = np.arange(perm.size)
    R = rotation(-np.pi / 2, 0.0, 0.3)
    return mesh_from_triangles(10.0 * V[perm] @ R.T + [1.0, 2.0, -3.0], inv[F], name=name)


@pytest.fixture(scope="module")
def blend_case(mannequins):
    source = mannequins["banana"]
    basis = shape_basis.shape_basis_from_bodies(source, [mannequins[n] for n in ("pear", "heavy", "slim")])
    weights = np.array([0.3, 0.6, 0.2])
    V = source.V + np.tensordot(weights, basis, axes=1)
    return source, basis, weights, V, shuffled_and_moved(V, source.F, "blend")


def test_shape_fit_recovers_the_weights_of_an_exact_blend(blend_case):
    source, basis, weights, V, target = blend_case
    # The target in the source's frame (the alignment's job), its vertices in another order.
    back = (target.V - [1.0, 2.0, -3.0]) @ rotation(-np.pi / 2, 0.0, 0.3) / 10.0
    w, X, info = shape_basis.fit_shape(source.V, source.F, basis, back, target.F)
    assert info["used"] and info["explained"] > 0.999
    assert np.abs(w - weights).max() < 1e-4
    assert np.abs(X - V).max() < 1e-4 * np.ptp(V, axis=0).max()


def test_registration_with_a_shape_basis_reaches_an_exact_blend(blend_case, tmp_path):
    source, basis, weights, V, target = blend_case
    reg = register(source, target, shape_basis=basis, cache=tmp_path)
    # The fit follows the target in its own frame (the alignment's own error, about 1e-3 of the height
    # on this body, is undone with it); the weights come from the aligned target.
    assert np.abs(reg.shape_weights - weights).max() < 2e-3
    truth = 10.0 * V @ rotation(-np.pi / 2, 0.0, 0.3).T + [1.0, 2.0, -3.0]
    height = np.ptp(truth, axis=0).max()
    err = np.linalg.norm(reg.V - truth, axis=1)
    assert err.mean() < 1e-4 * height and err.max() < 1e-3 * height
    assert reg.quality["shape_used"] == 1.0
    # Cached under its own key: read back with its weights; without the basis it is another entry.
    hit = register(source, target, shape_basis=basis, cache=tmp_path)
    assert hit.cached and np.array_equal(hit.shape_weights, reg.shape_weights)
    assert hit.summary()["shape_weights"] == pytest.approx(reg.shape_weights.tolist())
    plain = register(source, target, cache=tmp_path)
    assert not plain.cached and plain.shape_weights is None
    assert len(list(tmp_path.glob("*.npz"))) == 2
    # Without the basis the surfaces decide the correspondence: farther from the blend's vertices.
    assert np.linalg.norm(plain.V - truth, axis=1).mean() > 10 * err.mean()


def test_a_zero_basis_gives_the_result_without_one(mannequins):
    source = mannequins["banana"]
    target = shuffled_and_moved(mannequins["pear"].V, source.F, "pear_moved")
    plain = register(source, target, cache=False)
    zero = register(source, target, shape_basis=np.zeros((2, source.n_vertices, 3)), cache=False)
    assert np.array_equal(zero.V, plain.V)
    assert np.array_equal(zero.shape_weights, [0.0, 0.0]) and zero.quality["shape_used"] == 0.0


@pytest.mark.parametrize("basis, message", [
    (np.zeros((7980, 3)), r"one delta.*basis\[None\]"),
    (np.zeros((2, 100, 3)), "100 vertices but the source body has 7980"),
    (np.zeros((2, 7980, 2)), "2 coordinates per vertex, not 3"),
    (np.zeros((0, 7980, 3)), "no deltas"),
    (np.zeros((2, 7980)), r"\(k, 7980, 3\).*shape \(2, 7980\)"),
    (np.full((2, 7980, 3), np.nan), "delta 0 has NaN"),
    ([["a"]], "not an array of numbers"),
])
def test_a_bad_shape_basis_is_refused_naming_the_problem(mannequins, basis, message):
    source = mannequins["banana"]
    with pytest.raises(ValueError, match=message):
        register(source, mannequins["pear"], shape_basis=basis, cache=False)


def test_bad_bounds_and_a_basis_body_of_another_mesh_are_refused(mannequins, source):
    banana = mannequins["banana"]
    basis = np.zeros((2, banana.n_vertices, 3))
    with pytest.raises(ValueError, match="bounds must be"):
        register(banana, mannequins["pear"], shape_basis=basis, shape_bounds=(0.5, 1.0), cache=False)
    with pytest.raises(ValueError, match=r"one \(low, high\) per delta \(2\)"):
        register(banana, mannequins["pear"], shape_basis=basis, shape_bounds=np.zeros((3, 2)), cache=False)
    with pytest.raises(TopologyMismatchError, match="female_average: has 13380 vertices"):
        shape_basis.shape_basis_from_bodies(banana, [mannequins["pear"], source])


def leave_one_out_basis(source, target_name):
    """Deltas of the other MakeHuman bodies from the source: never the target body itself."""
    folder = require_makehuman() / "bodies"
    others = [n for n in ("female_slim_banana", "female_pear", "male_average", "male_slim") if n != target_name]
    return others, shape_basis.shape_basis_from_bodies(source, [read_obj(folder / f"{n}.obj", name=n)
                                                                 for n in others])


def test_leave_one_out_prior_carries_the_male_correspondence(source):
    # male_average re-meshed (5K triangles, shuffled); the basis holds male_slim but never
    # male_average. Without the prior the fit measured 15.8 mm mean, 34 mm p95 (its legs slide along
    # the target); with it 3.2 / 6.6 mm. Decimetres.
    male = read_obj(require_makehuman() / "bodies" / "male_average.obj", name="male_average")
    U, G = remesh(male.V, male.F, 5000)
    names, basis = leave_one_out_basis(source, "male_average")
    reg = register(source, mesh_from_triangles(U, G, name="male_average_5k"), shape_basis=basis, cache=False)
    err = np.linalg.norm(reg.V - male.V, axis=1)
    assert err.mean() <= 0.05 and np.quantile(err, 0.95) <= 0.10
    assert reg.quality["shape_used"] == 1.0 and reg.quality["shape_explained"] > 0.7
    assert reg.shape_weights[names.index("male_slim")] > 0.5


def test_leave_one_out_prior_that_does_not_hold_the_target_is_not_used(source):
    # female_slim_banana against a basis of female_pear and the two male bodies: the best blend
    # borrows a slim male's proportions (about 0.4 of male_slim, scaled down) and removes only 20% of
    # the misfit; used, it doubled the vertex error (1.7 -> 3.9 mm at 50K triangles).
    banana = read_obj(require_makehuman() / "bodies" / "female_slim_banana.obj", name="female_slim_banana")
    U, G = remesh(banana.V, banana.F, 5000)
    target = mesh_from_triangles(U, G, name="female_slim_banana_5k")
    names, basis = leave_one_out_basis(source, "female_slim_banana")
    T = align(source, target)[0].apply(target.V)
    w, X, info = shape_basis.fit_shape(source.V, source.F, basis, T, target.F)
    assert info["fitted_weights"][names.index("male_slim")] > 0.2
    assert info["explained"] < shape_basis.SHAPE_MIN_EXPLAINED
    assert not info["used"] and np.array_equal(w, np.zeros(3)) and np.array_equal(X, source.V)


def test_cli_register_with_a_shape_basis(blend_case, tmp_path):
    source, basis, weights, V, target = blend_case
    bodies = ROOT / "data" / "demo" / "bodies"
    tgt = tmp_path / "blend.obj"
    write_obj(tgt, target)
    out = tmp_path / "fit.obj"
    p = run("register", "--source-body", bodies / "banana.obj", "--target-body", tgt, "--out", out,
            "--shape-basis", bodies / "pear.obj", bodies / "heavy.obj", bodies / "slim.obj", "--no-cache", "--json")
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    assert np.abs(np.array(data["shape_weights"]) - weights).max() < 2e-3
    assert data["quality"]["shape_used"] == 1.0 and len(data["shape_basis"]) == 3
    assert read_obj(out).n_vertices == source.n_vertices


def test_cli_refuses_a_shape_basis_of_another_mesh_writing_nothing(tmp_path):
    bodies = ROOT / "data" / "demo" / "bodies"
    other = tmp_path / "other.obj"
    V, F = icosphere(2)
    write_obj(other, mesh_from_triangles(V, F))
    garment = ROOT / "data" / "demo" / "garments" / "tshirt" / "banana.obj"
    out = tmp_path / "r.obj"
    p = run("transfer", "--source-body", bodies / "banana.obj", "--target-body", bodies / "pear.obj",
            "--garment", garment, "--out", out, "--shape-basis", bodies / "slim.obj", other, "--no-cache")
    assert p.returncode == 1
    assert "other.obj" in p.stderr and "shape basis body must be the source body's mesh" in p.stderr
    assert not out.exists()


def test_polar_rotations_are_the_svd_rotations():
    """The ARAP rotations by Newton's polar iteration equal the SVD's (det > 0), and the SVD decides
    reflections (det < 0), singular and zero matrices."""
    rng = np.random.default_rng(5)
    U = np.linalg.qr(rng.normal(size=(400, 3, 3)))[0]
    V = np.linalg.qr(rng.normal(size=(400, 3, 3)))[0]
    V[::2, :, 0] *= -1
    # Conditions up to about 1e5, either sign of the determinant.
    S = np.einsum("nij,nj,nkj->nik", U, np.exp(rng.normal(0.0, 2.0, (400, 3))), V)
    S[:5] = 0.0
    S[5] = np.outer([1.0, 0, 0], [0, 1.0, 0])
    S[6] = np.diag([1.0, 1.0, 0.0])
    S[7] = -np.eye(3)
    S[8] = np.diag([1.0, 1.0, -1e-9])
    R = nonrigid.best_rotations(S)
    expected = nonrigid.svd_rotations(S.copy())
    assert np.abs(R - expected).max() < 1e-12
    assert np.abs(np.linalg.det(R) - 1.0).max() < 1e-12
    assert (np.linalg.det(S[9:]) < 0).any() and (np.linalg.det(S[9:]) > 0).any()


def test_arap_solve_matches_a_direct_solve(source):
    """The ARAP step factored in the order found once gives the solution of its linear system."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    X0, F = source.V, np.asarray(source.F)
    fit = nonrigid.ArapFit(X0, F)
    rng = np.random.default_rng(2)
    X = X0 + rng.normal(0.0, 1e-3, X0.shape)
    P = X0[rng.choice(X0.shape[0], 500, replace=False)] + rng.normal(0.0, 1e-3, (500, 3))
    Np = np.tile([0.0, 0.0, 1.0], (500, 1))
    B, wt, _ = nonrigid.pairs_from_target(X, F, P, Np, -2.0, np.inf)
    ws = rng.random(X0.shape[0])
    C = X0 + rng.normal(0.0, 1e-3, X0.shape)
    for alpha in (200.0, 1.0):
        got = fit.solve(X, alpha, ws, C, B, wt, P)
        R = nonrigid.svd_rotations(np.asarray(
            fit.both @ np.einsum("ka,kb->kab", fit.e0, X[fit.i] - X[fit.j]).reshape(-1, 9)).reshape(-1, 3, 3))
        eps = 1e-8 * (alpha * 8.0 + 1.0)
        A = 2 * alpha * fit.L + sp.diags(ws) + B.T @ sp.diags(wt) @ B + eps * sp.identity(fit.n)
        rhs = 2 * alpha * fit.arap_rhs(R) + ws[:, None] * C + B.T @ (wt[:, None] * P) + eps * X
        want = spla.spsolve(A.tocsc(), rhs)
        assert np.abs(got - want).max() < 1e-9 * np.abs(want).max()


def test_bodies_with_inward_faces_are_fitted_as_the_same_bodies_facing_outward(source, pear_remeshed, monkeypatch):
    # The fit compares normals: a source or target written with the other winding must give it the very same
    # surfaces (it failed before: "registration failed ... same pose?" for a turned source body).
    from garment_transfer.geometry.mesh import turned_around
    from garment_transfer.geometry.proximity import orientation

    class Fitted(Exception):
        pass

    seen = []

    def fit(start, F, T, G, **kwargs):
        seen.append((start, F, T, G))
        raise Fitted

    monkeypatch.setattr(registration, "nonrigid_fit", fit)
    for s, t in ((source, pear_remeshed), (turned_around(source), pear_remeshed),
                 (source, turned_around(pear_remeshed)), (turned_around(source), turned_around(pear_remeshed))):
        with pytest.raises(Fitted):
            register(s, t, cache=False)
    assert orientation(source.V, source.F) == orientation(pear_remeshed.V, pear_remeshed.F) == 1
    for other in seen[1:]:
        for a, b in zip(seen[0], other):
            np.testing.assert_array_equal(a, b)
