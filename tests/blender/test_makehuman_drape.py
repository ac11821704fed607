"""lab.makehuman_drape: a MakeHuman fixture garment draped by Blender's cloth solver on the source body and
a target body, written in the fixtures' layout, units and axes; the fixtures themselves untouched."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytestmark = pytest.mark.lab

GARMENT = "male_casualsuit04"       # the smallest fixture garment (1,696 vertices)


def test_axes_round_trip_exactly():
    from lab.makehuman_drape import from_blender, to_blender

    V = np.random.default_rng(0).normal(size=(50, 3))
    B = to_blender(V)
    assert np.allclose(B[:, 2], 0.1 * V[:, 1]) and np.allclose(B[:, 1], -0.1 * V[:, 2])   # Y up -> Z up
    assert np.allclose(from_blender(B), V, atol=1e-12)


def test_drape_writes_a_simulated_garment_in_the_fixtures_layout(tmp_path, makehuman):
    from garment_transfer.geometry.obj import read_obj
    from garment_transfer.geometry.proximity import TriangleSurface
    from lab.makehuman_drape import main

    folder = makehuman
    before = {p: p.stat().st_mtime_ns for p in folder.rglob("*.obj")}
    out = tmp_path / "sim"
    assert main(["--out", str(out), "--garments", GARMENT, "--targets", "female_pear"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["garments"] == [GARMENT] and manifest["bodies"] == ["female_average", "female_pear"]
    assert "cloth solver" in manifest["placed_by"] and manifest["units"] == "decimetres"
    for body in ("female_average", "female_pear"):
        proxy = read_obj(folder / "garments" / GARMENT / f"{body}.obj")
        sim = read_obj(out / "garments" / GARMENT / f"{body}.obj")
        assert np.array_equal(sim.face_vertices, proxy.face_vertices) and sim.V.shape == proxy.V.shape
        body_mesh = read_obj(out / "bodies" / f"{body}.obj")
        assert np.array_equal(body_mesh.V, read_obj(folder / "bodies" / f"{body}.obj").V)
        # Decimetres, Y up: near the proxy fit (within a few cm), moved by the simulation, outside the body.
        d = np.linalg.norm(sim.V - proxy.V, axis=1)
        assert 0.01 < d.mean() < 0.3
        assert TriangleSurface(body_mesh.V, body_mesh.F).signed_distance(sim.V)[0].min() >= 0.0
    log = json.loads((out / "drape_log.json").read_text())
    assert log[GARMENT]["pinned"] > 0 and log[GARMENT]["inside_after_fix"] == [0, 0]
    assert log[GARMENT]["simulation"] == manifest["simulation"] == {"source_frames": 30, "morph_frames": 15,
                                                                     "frames": 15, "continuous": False}
    # A second run finds the garment done and leaves its files as they are.
    stamp = (out / "garments" / GARMENT / "female_pear.obj").stat().st_mtime_ns
    assert main(["--out", str(out), "--garments", GARMENT, "--targets", "female_pear"]) == 0
    assert (out / "garments" / GARMENT / "female_pear.obj").stat().st_mtime_ns == stamp
    assert {p: p.stat().st_mtime_ns for p in folder.rglob("*.obj")} == before


def test_the_fixtures_folder_is_refused_as_the_output(capsys, makehuman):
    from lab.makehuman_drape import main

    folder = makehuman
    with pytest.raises(SystemExit) as e:
        main(["--out", str(folder), "--garments", GARMENT])
    assert e.value.code == 2
    assert "fixtures' own folder" in capsys.readouterr().err


def test_every_piece_of_a_garment_is_pinned(makehuman):
    """female_casualsuit02's belt lies on the skirt, not on the body: it is pinned as a piece of its own."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from garment_transfer.geometry.obj import read_obj
    from lab.makehuman_drape import to_blender, waist_pins

    body = read_obj(makehuman / "bodies" / "female_average.obj")
    g = read_obj(makehuman / "garments" / "female_casualsuit02" / "female_average.obj")
    pins = waist_pins(to_blender(g.V), g.F, to_blender(body.V), body.F)
    n = g.n_vertices
    edges = coo_matrix((np.ones(g.F.size), (g.F.ravel(), np.roll(g.F, 1, axis=1).ravel())), shape=(n, n))
    count, pieces = connected_components(edges, directed=False)
    assert count == 3
    assert all(np.isin(np.flatnonzero(pieces == p), pins).any() for p in range(count))
    assert pins.size < n // 4


def test_continuous_drape_with_its_settings_recorded(tmp_path, makehuman):
    from garment_transfer.geometry.obj import read_obj
    from garment_transfer.geometry.proximity import TriangleSurface
    from lab.makehuman_drape import main

    out = tmp_path / "sim"
    argv = ["--out", str(out), "--garments", GARMENT, "--targets", "female_pear", "--continuous",
            "--source-frames", "10", "--morph-frames", "5", "--frames", "5"]
    assert main(argv) == 0
    sim = {"source_frames": 10, "morph_frames": 5, "frames": 5, "continuous": True}
    assert json.loads((out / "drape_log.json").read_text())[GARMENT]["simulation"] == sim
    assert json.loads((out / "manifest.json").read_text())["simulation"] == sim
    body = read_obj(out / "bodies" / "female_pear.obj")
    draped = read_obj(out / "garments" / GARMENT / "female_pear.obj")
    assert TriangleSurface(body.V, body.F).signed_distance(draped.V)[0].min() >= 0.0
    assert np.linalg.norm(draped.V - read_obj(out / "garments" / GARMENT / "female_average.obj").V,
                          axis=1).mean() > 0.01        # decimetres: the garment followed the body's change


def test_a_folder_draped_with_other_settings_is_refused(tmp_path, capsys, makehuman):
    from lab.makehuman_drape import SIMULATION, main

    out = tmp_path / "sim"
    out.mkdir()
    (out / "drape_log.json").write_text(json.dumps({GARMENT: {"garment": GARMENT, "simulation": SIMULATION}}))
    with pytest.raises(SystemExit) as e:
        main(["--out", str(out), "--garments", GARMENT, "--continuous"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "drape_log.json" in err and GARMENT in err and "other simulation settings" in err
    # A log written before the settings were recorded holds the defaults.
    (out / "drape_log.json").write_text(json.dumps({GARMENT: {"garment": GARMENT}}))
    with pytest.raises(SystemExit):
        main(["--out", str(out), "--garments", GARMENT, "--frames", "20"])
    assert not (out / "garments").exists()


def test_looser_cuts_are_draped_and_listed_as_variants(tmp_path, makehuman):
    from garment_transfer.geometry.obj import read_obj
    from garment_transfer.geometry.proximity import TriangleSurface
    from lab.makehuman_drape import main, to_blender, waist_pins

    out = tmp_path / "sim"
    short = ["--targets", "female_pear", "--continuous", "--source-frames", "5", "--morph-frames", "3",
             "--frames", "3"]
    assert main(["--out", str(out), "--garments", GARMENT, "--loose", "0.01", *short]) == 0
    name = GARMENT + "_loose"
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["garments"] == [name] and manifest["variants"] == {name: GARMENT}
    log = json.loads((out / "drape_log.json").read_text())[name]
    assert log["variant_of"] == GARMENT and log["ease"] == 0.01
    body = read_obj(makehuman / "bodies" / "female_average.obj")
    proxy = read_obj(makehuman / "garments" / GARMENT / "female_average.obj")
    assert log["pinned"] == waist_pins(to_blender(proxy.V), proxy.F, to_blender(body.V), body.F).size
    loose = read_obj(out / "garments" / name / "female_average.obj")
    assert np.array_equal(loose.face_vertices, proxy.face_vertices)
    surface = TriangleSurface(body.V, body.F)
    # Decimetres: farther from the body than the fitted garment, on average by most of the 1 cm of ease.
    assert surface.signed_distance(loose.V)[0].mean() - surface.signed_distance(proxy.V)[0].mean() > 0.05
    with pytest.raises(SystemExit):
        main(["--out", str(tmp_path / "other"), "--garments", GARMENT, "--loose", "0.2", *short])
