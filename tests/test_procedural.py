"""Procedural mannequins and garments: one closed topology for every shape, shapes that follow the
measurements, garments that are deterministic, closed where they should be and start outside the body."""

from __future__ import annotations

import numpy as np
import pytest

from garment_transfer.geometry.mesh import mesh_from_polygons, mesh_from_triangles, mesh_report, triangle_normals
from lab.procedural.garments import CLEARANCE, TEST_GARMENTS, TRAIN_GARMENTS, _source_body, garment, push_out
from lab.procedural.mannequin import PRESETS, Body, body_sdf, mannequin, measurements
from lab.procedural.sdf import gradient


@pytest.fixture(scope="module")
def bodies():
    return {name: mannequin(name) for name in ("banana", "pear", "heavy")}


def girth_width(V, z, band=0.015, reach=0.28):
    """Half-width of the torso (arms excluded) at height z."""
    sel = (np.abs(V[:, 2] - z) < band) & (np.abs(V[:, 0]) < reach)
    return float(np.abs(V[sel, 0]).max())


def test_every_preset_is_known_and_unknown_names_are_refused():
    assert {"banana", "pear", "slim", "heavy", "apple", "hourglass"} <= set(PRESETS)
    with pytest.raises(ValueError, match="unknown preset"):
        measurements("cucumber")
    assert measurements({"hip": 1.2}).hip == 1.2


def test_bodies_share_one_closed_manifold_topology(bodies):
    F0 = bodies["banana"][1]
    for name, (V, F) in bodies.items():
        assert np.array_equal(F, F0), name
        report = mesh_report(mesh_from_triangles(V, F, name))
        assert report["boundary_edges"] == 0, name
        assert report["non_manifold_edges"] == 0, name
        assert report["degenerate_triangles"] == 0, name
        assert report["pieces"] == 1, name
        assert report["triangles"] >= 10_000
    # Consistently oriented: every directed edge once.
    e = np.concatenate([F0[:, [0, 1]], F0[:, [1, 2]], F0[:, [2, 0]]])
    assert np.unique(e, axis=0).shape[0] == e.shape[0]


def test_bodies_face_outwards_without_fold_overs(bodies):
    for name, (V, F) in bodies.items():
        volume = np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6
        assert 0.04 < volume < 0.12, name  # cubic metres: a person
        N, _ = triangle_normals(V, F)
        g = gradient(body_sdf(name), V[F].mean(axis=1))
        assert np.all(np.einsum("ij,ij->i", N, g) > 0), name
        assert np.abs(body_sdf(name)(V)).max() < 1e-4


def test_body_stands_on_the_floor_facing_minus_y(bodies):
    V, _ = bodies["banana"]
    assert abs(V[:, 2].min()) < 2e-3
    assert abs(V[:, 2].max() - PRESETS["banana"].height) < 5e-3
    feet = V[V[:, 2] < 0.05]
    assert feet[:, 1].min() < -0.1  # toes point to -Y
    assert np.abs(V[:, 0].max() + V[:, 0].min()) < 1e-3  # symmetric


def test_legs_are_separate_below_the_crotch(bodies):
    for name, (V, F) in bodies.items():
        crotch = 0.455 * PRESETS[name].height
        C = V[F]
        below = C[:, :, 2].max(axis=1) < crotch - 0.04
        crosses = (C[:, :, 0].min(axis=1) <= 0) & (C[:, :, 0].max(axis=1) >= 0)
        assert not np.any(below & crosses), name


def test_measurements_move_the_shape_the_expected_way(bodies):
    Vb, Vp, Vh = bodies["banana"][0], bodies["pear"][0], bodies["heavy"][0]
    H = PRESETS["banana"].height
    assert girth_width(Vp, 0.50 * H) > girth_width(Vb, 0.50 * H) + 0.02  # pear: wider hips
    assert Body(PRESETS["pear"]).shoulders[1][0] < Body(PRESETS["banana"]).shoulders[1][0]
    assert girth_width(Vh, 0.62 * H) > girth_width(Vb, 0.62 * H) + 0.02  # heavy: wider waist
    b_wide = Body(measurements({"bust": 1.0}))
    assert b_wide.torso_axes(np.array([0.72 * H]))[0][0] > Body(PRESETS["banana"]).torso_axes(
        np.array([0.72 * H]))[0][0]


def test_garment_catalogue_follows_the_paper():
    assert len(TRAIN_GARMENTS) == 15 and len(TEST_GARMENTS) == 5
    assert set(TEST_GARMENTS) == {"shift_dress", "formal_dress", "wrap_dress", "shorts", "tshirt"}
    assert not set(TRAIN_GARMENTS) & set(TEST_GARMENTS)
    with pytest.raises(ValueError, match="unknown garment"):
        garment("cape")


@pytest.mark.parametrize("name", TRAIN_GARMENTS + TEST_GARMENTS)
def test_garments_are_clean_and_start_outside_the_body(name):
    g = garment(name)
    report = mesh_report(mesh_from_polygons(g.V, g.polygons, name=name))
    assert 1_000 <= report["triangles"] <= 25_000
    assert report["non_manifold_edges"] == 0
    assert report["degenerate_triangles"] == 0
    assert report["loose_vertices"] == 0
    assert report["pieces"] == 1
    assert report["boundary_edges"] > 0  # open: hems, neck, cuffs
    e = np.concatenate([g.polygons[:, [0, 1]], g.polygons[:, [1, 2]], g.polygons[:, [2, 3]],
                        g.polygons[:, [3, 0]]])
    assert np.unique(e, axis=0).shape[0] == e.shape[0]  # consistently oriented
    assert _source_body().sdf(g.V).min() > CLEARANCE - 1e-3
    assert g.pin.size > 0 and g.pin.max() < g.V.shape[0]


def test_garments_are_deterministic():
    a, b = garment("pleated_skirt"), garment("pleated_skirt")
    assert np.array_equal(a.V, b.V) and np.array_equal(a.polygons, b.polygons)
    assert np.array_equal(a.pin, b.pin)


def test_push_out_moves_inside_points_to_the_clearance():
    body = _source_body()
    P = np.array([[0.0, 0.0, 1.0], [0.0, -0.5, 1.0]])
    Q = push_out(body, P, clearance=0.01)
    assert body.sdf(Q[:1])[0] == pytest.approx(0.01, abs=1e-3)
    assert np.array_equal(Q[1], P[1])


def test_a_body_between_two_presets_has_their_mean_measurements_and_lies_between_them(bodies):
    from lab.procedural.mannequin import BETWEEN

    a, c, share = BETWEEN["pear_heavy"]
    assert (a, c) == ("pear", "heavy")
    m = measurements("pear_heavy")
    for field in ("hip", "waist", "bust", "height", "thigh", "shoulder_width"):
        want = (1 - share) * getattr(PRESETS[a], field) + share * getattr(PRESETS[c], field)
        assert abs(getattr(m, field) - want) < 1e-12, field
    V, F = mannequin("pear_heavy")
    assert np.array_equal(F, bodies["banana"][1])
    mid = (1 - share) * bodies[a][0] + share * bodies[c][0]
    apart = np.linalg.norm(bodies[a][0] - bodies[c][0], axis=1).mean()
    # Much closer to the blend of its two bodies than they are to each other.
    assert np.linalg.norm(V - mid, axis=1).mean() < 0.1 * apart
