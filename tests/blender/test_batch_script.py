"""scripts/batch_transfer.py with the bpy module: many garments to many targets in one run, past bad files."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np

from conftest import GARMENT, ROOT


def read_obj_vertices(path):
    return np.array([[float(x) for x in ln.split()[1:4]] for ln in path.read_text().splitlines()
                     if ln.startswith("v ")])


def test_batch_transfers_to_two_targets_and_goes_past_a_bad_file(makehuman, tmp_path):
    garment = makehuman / "garments" / GARMENT / "female_average.obj"
    far = tmp_path / "far.obj"
    far.write_text("v 1000 0 0\nv 1001 0 0\nv 1000 1 0\nf 1 2 3\n")
    garbage = tmp_path / "garbage.obj"
    garbage.write_bytes(bytes(range(256)) * 8)
    out = tmp_path / "out"
    cmd = [sys.executable, str(ROOT / "scripts" / "batch_transfer.py"), "--",
           "--source-body", str(makehuman / "bodies" / "female_average.obj"),
           "--target-body", str(makehuman / "bodies" / "female_pear.obj"),
           "--target-body", str(makehuman / "bodies" / "female_slim_banana.obj"),
           "--garment", str(garment), "--garment", str(tmp_path / "missing.obj"),
           "--garment", str(far), "--garment", str(garbage),
           "--out", str(out), "--scale", "0.1", "--blend", str(tmp_path / "all.blend")]
    system_tmp = tmp_path / "system_tmp"
    system_tmp.mkdir()
    proc = subprocess.run(cmd, capture_output=True, encoding="utf-8", errors="replace", timeout=300,
                          cwd=tmp_path, env={**os.environ, "TMPDIR": str(system_tmp)})
    assert proc.returncode == 1, proc.stderr
    # Blender's folder for the session's temporary files is removed as Blender removes it at exit.
    assert list(system_tmp.iterdir()) == []

    records = json.loads((out / "summary.json").read_text())
    done = [r for r in records if "error" not in r]
    failed = [r for r in records if "error" in r]
    label = f"{GARMENT}_female_average"
    assert sorted(r["target"] for r in done) == ["female_pear", "female_slim_banana"]
    assert all(r["garment"] == label for r in done)
    assert any("missing.obj" in r["garment"] and "not found" in r["error"] for r in failed)
    assert any("garbage.obj" in r["garment"] and "binary content" in r["error"] for r in failed)
    assert [r["target"] for r in failed if r["garment"] == "far"] == ["female_pear", "female_slim_banana"]
    assert all("is far from the source body" in r["error"] for r in failed if r["garment"] == "far")
    assert len(failed) == 4
    assert (tmp_path / "all.blend").is_file()

    # Written in the input files' units and axes and the garment's vertex order: what the core makes
    # of the files themselves, up to float32 rounding (which flips a few penetration push-outs).
    from garment_transfer.geometry.obj import read_obj
    from garment_transfer.pipeline.transfer import transfer_garment

    source_body = read_obj(makehuman / "bodies" / "female_average.obj")
    cloth = read_obj(garment)
    for target in ("female_pear", "female_slim_banana"):
        result = read_obj_vertices(out / f"{label}_on_{target}.obj")
        expected = transfer_garment(source_body, read_obj(makehuman / "bodies" / f"{target}.obj"),
                                    cloth).V
        gap = np.linalg.norm(result - expected, axis=1)
        assert np.percentile(gap, 99) < 1e-3 and gap.max() < 0.1, (target, gap.max())
    assert "2 transferred, 4 failed" in proc.stderr


def test_batch_reads_the_core_catalogue_and_matches_the_core_batch(makehuman, tmp_path):
    """--catalogue: the same TOML that python -m garment_transfer batch runs, the same result layout and
    (up to the float32 of Blender meshes) the same results; a missing body fails its pairs only."""
    from garment_transfer.pipeline.batch import run_batch
    from garment_transfer.pipeline.catalogue import read_catalogue

    catalogue = tmp_path / "cat.toml"
    catalogue.write_text(
        f'source = "female_average"\ntargets = ["female_pear", "gone"]\n'
        f'[bodies]\nfemale_average = "{makehuman}/bodies/female_average.obj"\n'
        f'female_pear = "{makehuman}/bodies/female_pear.obj"\ngone = "missing/gone.obj"\n'
        f'[[garments]]\nname = "suit"\nfile = "{makehuman}/garments/{GARMENT}/female_average.obj"\n')
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "batch_transfer.py"), "--",
                           "--catalogue", str(catalogue), "--out", str(out), "--scale", "0.1"],
                          capture_output=True, encoding="utf-8", errors="replace", timeout=300, cwd=tmp_path)
    assert proc.returncode == 1, proc.stderr
    records = json.loads((out / "summary.json").read_text())
    assert [(r["garment"], r["target"], "error" in r) for r in records] == [
        ("suit", "gone", True), ("suit", "female_pear", False)]
    assert f"{tmp_path / 'missing' / 'gone.obj'}: file not found" in records[0]["error"]
    core = run_batch(read_catalogue(catalogue), tmp_path / "core", workers=1)
    assert [r["outcome"] for r in core.records] == ["done", "failed"]
    gap = np.linalg.norm(read_obj_vertices(out / "suit" / "female_pear.obj")
                         - read_obj_vertices(tmp_path / "core" / "suit" / "female_pear.obj"), axis=1)
    assert np.percentile(gap, 99) < 1e-3 and gap.max() < 0.1, gap.max()


def test_batch_catalogue_and_file_options_do_not_mix(tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "batch_transfer.py"), "--catalogue",
                           str(tmp_path / "cat.toml"), "--garment", "g.obj", "--out", str(tmp_path)],
                          capture_output=True, encoding="utf-8", timeout=120)
    assert proc.returncode == 2 and "drop --garment" in proc.stderr
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "batch_transfer.py"), "--catalogue",
                           str(tmp_path / "nothing.toml"), "--out", str(tmp_path / "o")],
                          capture_output=True, encoding="utf-8", timeout=120)
    assert proc.returncode == 1 and "nothing.toml: catalogue not found" in proc.stderr


def test_batch_results_are_the_garment_file_with_its_materials_groups_and_comments(makehuman, tmp_path):
    """A result is the garment's own file with the new positions: its material library (named from the results
    folder), materials, groups, smoothing and comments in any encoding, as the core batch writes it."""
    folder = tmp_path / "garments"
    folder.mkdir()
    (folder / "cloth.mtl").write_text("newmtl cotton\nKd 0.8 0.1 0.1\n")
    data = (makehuman / "garments" / GARMENT / "female_average.obj").read_bytes()
    first_face = data.index(b"\nf ") + 1
    garment = folder / "suit.obj"
    garment.write_bytes(b"# caf\xe9 (Latin-1)\nmtllib cloth.mtl\n" + data[:first_face]
                        + b"g suit\nusemtl cotton\ns 1\n" + data[first_face:])
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "batch_transfer.py"), "--",
                           "--source-body", str(makehuman / "bodies" / "female_average.obj"),
                           "--target-body", str(makehuman / "bodies" / "female_pear.obj"),
                           "--garment", str(garment), "--out", str(out), "--scale", "0.1"],
                          capture_output=True, encoding="utf-8", errors="replace", timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    written = (out / "suit_on_female_pear.obj").read_bytes().split(b"\n")
    source = garment.read_bytes().split(b"\n")
    assert [ln for ln in written if not ln.startswith((b"v ", b"mtllib"))] == \
        [ln for ln in source if not ln.startswith((b"v ", b"mtllib"))]
    assert written[1] == b"mtllib ../garments/cloth.mtl"
    from garment_transfer.geometry.obj import read_obj
    from garment_transfer.pipeline.transfer import transfer_garment

    expected = transfer_garment(read_obj(makehuman / "bodies" / "female_average.obj"),
                                read_obj(makehuman / "bodies" / "female_pear.obj"), read_obj(garment)).V
    gap = np.linalg.norm(read_obj(out / "suit_on_female_pear.obj").V - expected, axis=1)
    assert np.percentile(gap, 99) < 1e-3 and gap.max() < 0.1, gap.max()
