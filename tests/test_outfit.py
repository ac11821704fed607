"""Outfits of several layers: each layer outside the ones under it and no two layers crossing
(checked exactly), an impossible order refused with the garments named, nothing written then."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from meshes import icosphere

from garment_transfer.geometry.intersections import crossings, self_intersections
from garment_transfer.geometry.readings import readings_of
from garment_transfer.geometry.mesh import mesh_from_triangles
from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.proximity import TriangleSurface
from garment_transfer.pipeline.outfit import (
    OutfitError,
    check_order,
    merge_meshes,
    obstacle_distance,
    oriented_outward,
    rim_triangles,
    transfer_outfit,
    warp_out,
)
from lab.paths import DEMO_DATA

ROOT = Path(__file__).resolve().parents[1]
DEMO = DEMO_DATA


def spheres():
    V, F = icosphere(3)
    source = mesh_from_triangles(V, F, name="source")
    target = mesh_from_triangles(V * [1.3, 1.3, 1.0], F, name="target")
    inner = mesh_from_triangles(*icosphere(3, radius=1.02), name="inner")
    # The outer layer drawn at the same place as the inner one: they cross everywhere until separated.
    GV, GF = icosphere(2, radius=1.021)
    outer = mesh_from_triangles(GV, GF, name="outer")
    return source, target, inner, outer


def test_two_layers_are_separated_on_source_and_target():
    source, target, inner, outer = spheres()
    assert crossings(outer.V, outer.F, inner.V, inner.F)["a_edge_pairs"] > 0
    r = transfer_outfit(source, target, [inner, outer], offsets=0.01)
    for V, g in zip(r.V, (inner, outer)):
        c = crossings(V, g.F, target.V, target.F)
        assert c["a_edge_pairs"] + c["b_edge_pairs"] == 0
    c = crossings(r.V[1], outer.F, r.V[0], inner.F)
    assert c["a_edge_pairs"] + c["b_edge_pairs"] == 0
    # The outer layer is outside the inner one (positive signed distance to it everywhere).
    inner_radius = np.linalg.norm(r.V[0][:, :2], axis=1).max()
    body = TriangleSurface(target.V, target.F)
    outer_surface = TriangleSurface(r.V[0], oriented_outward(r.V[0], inner.F, body))
    sd = outer_surface.signed_distance(r.V[1])[0]
    assert sd.min() > 0 and inner_radius > 1.0
    assert {"separate_source", "transfer", "separate_target", "total"} <= set(r.seconds)


def test_wrong_order_is_refused_naming_both():
    source, target, inner, outer = spheres()
    big = mesh_from_triangles(*icosphere(2, radius=1.2), name="coat")
    with pytest.raises(OutfitError, match="coat") as err:
        check_order([big, inner], [big.V, inner.V], TriangleSurface(source.V, source.F))
    assert "inner" in str(err.value)
    with pytest.raises(OutfitError, match="inner"):
        transfer_outfit(source, target, [big, inner])
    transfer_outfit(source, target, [inner, big])   # the right order goes through


def test_repeated_layer_and_offsets_checked():
    source, target, inner, outer = spheres()
    with pytest.raises(OutfitError, match="repeated"):
        transfer_outfit(source, target, [inner, inner])
    with pytest.raises(ValueError, match="offsets"):
        transfer_outfit(source, target, [inner, outer], offsets=[0.01])
    # A layer's offset left out (None) is the default; the others as given.
    from garment_transfer.geometry.embedding import body_scale
    from garment_transfer.pipeline.transfer import OFFSET_SHARE

    r = transfer_outfit(source, target, [inner, outer], offsets=[None, 0.02])
    assert [i["offset"] for i in r.info] == [OFFSET_SHARE * body_scale(source.V), 0.02]


def crossing_pairs(V_a, F_a, V_b, F_b):
    c = crossings(V_a, F_a, V_b, F_b)
    return c["a_edge_pairs"] + c["b_edge_pairs"]


def test_warp_keeps_the_sheets_of_a_fold_in_order():
    # A fold under a flat obstacle z = 0 (outward +z): one sheet 10 mm inside, one 2 mm outside,
    # over the same points. Both must end at least ``clear`` out, the inner one still under the
    # outer one; cloth beyond the band does not move.
    xy = np.random.default_rng(0).uniform(-0.5, 0.5, size=(50, 2))
    V = np.concatenate([np.column_stack([xy, np.full(50, -0.010)]), np.column_stack([xy, np.full(50, 0.002)]),
                        np.column_stack([xy, np.full(50, 0.2)])])
    normal = np.tile([0.0, 0.0, 1.0], (150, 1))
    clear, band = 0.005, 0.02
    for radius in (None, 0.3):
        W = warp_out(V, V[:, 2].copy(), normal, clear, band, radius)
        assert np.all(W[:100, 2] >= clear - 1e-12)
        assert np.all(W[:50, 2] < W[50:100, 2] - 1e-3)
        np.testing.assert_array_equal(W[:, :2], V[:, :2])
        np.testing.assert_array_equal(W[100:], V[100:])
    # The deepest vertex lands exactly on ``clear``; one at clear + band does not move.
    W = warp_out(np.array([[0, 0, -0.01], [0, 0, clear + band]]), np.array([-0.01, clear + band]),
                 np.tile([0.0, 0.0, 1.0], (2, 1)), clear, band)
    np.testing.assert_allclose(W[:, 2], [clear, clear + band], atol=1e-15)


def test_obstacle_distance_beyond_the_rim_of_an_open_layer():
    # A body (sphere) under an open layer (the upper half of a larger sphere). A point just below
    # the layer's rim, on its inner side, has its closest point on the rim, where the pseudonormal
    # says "inside"; the winding number says outside, and nothing is under the layer there.
    bV, bF = icosphere(3, radius=0.5)
    cV, cF = icosphere(3, radius=1.1)
    cF = cF[(cV[cF][:, :, 2] > -1e-9).all(axis=1)]
    oV, oF = merge_meshes([(bV, bF), (cV, cF)])
    surface = TriangleSurface(oV, oF)
    rim = rim_triangles(oF)
    assert rim[: bF.shape[0]].sum() == 0 and rim.sum() > 0
    rim_vertices = np.unique(oF[rim])
    r = oV[rim_vertices[np.argmin(oV[rim_vertices, 2])]]
    P = np.array([r * (1.09 / 1.1) - [0.0, 0.0, 0.1], [0.0, 0.3, 0.9], [0.0, 0.0, 1.2]])
    assert surface.signed_distance(P)[0][0] < 0
    sd, normal = obstacle_distance(surface, P)
    assert sd[0] > 0.09 and sd[1] < 0 and sd[2] > 0
    assert normal[0, 2] < -0.9   # away from the rim, downward


def test_demo_outfit_adds_no_self_intersection():
    # tshirt under shift_dress on banana: draped one by one, they cross at 2,045 edge-triangle pairs.
    # After the outfit transfer to pear, no layer crosses itself more than as given, and nothing
    # crosses anything (exact).
    src, tgt = read_obj(DEMO / "bodies" / "banana.obj"), read_obj(DEMO / "bodies" / "pear.obj")
    layers = [read_obj(DEMO / "garments" / g / "banana.obj", name=g) for g in ("tshirt", "shift_dress")]
    R = [readings_of(g) for g in layers]
    assert crossing_pairs(layers[1].V, R[1], layers[0].V, R[0]) > 1000
    given = [self_intersections(g.V, r)[0] for g, r in zip(layers, R)]
    r = transfer_outfit(src, tgt, layers)
    # Under every triangulation of the layers' quads (and of the bodies').
    for where, body, Vs in (("source", src, r.source_V), ("target", tgt, r.V)):
        for k, (g, V) in enumerate(zip(layers, Vs)):
            assert self_intersections(V, R[k])[0] <= given[k], (where, g.name)
            assert crossing_pairs(V, R[k], body.V, readings_of(body)) == 0, (where, g.name)
        assert crossing_pairs(Vs[1], R[1], Vs[0], R[0]) == 0, where
    assert r.info[1]["target_separation"]["self_intersections_after"] <= given[1]


def run(*args):
    return subprocess.run([sys.executable, "-m", "garment_transfer", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)


def test_cli_outfit_from_demo_garments(tmp_path):
    src, tgt = DEMO / "bodies" / "banana.obj", DEMO / "bodies" / "pear.obj"
    top, dress = DEMO / "garments" / "tshirt" / "banana.obj", DEMO / "garments" / "shift_dress" / "banana.obj"
    outs = [tmp_path / "top.obj", tmp_path / "dress.obj"]
    p = run("transfer", "--source-body", src, "--target-body", tgt, "--garment", top, "--garment", dress,
            "--out", outs[0], "--out", outs[1], "--json")
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    assert [Path(x).name for x in data["out"]] == ["top.obj", "dress.obj"]
    body = read_obj(tgt)
    layers = [read_obj(o) for o in outs]
    for g in layers:
        c = crossings(g.V, g.F, body.V, body.F)
        assert c["a_edge_pairs"] + c["b_edge_pairs"] == 0
    c = crossings(layers[1].V, layers[1].F, layers[0].V, layers[0].F)
    assert c["a_edge_pairs"] + c["b_edge_pairs"] == 0
    # The other order: refused, both garments named, nothing written.
    bad = [tmp_path / "a.obj", tmp_path / "b.obj"]
    p = run("transfer", "--source-body", src, "--target-body", tgt, "--garment", dress, "--garment", top,
            "--out", bad[0], "--out", bad[1])
    assert p.returncode == 1
    assert "tshirt" in p.stderr and "shift_dress" in p.stderr
    assert not any(b.exists() for b in bad)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["dress.obj", "top.obj"]


def test_cli_outfit_onto_a_body_of_another_mesh_in_other_units_is_registered_once(tmp_path):
    from garment_transfer.geometry.obj import write_obj
    from lab.registration import remesh

    src = DEMO / "bodies" / "banana.obj"
    top, dress = DEMO / "garments" / "tshirt" / "banana.obj", DEMO / "garments" / "shift_dress" / "banana.obj"
    pear = read_obj(DEMO / "bodies" / "pear.obj")
    # The pear re-meshed and written in centimetres: another mesh, other units.
    U, G = remesh(pear.V, pear.F, 20000)
    write_obj(tmp_path / "pear_cm.obj", mesh_from_triangles(U * 100.0, G))
    outs = [tmp_path / "top.obj", tmp_path / "dress.obj"]
    p = run("transfer", "--source-body", src, "--target-body", tmp_path / "pear_cm.obj", "--garment", top,
            "--garment", dress, "--out", outs[0], "--out", outs[1], "--json", "--no-cache")
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    assert data["registered"] and 95 < 1.0 / data["registration"]["alignment"]["scale"] < 105
    # Each layer's offset in the target's units: the source's, scaled by the registration.
    same = run("transfer", "--source-body", src, "--target-body", DEMO / "bodies" / "pear.obj", "--garment", top,
               "--garment", dress, "--out", tmp_path / "a.obj", "--out", tmp_path / "b.obj", "--json")
    plain = json.loads(same.stdout)
    assert not plain["registered"] and "registration" not in plain
    for layer, base in zip(data["layers"], plain["layers"]):
        ratio = layer["info"]["offset"] / base["info"]["offset"]
        assert ratio == pytest.approx(1.0 / data["registration"]["alignment"]["scale"], rel=1e-9)
    # As written, against the body given: no layer through it or through the layer under it, under every split.
    body = read_obj(tmp_path / "pear_cm.obj")
    layers = [read_obj(o) for o in outs]
    for g in layers:
        c = crossings(g.V, readings_of(g), body.V, body.F)
        assert c["a_edge_pairs"] + c["b_edge_pairs"] == 0
    c = crossings(layers[1].V, readings_of(layers[1]), layers[0].V, readings_of(layers[0]))
    assert c["a_edge_pairs"] + c["b_edge_pairs"] == 0
    assert [layer["check"]["self_intersections_new"] for layer in data["layers"]] == [0, 0]
    # Near the outfit onto the pear's own mesh (the registration's error; measured: 4.1 and 8.7 mm on average).
    for layer, own in zip(layers, [tmp_path / "a.obj", tmp_path / "b.obj"]):
        assert np.linalg.norm(layer.V / 100.0 - read_obj(own).V, axis=1).mean() < 0.012
    # Offsets given are the target's, as one garment's --offset: kept as given on the target (centimetres here),
    # the source's those times the registration's scale.
    source, garments = read_obj(src), [read_obj(top, name="top"), read_obj(dress, name="dress")]
    first = transfer_outfit(source, body, garments, cache=False)
    given = transfer_outfit(source, body, garments, offsets=[0.5, 0.8], registration=first.registration)
    assert [i["offset"] for i in given.info] == [0.5, 0.8]
    default = transfer_outfit(source, read_obj(DEMO / "bodies" / "pear.obj"), garments).info[0]["offset"]
    assert first.info[0]["offset"] == pytest.approx(default / first.registration.alignment.scale, rel=1e-12)
    for V, g in zip(given.V, garments):
        c = crossings(V, readings_of(g), body.V, body.F)
        assert c["a_edge_pairs"] + c["b_edge_pairs"] == 0


def test_cli_outfit_out_count_must_match(tmp_path):
    src, tgt = DEMO / "bodies" / "banana.obj", DEMO / "bodies" / "pear.obj"
    top, dress = DEMO / "garments" / "tshirt" / "banana.obj", DEMO / "garments" / "shift_dress" / "banana.obj"
    p = run("transfer", "--source-body", src, "--target-body", tgt, "--garment", top, "--garment", dress,
            "--out", tmp_path / "only.obj")
    assert p.returncode == 1 and "--out" in p.stderr
    assert list(tmp_path.iterdir()) == []
