"""Outfits of several layers: each layer outside the ones under it and no two layers crossing
(checked exactly), an impossible order refused with the garments named, nothing written then."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from garment_transfer.intersections import crossings
from garment_transfer.mesh import mesh_from_triangles
from garment_transfer.obj import read_obj
from garment_transfer.outfit import OutfitError, check_order, oriented_outward, transfer_outfit
from garment_transfer.proximity import TriangleSurface
from meshes import icosphere

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


def test_cli_outfit_out_count_must_match(tmp_path):
    src, tgt = DEMO / "bodies" / "banana.obj", DEMO / "bodies" / "pear.obj"
    top, dress = DEMO / "garments" / "tshirt" / "banana.obj", DEMO / "garments" / "shift_dress" / "banana.obj"
    p = run("transfer", "--source-body", src, "--target-body", tgt, "--garment", top, "--garment", dress,
            "--out", tmp_path / "only.obj")
    assert p.returncode == 1 and "--out" in p.stderr
    assert list(tmp_path.iterdir()) == []
