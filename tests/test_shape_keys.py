"""Shape keys in the core: one preparation, every key exactly its transfer, correctives, weights, CLI."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from meshes import icosphere

from garment_transfer.errors import MeshError
from garment_transfer.geometry.mesh import mesh_from_triangles
from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.proximity import TriangleSurface
from garment_transfer.geometry.embedding import body_scale
from garment_transfer.pipeline.shape_keys import (MIX_LIFT_RADIUS, SHAPE_KEY_BANDS, ShapeKeyFit, body_at,
                                                  fit_shape_keys, hanging_bands, keep_outside, keep_outside_banded,
                                                  keep_outside_bands, mix_excess, mix_lift, pair_warnings,
                                                  self_crossing_pairs, transfer_to_shapes)
from garment_transfer.pipeline.transfer import prepare_garment, transfer_garment
from garment_transfer import surface_weights
from lab.paths import makehuman_folder

ROOT = Path(__file__).resolve().parents[1]
KEYS = ("female_pear", "male_slim")


@pytest.fixture(scope="module")
def keyed():
    folder = makehuman_folder()
    if folder is None:
        pytest.skip("MakeHuman fixtures not found")
    basis = read_obj(folder / "bodies" / "female_average.obj")
    shapes = {k: read_obj(folder / "bodies" / f"{k}.obj").V for k in KEYS}
    garment = read_obj(folder / "garments" / "female_casualsuit01" / "female_average.obj")
    prepared = prepare_garment(basis, garment)
    fit = fit_shape_keys(basis, shapes, garment, prepared=prepared, pairs=[KEYS])
    return basis, shapes, garment, prepared, fit, folder


def test_each_key_at_one_is_exactly_the_transfer_to_that_shape_and_nothing_is_inside(keyed):
    basis, shapes, garment, prepared, fit, _ = keyed
    for name, V in shapes.items():
        body = basis.with_vertices(V)
        reused = transfer_garment(basis, body, garment, prepared=prepared).V
        assert np.array_equal(fit.keys[name], reused)
        assert np.abs(fit.blend({name: 1.0}) - fit.keys[name]).max() < 1e-12     # rounding only
        cold = transfer_garment(basis, body, garment).V
        assert np.abs(fit.keys[name] - cold).max() < 1e-9
        assert (TriangleSurface(V, basis.F).signed_distance(fit.keys[name])[0] < 0).sum() == 0
    # Every slider at 0: the garment on the basis, which had vertices inside (the fixture's skin-tight
    # parts) and now has none.
    assert (TriangleSurface(basis.V, basis.F).signed_distance(garment.V)[0] < 0).sum() > 0
    assert np.array_equal(fit.blend({}), fit.basis)
    assert (TriangleSurface(basis.V, basis.F).signed_distance(fit.basis)[0] < 0).sum() == 0


def test_a_corrective_pair_makes_both_keys_at_one_exact(keyed):
    basis, shapes, garment, prepared, fit, _ = keyed
    both = body_at(basis.V, shapes, {k: 1.0 for k in KEYS})
    exact = transfer_garment(basis, basis.with_vertices(both), garment, prepared=prepared).V
    assert np.abs(fit.blend({k: 1.0 for k in KEYS}) - exact).max() < 1e-12
    linear = fit.blend({k: 1.0 for k in KEYS}, correctives=False)
    assert np.abs(linear - exact).max() > 1e-4              # the linear blend alone is not exact
    half = fit.blend({k: 0.5 for k in KEYS})
    assert np.allclose(half, fit.blend({k: 0.5 for k in KEYS}, correctives=False)
                       + 0.25 * fit.correctives[KEYS])


def test_the_lift_of_a_mix_is_zero_within_the_fitted_shapes_and_outward_by_the_sagitta_of_the_longest_edge():
    assert mix_excess({}) == mix_excess({"a": 1.0}) == mix_excess({"a": 0.4, "b": 0.6}) == 0.0
    assert mix_excess({"a": 0.9, "b": 0.8, "c": -0.5}) == pytest.approx(0.2)
    assert mix_excess({"a": 1.5, "b": -0.7}) == 0.0          # negative values count negatively, as a Sum driver
    # A round body and a garment over it: the lift is along the body's outward normal at each vertex's closest point
    # (here the radial direction) and its length the longest edge's square over 8 r.
    V, F = icosphere(3)
    body = mesh_from_triangles(V, F, "body")
    G, GF = icosphere(1, radius=1.1)
    garment = mesh_from_triangles(G, GF, "garment")
    lift = mix_lift(body, garment, G)
    E = np.concatenate([GF[:, [0, 1]], GF[:, [1, 2]], GF[:, [2, 0]]])
    longest = np.zeros(len(G))
    np.maximum.at(longest, E[:, 0], np.linalg.norm(G[E[:, 0]] - G[E[:, 1]], axis=1))
    expected = longest ** 2 / (8 * MIX_LIFT_RADIUS * body_scale(V))
    np.testing.assert_allclose(np.linalg.norm(lift, axis=1), expected, rtol=1e-12)
    radial = G / np.linalg.norm(G, axis=1)[:, None]
    normal = lift / np.linalg.norm(lift, axis=1)[:, None]
    assert np.einsum("ij,ij->i", normal, radial).min() > 0.99
    # Blended: nothing at the basis, at a key at 1 or at a mix adding up to 1; beyond, the excess times the lift.
    key = G * 1.2
    fit = ShapeKeyFit(G, {"a": key, "b": G + [0.1, 0, 0]}, lift=lift)
    assert np.array_equal(fit.blend({}), G) and np.array_equal(fit.blend({"a": 1.0}), key)
    np.testing.assert_allclose(fit.blend({"a": 0.5, "b": 0.5}), fit.blend({"a": 0.5, "b": 0.5}, lift=False), atol=0)
    w = {"a": 0.9, "b": 0.7}
    np.testing.assert_allclose(fit.blend(w) - fit.blend(w, lift=False), 0.6 * lift, rtol=1e-12, atol=1e-15)
    # A fit lifts from its basis; not with corrective pairs (exact at both keys at 1), nor when asked not to.
    shapes = {"big": V * 1.05, "long": V * [1.0, 1.0, 1.08]}
    fitted = fit_shape_keys(body, shapes, garment)
    np.testing.assert_array_equal(fitted.lift, mix_lift(body, garment, fitted.basis))
    assert fit_shape_keys(body, shapes, garment, pairs=[("big", "long")]).lift is None
    assert fit_shape_keys(body, shapes, garment, lift=False).lift is None


def test_a_pair_of_keys_whose_body_crosses_itself_only_together_is_found():
    from garment_transfer.geometry.intersections import self_intersections
    from garment_transfer.geometry.readings import readings_of

    # Two balls 3 apart; each key brings one of them 0.7 nearer: alone they stay apart, together they overlap.
    V1, F1 = icosphere(2)
    V = np.vstack([V1, V1 + [3.0, 0, 0]])
    F = np.vstack([F1, F1 + len(V1)])
    body = mesh_from_triangles(V, F, "balls")
    n = len(V1)
    shapes = {"left": V + np.where(np.arange(2 * n)[:, None] < n, [0.7, 0, 0], 0.0),
              "right": V - np.where(np.arange(2 * n)[:, None] >= n, [0.7, 0, 0], 0.0),
              "up": V + [0, 0.5, 0]}
    both = shapes["left"] + shapes["right"] - V
    expected = self_intersections(both, readings_of(body))[0]
    assert expected > 0 and self_intersections(shapes["left"], readings_of(body))[0] == 0
    garment = np.vstack([V1 * 1.05, V1 * 1.05 + [3.0, 0, 0]])
    assert self_crossing_pairs(body, shapes, garment, 0.01) == [("left", "right", expected)]
    assert self_crossing_pairs(body, shapes, garment, 0.01, least=expected + 1) == []
    # Keys that move nothing under the garment are not paired (a garment far away: none).
    assert self_crossing_pairs(body, shapes, garment + [100.0, 0, 0], 0.01) == []
    fit = ShapeKeyFit(V, {}, info={"self_crossing_pairs": [{"keys": ["left", "right"], "new_crossings": expected}]})
    (warning,) = pair_warnings(fit, "balls")
    assert "left and right both at 1 crosses itself" in warning and str(expected) in warning


def test_transfer_to_shapes_gives_positions_per_shape(keyed):
    basis, shapes, garment, prepared, fit, _ = keyed
    positions, info = transfer_to_shapes(basis, shapes, garment, prepared=prepared)
    assert set(positions) == set(KEYS)
    for k in KEYS:
        assert np.array_equal(positions[k], fit.keys[k])
        assert info[k]["penetrating_vertices"] == 0
    # The margin is added to the distance the penetration fix keeps (the crossing pass, which may move
    # single vertices a little closer to remove an edge crossing, is left out to see it exactly).
    margin = fit_shape_keys(basis, {"female_pear": shapes["female_pear"]}, garment, prepared=prepared,
                            margin=0.02, resolve_crossings=False)
    d = TriangleSurface(shapes["female_pear"], basis.F).signed_distance(margin.keys["female_pear"])[0]
    assert d.min() > fit.info["female_pear"]["offset"] + 0.02 - 1e-6


def test_shapes_are_checked_against_the_basis(keyed):
    basis, shapes, garment, prepared, _, _ = keyed
    with pytest.raises(MeshError, match="key short: has 10 vertices"):
        fit_shape_keys(basis, {"short": basis.V[:10]}, garment, prepared=prepared)
    bad = basis.V.copy()
    bad[3, 0] = np.nan
    with pytest.raises(MeshError, match="key nan: has NaN"):
        fit_shape_keys(basis, {"nan": bad}, garment, prepared=prepared)
    with pytest.raises(MeshError, match="has no shape keys"):
        fit_shape_keys(basis, {}, garment, prepared=prepared)
    with pytest.raises(ValueError, match="no shape key 'hips'"):
        fit_shape_keys(basis, shapes, garment, prepared=prepared, pairs=[("female_pear", "hips")])


def test_keep_outside_moves_only_what_is_too_close():
    V, F = icosphere(3)
    surface = TriangleSurface(V, F)
    P = np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 1.5], [0.0, 0.0, 1.01]])
    out = keep_outside(P, surface, 0.05)
    assert np.array_equal(out[1], P[1])
    sd = surface.signed_distance(out)[0]
    assert np.allclose(sd[[0, 2]], 0.05)


def test_keep_outside_limited_to_some_vertices_leaves_the_others():
    V, F = icosphere(3)
    surface = TriangleSurface(V, F)
    P = np.array([[0.0, 0.0, 0.5], [0.0, 0.5, 0.0], [0.0, 0.0, 1.01]])
    out = keep_outside(P, surface, 0.05, only=np.array([True, False, True]))
    assert np.array_equal(out[1], P[1])
    assert np.allclose(surface.signed_distance(out)[0][[0, 2]], 0.05)


def test_keep_outside_bands_move_no_key_at_one_and_keep_a_mix_as_far_as_its_band(keyed):
    basis, shapes, garment, prepared, fit, _ = keyed
    offset = fit.info["Basis"]["offset"]
    bands = keep_outside_bands(fit, basis, shapes)
    # The pear key at 1 holds one vertex nearer than half the offset: every vertex is kept at that distance,
    # and each band (half the offset included) keeps only the vertices every shape holds that far. The male_slim
    # key at 1 has one vertex, twice the offset out, behind its closest triangle's face normal (a concave edge):
    # a Shrinkwrap would move it by 9 mm, so it is in no band.
    floor = bands[0][0]
    assert 0.4 * offset < floor < SHAPE_KEY_BANDS[0] * offset
    assert [d for d, _ in bands[1:]] == pytest.approx([b * offset for b in SHAPE_KEY_BANDS])
    assert (~bands[0][1]).sum() == 1 and not bands[1][1].all()
    k = np.flatnonzero(~bands[0][1])[0]
    slim = TriangleSurface(shapes["male_slim"], basis.F)
    assert np.linalg.norm(keep_outside(fit.keys["male_slim"], slim, floor)[k] - fit.keys["male_slim"][k]) > 0.05
    for (_, wider), (_, narrower) in zip(bands, bands[1:]):
        assert not (narrower & ~wider).any()             # nested: a vertex in a band is in every band below
    assert 0 < bands[-1][1].sum() < len(fit.basis)
    # The basis and each key at 1 are left exactly as they are; the whole offset for every vertex would move them.
    moved_whole = 0.0
    for V_body, V in [(basis.V, fit.basis)] + [(shapes[k], fit.keys[k]) for k in shapes]:
        surface = TriangleSurface(V_body, basis.F)
        assert np.array_equal(keep_outside_banded(V, surface, bands), V)
        moved_whole = max(moved_whole, np.abs(keep_outside(V, surface, offset) - V).max())
    assert moved_whole > 0
    # At a mix, every vertex ends at least its own band's distance out, up to the offset. Above it (bands of
    # vertices every shape holds farther out), the Shrinkwrap moves a vertex that far from its closest point, but
    # in a hollow of the body another part may then be nearer: here one vertex of band 1.1 ends 1.02 offsets out.
    mix = {k: 0.8 for k in shapes}
    surface = TriangleSurface(body_at(basis.V, shapes, mix), basis.F)
    sd = surface.signed_distance(keep_outside_banded(fit.blend(mix, correctives=False), surface, bands))[0]
    own = np.max([np.where(only, d, 0.0) for d, only in bands], axis=0)
    assert (sd >= np.minimum(own, offset) - 1e-6 * offset).all()
    assert (sd < own - 1e-6 * offset).sum() <= 2
    with pytest.raises(ValueError, match="increasing"):
        keep_outside_bands(fit, basis, shapes, bands=(1.0, 0.5))


def test_surface_weights_are_exact_at_vertices_and_for_linear_fields():
    V, F = icosphere(2)
    W = np.stack([V[:, 0], V[:, 1] ** 2, np.ones(len(V))], axis=1)
    assert np.allclose(surface_weights(V, F, W, V), W)
    # Points on the triangles: barycentric interpolation reproduces a linear field exactly.
    rng = np.random.default_rng(0)
    tri = rng.integers(0, len(F), 50)
    bary = rng.dirichlet(np.ones(3), 50)
    P = np.einsum("pk,pkj->pj", bary, V[F[tri]])
    lin = 2.0 * V[:, :1] - V[:, 2:3] + 0.5
    assert np.allclose(surface_weights(V, F, lin, P), 2.0 * P[:, :1] - P[:, 2:3] + 0.5)
    with pytest.raises(ValueError, match="weights must be"):
        surface_weights(V, F, W[:5], P)


def run(*args):
    return subprocess.run([sys.executable, "-m", "garment_transfer", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)


def test_cli_writes_one_garment_per_shape_and_a_summary(tmp_path, keyed):
    _, _, _, _, fit, folder = keyed
    out = tmp_path / "sizes"
    r = run("shapes", "--source-body", folder / "bodies" / "female_average.obj",
            *[a for k in KEYS for a in ("--target-body", folder / "bodies" / f"{k}.obj")],
            "--garment", folder / "garments" / "female_casualsuit01" / "female_average.obj",
            "--out", out, "--json")
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert json.loads((out / "shapes.json").read_text()) == summary
    assert [s["target"] for s in summary["shapes"]] == list(KEYS)
    for s in summary["shapes"]:
        written = read_obj(s["out"]).V
        assert np.abs(written - fit.keys[s["target"]]).max() < 1e-6
        assert s["penetrating_vertices"] == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["shapes.json"] + [f"female_average_on_{k}.obj" for k in KEYS])


def test_cli_bad_shape_exits_1_and_writes_nothing(tmp_path, keyed):
    folder = keyed[5]
    V, F = icosphere(1)
    other = tmp_path / "sphere.obj"
    from garment_transfer.geometry.obj import write_obj
    write_obj(other, mesh_from_triangles(V, F))
    out = tmp_path / "sizes"
    r = run("shapes", "--source-body", folder / "bodies" / "female_average.obj",
            "--target-body", folder / "bodies" / "female_pear.obj", "--target-body", other,
            "--garment", folder / "garments" / "female_sportsuit01" / "female_average.obj", "--out", out)
    assert r.returncode == 1
    assert "sphere" in r.stderr
    assert not out.exists()


def test_cli_refuses_a_target_shape_given_twice_or_two_of_one_name_and_writes_nothing(tmp_path, keyed):
    folder = keyed[5]
    pear = folder / "bodies" / "female_pear.obj"
    (tmp_path / "copy").mkdir()
    twin = tmp_path / "copy" / "female_pear.obj"
    twin.write_bytes(pear.read_bytes())
    out = tmp_path / "sizes"
    for second, problem in ((pear, f"error: {pear}: is given twice as a target shape"),
                            (twin, f"error: {twin}: has the same name as {pear}; each target shape needs its own "
                                   "file name")):
        r = run("shapes", "--source-body", folder / "bodies" / "female_average.obj", "--target-body", pear,
                "--target-body", second, "--garment", folder / "garments" / "female_sportsuit01" / "female_average.obj",
                "--out", out)
        assert r.returncode == 1 and r.stderr.startswith(problem), r.stderr
        assert not out.exists()


def test_hanging_bands_keep_the_free_cloth_as_far_out_as_at_rest_and_move_nothing_at_rest():
    # A floor (z = 0, facing up) and cloth above it at known heights, in offsets; every other vertex hangs free.
    floor_V = np.array([[-100.0, -100.0, 0.0], [100.0, -100.0, 0.0], [100.0, 100.0, 0.0], [-100.0, 100.0, 0.0]])
    floor_F = np.array([[0, 1, 2], [0, 2, 3]])
    offset = 0.01
    heights = np.array([0.2, 1.2, 1.6, 1.6, 2.5, 3.5, 3.5, 5.0])
    hanging = np.array([True, True, True, False, True, True, False, True])
    V = np.stack([np.linspace(-1.0, 1.0, 8), np.zeros(8), heights * offset], axis=1)
    bands = hanging_bands(TriangleSurface(floor_V, floor_F), V, offset, hanging, (1.5, 2.0, 3.0, 4.0, 6.0))
    # The band of 6 offsets holds no vertex: left out. Each band: the hanging vertices held at least that far.
    assert [d for d, _ in bands] == pytest.approx([0.015, 0.02, 0.03, 0.04])
    assert [np.flatnonzero(only).tolist() for _, only in bands] == [[2, 4, 5, 7], [4, 5, 7], [5, 7], [7]]
    # At rest the Shrinkwrap of each band moves nothing.
    rest = TriangleSurface(floor_V, floor_F)
    assert np.array_equal(keep_outside_banded(V, rest, bands), V)
    # The floor raised by two offsets (a leg swung into the skirt): each hanging vertex ends as far above it as the
    # largest band it is held in, the others where they were.
    raised = TriangleSurface(floor_V + [0.0, 0.0, 2 * offset], floor_F)
    out = keep_outside_banded(V, raised, bands)
    expected = V.copy()
    expected[[2, 4, 5, 7], 2] = 2 * offset + np.array([1.5, 2.0, 3.0, 4.0]) * offset
    np.testing.assert_allclose(out, expected, rtol=0, atol=1e-12)
    assert out[3, 2] == V[3, 2] and out[6, 2] == V[6, 2]
    assert hanging_bands(rest, V, offset, np.zeros(8, bool)) == []
    with pytest.raises(ValueError, match="one value per garment vertex"):
        hanging_bands(rest, V, offset, hanging[:5])
    with pytest.raises(ValueError, match="increasing"):
        hanging_bands(rest, V, offset, hanging, (2.0, 1.5))
