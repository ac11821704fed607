"""The Blender side of careless inputs: mirrored characters, settings out of range, outputs checked
before the work, and the batch script checking files as the command line does."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import bpy
import numpy as np
import pytest
from test_bad_input import expect_report

from conftest import ROOT, world_vertices

sys.path.insert(0, str(ROOT / "tests"))
from meshes import icosphere  # noqa: E402


def mesh_object(name, V, F, parent=None):
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(v) for v in V], [], [tuple(int(i) for i in f) for f in F])
    me.update()
    obj = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(obj)
    obj.parent = parent
    return obj


def sphere_scene(parent=None):
    """A ball body (radius 1) made 1.2 times larger as the target, and a band around it at 1.04."""
    V, F = icosphere(3)
    GV, GF = icosphere(3, radius=1.04)
    keep = GV[GF].mean(axis=1)[:, 2] < 0.3
    settings = bpy.context.scene.garment_transfer
    settings.source_body = mesh_object("ball", V, F, parent)
    settings.target_body = mesh_object("big_ball", V * 1.2, F, parent)
    settings.garment = mesh_object("band", GV, GF[keep], parent)
    return settings


def test_negative_scale_parent_keeps_the_garment_outside_the_body():
    mirror = bpy.data.objects.new("mirror", None)
    bpy.context.scene.collection.objects.link(mirror)
    mirror.scale = (-1.0, 1.0, 1.0)
    mirror.location = (3.0, 0.0, 0.0)
    settings = sphere_scene(parent=mirror)
    bpy.context.view_layer.update()
    assert np.linalg.det(np.array(settings.garment.matrix_world)[:3, :3]) < 0

    from garment_transfer_ext.operators.convert import mesh_arrays_from_object

    from garment_transfer.geometry.proximity import signed_volume

    V, fv, fs = mesh_arrays_from_object(settings.target_body, bpy.context.evaluated_depsgraph_get())
    assert signed_volume(V, fv.reshape(-1, 3)) > 0           # world-space faces point outward

    bpy.ops.garment_transfer.transfer()
    result = world_vertices(settings.result)
    centre = np.array([3.0, 0.0, 0.0])
    used = np.unique(np.array([list(p.vertices) for p in settings.garment.data.polygons]))
    radius = np.linalg.norm(result[used] - centre, axis=1)
    # Outside the target ball (radius 1.2; its flat facets come in to 0.995 of that).
    assert radius.min() > 1.2 * 0.995, radius.min()
    metrics = json.loads(settings.last_metrics)
    assert metrics["penetration_ratio"] == 0.0


def test_offset_out_of_range_is_refused_like_on_the_command_line():
    settings = sphere_scene()
    settings.auto_offset = False
    settings.offset = 0.5        # within the property's range, but 20% of this body's size
    expect_report(bpy.ops.garment_transfer.transfer, "offset", "more than 5% of the size of the body",
                  "big_ball")
    prop = type(settings).bl_rna.properties["offset"]
    assert prop.hard_min == 0.0 and prop.hard_max == 1.0
    settings.offset = -1.0
    assert settings.offset == 0.0                 # clamped by the property itself


def test_train_checks_its_output_before_training(tmp_path):
    settings = bpy.context.scene.garment_transfer
    settings.dataset_path = str(tmp_path)
    settings.train_output = str(tmp_path / "missing" / "model.npz")
    expect_report(bpy.ops.garment_transfer.train, "model.npz", "does not exist")
    settings.train_output = str(tmp_path)
    expect_report(bpy.ops.garment_transfer.train, "is a folder")


def run_batch(tmp_path, *args):
    cmd = [sys.executable, str(ROOT / "scripts" / "batch_transfer.py"), "--", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, encoding="utf-8", errors="replace", timeout=300,
                          cwd=tmp_path)


def write(path, V, F, extra=""):
    path.write_text(extra + "".join(f"v {float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in V)
                    + "".join("f " + " ".join(str(i + 1) for i in f) + "\n" for f in F))
    return path


@pytest.fixture
def ball_files(tmp_path):
    V, F = icosphere(3)
    GV, GF = icosphere(3, radius=1.04)
    keep = GV[GF].mean(axis=1)[:, 2] < 0.3
    used = np.unique(GF[keep])
    remap = -np.ones(len(GV), int)
    remap[used] = np.arange(len(used))
    return (write(tmp_path / "ball.obj", V, F), write(tmp_path / "big.obj", V * 1.2, F),
            write(tmp_path / "band.obj", GV[used], remap[GF[keep]]), GV[used], remap[GF[keep]])


def test_batch_refuses_a_nan_garment_like_the_command_line(tmp_path, ball_files):
    source, target, garment, GV, GF = ball_files
    GV = GV.copy()
    GV[5, 2] = np.nan
    nan = write(tmp_path / "nan.obj", GV, GF)
    before = {p: (p.read_bytes(), os.stat(p).st_mode) for p in tmp_path.iterdir()}
    out = tmp_path / "out"
    proc = run_batch(tmp_path, "--source-body", source, "--target-body", target, "--garment", garment,
                     "--garment", nan, "--out", out)
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    records = json.loads((out / "summary.json").read_text())
    failed = [r for r in records if "error" in r]
    assert len(failed) == 1 and "nan.obj" in failed[0]["garment"]
    assert "vertex 5 has a NaN or infinite coordinate" in failed[0]["error"]
    assert [r["target"] for r in records if "error" not in r] == ["big"]
    assert {p: (p.read_bytes(), os.stat(p).st_mode) for p in before} == before
    assert sorted(p.name for p in out.iterdir()) == ["band_on_big.obj", "summary.json"]


def test_batch_outputs_are_checked_before_the_run(tmp_path, ball_files):
    source, target, garment, *_ = ball_files
    taken = tmp_path / "taken"
    taken.write_text("mine\n")
    before = {p: (p.read_bytes(), os.stat(p).st_mode) for p in tmp_path.iterdir() if p.is_file()}
    for extra, problem in ((["--out", taken], "is a file, not a folder"),
                           (["--out", tmp_path / "o", "--blend", garment], "is the input"),
                           (["--out", tmp_path / "o", "--offset", "nan"], "finite distance")):
        proc = run_batch(tmp_path, "--source-body", source, "--target-body", target, "--garment", garment,
                         *extra)
        assert proc.returncode == 2, proc.stderr
        assert "Traceback" not in proc.stderr and problem in proc.stderr.strip().splitlines()[-1]
    assert {p: (p.read_bytes(), os.stat(p).st_mode) for p in before} == before
    assert not (tmp_path / "o").exists()
