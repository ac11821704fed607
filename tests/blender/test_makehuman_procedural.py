"""lab.makehuman_procedural: a garment of the procedural catalogue carried onto the MakeHuman source body and
draped by Blender's cloth solver into a target body, listed beside the fixtures' garments of a folder that
lab.makehuman_drape writes; the fixtures themselves untouched."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytestmark = pytest.mark.lab

GARMENT = "mini_skirt"              # a small catalogue garment (1,296 vertices)
FIXTURE_GARMENT = "male_casualsuit04"
SHORT = ["--targets", "female_pear", "--continuous", "--source-frames", "5", "--morph-frames", "3",
         "--frames", "3"]


def test_a_catalogue_garment_draped_on_the_makehuman_bodies(tmp_path, makehuman):
    from garment_transfer.geometry.obj import read_obj
    from garment_transfer.geometry.proximity import TriangleSurface
    from garment_transfer.learning.dataset import load_dataset
    from lab import makehuman_drape, makehuman_procedural
    from lab.procedural.garments import garment

    before = {p: p.stat().st_mtime_ns for p in makehuman.rglob("*.obj")}
    out = tmp_path / "sim"
    assert makehuman_procedural.main(["--out", str(out), "--garments", GARMENT, *SHORT]) == 0
    catalogue = garment(GARMENT)
    log = json.loads((out / "drape_log.json").read_text())[GARMENT]
    assert log["procedural"] and log["pinned"] == catalogue.pin.size and log["inside_after_fix"] == [0, 0]
    assert log["shoulder_drop"] == [0.0]                                  # a skirt: no piece at the shoulders
    for body in ("female_average", "female_pear"):
        draped = read_obj(out / "garments" / GARMENT / f"{body}.obj")
        assert np.array_equal(draped.polygons(), [list(p) for p in catalogue.polygons])
        mesh = read_obj(out / "bodies" / f"{body}.obj")
        # Decimetres, Y up, on the body and outside it: the skirt's waist near the body's.
        assert TriangleSurface(mesh.V, mesh.F).signed_distance(draped.V)[0].min() >= 0.0
        assert abs(draped.V[catalogue.pin, 1].mean() - mesh.V[:, 1].min() - 0.6 * np.ptp(mesh.V[:, 1])) < 1.5
    moved = read_obj(out / "garments" / GARMENT / "female_pear.obj").V
    assert np.linalg.norm(moved - read_obj(out / "garments" / GARMENT / "female_average.obj").V, axis=1).mean() > 0.01
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["garments"] == [GARMENT] and manifest["procedural_garments"] == [GARMENT]
    # A fixture garment draped into the same folder: both listed, the study reads them as one dataset.
    assert makehuman_drape.main(["--out", str(out), "--garments", FIXTURE_GARMENT, *SHORT]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["garments"] == [FIXTURE_GARMENT, GARMENT] and manifest["procedural_garments"] == [GARMENT]
    assert load_dataset(out).garments == [FIXTURE_GARMENT, GARMENT]
    # Done garments are skipped, their files left as they are.
    stamp = (out / "garments" / GARMENT / "female_pear.obj").stat().st_mtime_ns
    assert makehuman_procedural.main(["--out", str(out), "--garments", GARMENT, *SHORT]) == 0
    assert (out / "garments" / GARMENT / "female_pear.obj").stat().st_mtime_ns == stamp
    assert json.loads((out / "manifest.json").read_text())["garments"] == [FIXTURE_GARMENT, GARMENT]
    assert {p: p.stat().st_mtime_ns for p in makehuman.rglob("*.obj")} == before


@pytest.mark.parametrize("name", ["ball_gown", FIXTURE_GARMENT])
def test_garments_not_in_the_catalogue_are_refused(tmp_path, capsys, makehuman, name):
    from lab.makehuman_procedural import main

    with pytest.raises(SystemExit) as e:
        main(["--out", str(tmp_path / "sim"), "--garments", "trousers", name])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "not in the procedural catalogue" in err and name in err and "trousers" not in err
    assert not (tmp_path / "sim").exists()


def test_a_folder_draped_with_other_settings_is_refused(tmp_path, capsys, makehuman):
    from lab.makehuman_drape import SIMULATION
    from lab.makehuman_procedural import main

    out = tmp_path / "sim"
    out.mkdir()
    (out / "drape_log.json").write_text(json.dumps({FIXTURE_GARMENT: {"simulation": SIMULATION}}))
    with pytest.raises(SystemExit) as e:
        main(["--out", str(out), "--garments", GARMENT, "--continuous"])
    assert e.value.code == 2
    assert "other simulation settings" in capsys.readouterr().err
    assert not (out / "garments").exists()


def test_a_claim_left_by_a_stopped_run_is_taken_over(tmp_path, makehuman):
    import os
    import subprocess
    import sys

    from lab.makehuman_procedural import claimed_elsewhere, main

    claim = tmp_path / ".claimed"
    assert not claimed_elsewhere(claim)                                   # no claim
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    claim.write_text(str(gone.pid))
    assert not claimed_elsewhere(claim)                                   # its process is gone
    claim.write_text(str(os.getppid()))
    assert claimed_elsewhere(claim)                                       # a live process holds it
    # A run finds the stale claim in the folder and drapes the garment.
    out = tmp_path / "sim"
    (out / "garments" / GARMENT).mkdir(parents=True)
    (out / "garments" / GARMENT / ".claimed").write_text(str(gone.pid))
    assert main(["--out", str(out), "--garments", GARMENT, *SHORT]) == 0
    assert GARMENT in json.loads((out / "drape_log.json").read_text())
    assert not (out / "garments" / GARMENT / ".claimed").exists()


def test_an_outfit_is_draped_as_one_garment_pinned_at_the_waist(tmp_path, makehuman):
    from garment_transfer.geometry.mesh import connected_pieces
    from garment_transfer.geometry.obj import read_obj
    from lab.makehuman_drape import SLID_SHARE, to_blender, waist_pins
    from lab.makehuman_procedural import MANNEQUIN, OUTFITS, fit_outfit, main
    from lab.paths import DEMO_DATA

    name = "outfit_tank_top_shorts"
    out = tmp_path / "sim"
    assert main(["--out", str(out), "--garments", name, *SHORT]) == 0
    body = read_obj(makehuman / "bodies" / "female_average.obj")
    mesh = fit_outfit(name, read_obj(DEMO_DATA / "bodies" / f"{MANNEQUIN}.obj"), body)[0]
    log = json.loads((out / "drape_log.json").read_text())[name]
    # Pinned as the fixture suits are (at the waist and hips), not where the catalogue pins its garments.
    assert log["pinned"] == waist_pins(to_blender(mesh.V), mesh.F, to_blender(body.V), body.F).size > 0
    assert log["pieces"] == list(OUTFITS[name]) and log["inside_after_fix"] == [0, 0]
    assert len(log["shoulder_drop"]) == 1 and 0.0 <= log["shoulder_drop"][0] < SLID_SHARE
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["outfits"] == {name: list(OUTFITS[name])} and manifest["procedural_garments"] == [name]
    for b in ("female_average", "female_pear"):
        draped = read_obj(out / "garments" / name / f"{b}.obj")
        assert connected_pieces(draped.n_vertices, draped.F)[0] == 2
        assert all(np.array_equal(p, q) for p, q in zip(draped.polygons(), mesh.polygons()))
