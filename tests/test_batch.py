"""The batch command: catalogues, resumable runs, failures, interruptions, and Dask against a serial run."""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from meshes import icosphere, require_makehuman

from garment_transfer.geometry.mesh import mesh_from_triangles
from garment_transfer.geometry.obj import read_obj, write_obj
from garment_transfer.pipeline import batch
from garment_transfer.pipeline.batch import run_batch
from garment_transfer.pipeline.catalogue import CatalogueError, read_catalogue

ROOT = Path(__file__).resolve().parents[1]
PYTHON_ENV = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))

# Ellipsoids of one topology: x, y, z scale of the unit sphere.
SHAPES = {"round": (1.0, 1.0, 1.0), "wide": (1.25, 1.0, 1.0), "tall": (1.0, 1.0, 1.2),
          "flat": (1.1, 0.85, 1.0)}
# Garments: the part of the sphere between two heights, 3% outside the body.
GARMENTS = {"band": (-0.5, 0.5), "top": (0.2, 1.1), "skirt": (-1.1, -0.2)}


def make_dataset(folder, shapes=SHAPES, garments=GARMENTS, subdivisions=3):
    """A dataset folder of ellipsoid bodies and sphere-zone garments on each of them."""
    V, F = icosphere(subdivisions)
    (folder / "bodies").mkdir(parents=True)
    for name, scale in shapes.items():
        write_obj(folder / "bodies" / f"{name}.obj", mesh_from_triangles(V * np.array(scale), F))
    for g, (lo, hi) in garments.items():
        z = V[F][:, :, 2]
        keep = np.all((z > lo) & (z < hi), axis=1)
        used = np.unique(F[keep])
        remap = np.full(len(V), -1)
        remap[used] = np.arange(len(used))
        (folder / "garments" / g).mkdir(parents=True)
        for name, scale in shapes.items():
            write_obj(folder / "garments" / g / f"{name}.obj",
                      mesh_from_triangles(V[used] * np.array(scale) * 1.03, remap[F[keep]]))
    return folder


@pytest.fixture
def dataset(tmp_path):
    return make_dataset(tmp_path / "data")


def catalogue_dict(ds, **settings):
    return {"settings": settings,
            "bodies": {b: f"bodies/{b}.obj" for b in SHAPES},
            "source": "round",
            "targets": ["wide", "tall", "flat"],
            "garments": [{"name": g, "file": f"garments/{g}/round.obj",
                          "references": {t: f"garments/{g}/{t}.obj" for t in ("wide", "tall", "flat")}}
                         for g in GARMENTS]}


def toml_text(d):
    """The catalogue_dict as TOML (the few shapes it uses)."""
    lines = ['source = "round"', 'targets = ["wide", "tall", "flat"]', "[settings]"]
    lines += [f"{k} = {json.dumps(v)}" for k, v in d["settings"].items()]
    lines += ["[bodies]"] + [f'{b} = "{p}"' for b, p in d["bodies"].items()]
    for g in d["garments"]:
        lines += ["[[garments]]", f'name = "{g["name"]}"', f'file = "{g["file"]}"',
                  "references = {" + ", ".join(f'{t} = "{p}"' for t, p in g["references"].items()) + "}"]
    return "\n".join(lines) + "\n"


def results(out):
    """{relative path: bytes} of every result file (.obj)."""
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(Path(out).rglob("*.obj"))}


def metrics(out):
    keep = ("key", *batch.METRIC_KEYS, "output_sha256")
    return {str(p.relative_to(out)): {k: json.loads(p.read_text()).get(k) for k in keep}
            for p in sorted(Path(out).glob("*/*.json"))}


def records_of(folder):
    """{target: record} of the whole records in a garment's results folder."""
    return {p.stem: batch.read_record(p) for p in sorted(Path(folder).glob("*.json"))
            if not p.name.startswith(batch.PARTIAL_PREFIX)}


def leftovers(out):
    return [p for p in Path(out).rglob("*") if p.name.startswith(batch.PARTIAL_PREFIX)]


# --- the catalogue -------------------------------------------------------------------------------


def test_json_toml_and_folder_catalogues_give_the_same_jobs(dataset):
    d = catalogue_dict(dataset, offset=0.01)
    (dataset / "cat.json").write_text(json.dumps(d))
    (dataset / "cat.toml").write_text(toml_text(d))
    a = read_catalogue(dataset / "cat.json")
    b = read_catalogue(dataset / "cat.toml")
    c = read_catalogue(dataset, source="round", targets=["wide", "tall", "flat"],
                       settings={"offset": 0.01})
    def plain(cat):
        return {j.name: (os.path.normpath(j.file), j.source, os.path.normpath(j.source_file), j.settings,
                         [(t.name, os.path.normpath(t.body), t.label, os.path.normpath(t.reference))
                          for t in j.targets]) for j in cat.jobs}

    assert plain(a) == plain(b) == plain(c)
    assert [j.name for j in a.jobs] == [j.name for j in b.jobs] == list(GARMENTS)
    assert a.n_pairs == 9 and a.jobs[0].settings.offset == 0.01
    assert a.jobs[0].file == str(dataset / "garments" / "band" / "round.obj")


BAD_ENTRIES = [
    ({"method": "magic"}, "garments[1] 'top'", "method 'magic' is unknown"),
    ({"targets": ["wide", "nobody"]}, "garments[1] 'top' targets[1]", "'nobody' is not a body"),
    ({"targets": ["wide", "wide"]}, "garments[1] 'top' targets[1]", "listed twice"),
    ({"targets": ["round"]}, "garments[1] 'top' targets[0]", "is the source body"),
    ({"name": "band"}, "garments[1] 'band'", "already used by garments[0]"),
    ({"name": "a/b"}, "garments[1] 'a/b' name", "not a usable name"),
    ({"method": "model"}, "garments[1] 'top'", "needs a model file"),
    ({"offset": -1}, "garments[1] 'top'", "offset must be a non-negative number"),
    ({"colour": "red"}, "garments[1] 'top'", "unknown key 'colour'"),
    ({"file": "s3://bucket/top.obj"}, "garments[1] 'top' file", "URLs are not read"),
    ({"fix_penetration": "yes"}, "garments[1] 'top'", "must be true or false"),
    ({"field_share": 1.5}, "garments[1] 'top'", "field_share must be a number from 0 to 1"),
    ({"placement": "no"}, "garments[1] 'top'", "placement must be true or false"),
    ({"untangle": 1}, "garments[1] 'top'", "untangle must be true or false"),
]


@pytest.mark.parametrize("change, where, problem", BAD_ENTRIES)
def test_a_bad_entry_is_refused_naming_the_file_and_the_entry(dataset, change, where, problem):
    d = catalogue_dict(dataset)
    d["garments"][1].update(change)
    path = dataset / "cat.json"
    path.write_text(json.dumps(d))
    with pytest.raises(CatalogueError) as info:
        read_catalogue(path)
    assert str(info.value).startswith(f"{path}: {where}: "), str(info.value)
    assert problem in str(info.value)


def test_the_command_lines_settings_reach_every_garment_that_does_not_set_its_own(dataset):
    from garment_transfer.cli.commands import build_parser
    from garment_transfer.cli.paths import batch_catalogue

    d = catalogue_dict(dataset)
    d["garments"][1].update(untangle=False, interpolate=True)
    path = dataset / "cat.json"
    path.write_text(json.dumps(d))
    args = build_parser().parse_args(["batch", str(path), "--out", str(dataset / "out"), "--untangle",
                                      "--no-interpolate"])
    jobs = batch_catalogue(args).jobs
    assert [(j.settings.untangle, j.settings.interpolate) for j in jobs] == [(True, False), (False, True),
                                                                             (True, False)]
    plain = batch_catalogue(build_parser().parse_args(["batch", str(path), "--out", str(dataset / "out")])).jobs
    assert [(j.settings.untangle, j.settings.interpolate) for j in plain] == [(False, True)] * 3


def test_unreadable_catalogues_are_refused(dataset):
    bad = dataset / "bad.toml"
    bad.write_text("garments = [\n")
    with pytest.raises(CatalogueError, match="is not valid TOML"):
        read_catalogue(bad)
    with pytest.raises(CatalogueError, match="catalogue not found"):
        read_catalogue(dataset / "none.json")
    with pytest.raises(CatalogueError, match=r"say which body .*round"):
        read_catalogue(dataset)
    with pytest.raises(CatalogueError, match="bodies"):
        (dataset / "x.json").write_text(json.dumps({"garments": []}))
        read_catalogue(dataset / "x.json")


# --- runs in this process ------------------------------------------------------------------------


def test_serial_run_matches_the_core_writes_a_summary_and_a_rerun_does_no_work(dataset, tmp_path,
                                                                                monkeypatch):
    from garment_transfer.pipeline.transfer import transfer_garment

    cat = read_catalogue(dataset, source="round")
    out = tmp_path / "out"
    seen = []
    summary = run_batch(cat, out, workers=1, progress=lambda d, n, r: seen.append((d, n)))
    assert summary.ok and summary.counts["done"] == 9 and summary.interrupted is False
    assert seen[0] == (0, 9) and seen[-1] == (9, 9)
    # The result is exactly what the core makes of the same files.
    body = read_obj(dataset / "bodies" / "round.obj")
    garment = read_obj(dataset / "garments" / "top" / "round.obj")
    expected = transfer_garment(body, read_obj(dataset / "bodies" / "tall.obj"), garment).V
    np.testing.assert_allclose(read_obj(out / "top" / "tall.obj").V, expected, rtol=1e-8, atol=1e-9)
    # Summary: every pair once, in catalogue order, with metrics against the reference.
    doc = json.loads((out / "summary.json").read_text())
    assert [(r["garment"], r["target"]) for r in doc["pairs"]] == cat.pairs()
    assert all(r["drape_reference"] == "reference" and r["vertex_error_mean"] < 0.05 for r in doc["pairs"])
    rows = (out / "summary.csv").read_text().splitlines()
    assert len(rows) == 10 and rows[0].startswith("garment,target,label,outcome")
    assert rows[1].startswith("band,flat,,done,")
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.suffix in (".obj", ".json")
              and p.parent != out}
    files = results(out)

    # A re-run transfers nothing: no garment is even prepared.
    def boom(*a, **k):
        raise AssertionError("a re-run must not transfer again")

    monkeypatch.setattr("garment_transfer.pipeline.batch.prepare_garment", boom)
    monkeypatch.setattr("garment_transfer.pipeline.batch.transfer_to_any_body", boom)
    again = run_batch(cat, out, workers=1)
    assert again.ok and again.counts["skipped"] == 9 and again.counts["done"] == 0
    assert {p: p.stat().st_mtime_ns for p in before} == before
    assert results(out) == files
    assert [r["mdc"] for r in again.records] == [r["mdc"] for r in summary.records]


def test_a_garment_file_with_latin1_comments_and_a_material_library(dataset, tmp_path):
    """The result keeps the file's bytes (a Latin-1 comment) and names its material library from where it is."""
    folder = dataset / "garments" / "top"
    (folder / "cloth.mtl").write_text("newmtl cotton\nKd 0.8 0.1 0.1\n")
    data = (folder / "round.obj").read_bytes()
    (folder / "round.obj").write_bytes(b"# caf\xe9 cr\xe8me\nmtllib cloth.mtl\nusemtl cotton\n" + data)
    out = tmp_path / "out"
    summary = run_batch(read_catalogue(dataset, source="round"), out, workers=1)
    assert summary.ok and summary.counts["done"] == 9
    written = (out / "top" / "tall.obj").read_bytes().split(b"\n")
    assert written[0] == b"# caf\xe9 cr\xe8me" and written[2] == b"usemtl cotton"
    library = written[1].decode().removeprefix("mtllib ")
    assert (out / "top" / library).resolve() == (folder / "cloth.mtl").resolve()


def test_a_changed_setting_or_input_redoes_only_what_it_touches(dataset, tmp_path):
    out = tmp_path / "out"
    run_batch(read_catalogue(dataset, source="round"), out, workers=1)
    # A new offset for one garment only: its three pairs are redone, the rest skipped.
    d = catalogue_dict(dataset)
    d["garments"][1]["offset"] = 0.05
    (dataset / "cat.json").write_text(json.dumps(d))
    s = run_batch(read_catalogue(dataset / "cat.json"), out, workers=1)
    assert {(r["garment"], r["outcome"]) for r in s.records} == {("band", "skipped"), ("top", "done"),
                                                                  ("skirt", "skipped")}
    # A target body whose file changed: every garment's pair on it is redone.
    body = dataset / "bodies" / "flat.obj"
    body.write_text(body.read_text().replace("v ", "v  ", 1))
    s = run_batch(read_catalogue(dataset / "cat.json"), out, workers=1)
    assert sorted(r["target"] for r in s.records if r["outcome"] == "done") == ["flat"] * 3
    # A result file damaged after the run is made again.
    (out / "band" / "wide.obj").write_text("damaged")
    s = run_batch(read_catalogue(dataset / "cat.json"), out, workers=1)
    assert [(r["garment"], r["target"]) for r in s.records if r["outcome"] == "done"] == [("band", "wide")]


def test_a_garment_fit_model_file_with_its_placement_and_a_field_share(tmp_path):
    pytest.importorskip("torch")
    from test_dataset import make_tiny_dataset

    from garment_transfer.learning.garment_training import train_garment_fit_from_dataset
    from garment_transfer.learning.model_files import read_model_file
    from garment_transfer.pipeline.transfer import transfer_garment

    ds = make_tiny_dataset(tmp_path / "ds")
    model = tmp_path / "garment.npz"
    train_garment_fit_from_dataset(ds, "src", ["similar", "pear"], garments=["band", "skirt"],
                                   placement_epochs=10, out=model, threads=1)
    out = tmp_path / "out"
    cat = read_catalogue(ds, source="src", targets=["pear"], garments=["top"],
                         settings={"method": "model", "model": str(model)})
    s = run_batch(cat, out, workers=1)
    assert s.ok and s.counts["done"] == 1
    record = json.loads((out / "top" / "pear.json").read_text())
    assert (record["model_kind"], record["field_share"], record["placement"]) == ("garment", 0.5, True)
    from garment_transfer.learning.placement import LIBRARY_SHARE

    assert record["nearest_garments"] == LIBRARY_SHARE          # the default training mixes them in
    assert "field_share" not in record["settings"]          # unset: not part of the result's key
    loaded = read_model_file(model)
    expected = transfer_garment(read_obj(ds / "bodies" / "src.obj"), read_obj(ds / "bodies" / "pear.obj"),
                                read_obj(ds / "garments" / "top" / "src.obj"), method="model", model=loaded.model,
                                placement=loaded.placement, target="pear").V
    np.testing.assert_allclose(read_obj(out / "top" / "pear.obj").V, expected, rtol=1e-8, atol=1e-9)
    # Another share is another result: the pair is done again.
    cat = read_catalogue(ds, source="src", targets=["pear"], garments=["top"],
                         settings={"method": "model", "model": str(model), "field_share": 1.0})
    s = run_batch(cat, out, workers=1)
    assert s.counts["done"] == 1
    record = json.loads((out / "top" / "pear.json").read_text())
    assert record["field_share"] == 1.0 and record["settings"]["field_share"] == 1.0
    assert np.abs(read_obj(out / "top" / "pear.obj").V - expected).max() > 1e-5
    # The file's placement left out: the result is the transfer without it, and it is done again.
    cat = read_catalogue(ds, source="src", targets=["pear"], garments=["top"],
                         settings={"method": "model", "model": str(model), "placement": False})
    s = run_batch(cat, out, workers=1)
    assert s.counts["done"] == 1
    record = json.loads((out / "top" / "pear.json").read_text())
    assert record["placement"] is False and record["settings"]["placement"] is False
    unplaced = transfer_garment(read_obj(ds / "bodies" / "src.obj"), read_obj(ds / "bodies" / "pear.obj"),
                                read_obj(ds / "garments" / "top" / "src.obj"), method="model",
                                model=loaded.model, target="pear").V
    np.testing.assert_allclose(read_obj(out / "top" / "pear.obj").V, unplaced, rtol=1e-8, atol=1e-9)
    assert np.abs(unplaced - expected).max() > 1e-5


def test_a_broken_garment_and_a_missing_body_fail_and_the_rest_is_done(dataset, tmp_path, capsys):
    from garment_transfer.cli import main

    (dataset / "garments" / "top" / "round.obj").write_bytes(bytes(range(256)) * 4)
    d = catalogue_dict(dataset)
    d["bodies"]["gone"] = "bodies/gone.obj"
    d["targets"] = ["wide", "gone", "tall"]
    for g in d["garments"]:
        g.pop("references")
    (dataset / "cat.json").write_text(json.dumps(d))
    out = tmp_path / "out"
    code = main(["batch", str(dataset / "cat.json"), "--out", str(out), "--workers", "1", "--json"])
    assert code == 1
    printed = json.loads(capsys.readouterr().out)
    assert printed["counts"] == {"done": 4, "skipped": 0, "failed": 5, "not run": 0}
    pairs = {(r["garment"], r["target"]): r for r in json.loads((out / "summary.json").read_text())["pairs"]}
    for t in ("wide", "tall"):
        assert pairs["top", t]["error"].startswith(f"{dataset / 'garments' / 'top' / 'round.obj'}: "
                                                   "is not a text OBJ file")
    for g in ("band", "skirt", "top"):
        assert pairs[g, "gone"]["error"] == f"{dataset / 'bodies' / 'gone.obj'}: file not found"
    for g in ("band", "skirt"):
        assert pairs[g, "wide"]["outcome"] == pairs[g, "tall"]["outcome"] == "done"
        # Without a reference: the design kept and penetration, no drape error.
        r = pairs[g, "wide"]
        assert r["drape_reference"] is None and r["drape_error"] is None
        assert r["mdc"] > 0 and r["penetration_ratio"] == 0.0
    assert sorted(results(out)) == ["band/tall.obj", "band/wide.obj", "skirt/tall.obj", "skirt/wide.obj"]
    log = (out / "batch.log").read_text()
    assert log.count("FAILED") == 5 and log.count(" done ") == 4


def test_atomic_write_leaves_nothing_when_interrupted(tmp_path, monkeypatch):
    target = tmp_path / "r.obj"
    target.write_text("old")

    def interrupted(*a):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        batch.write_atomic(target, b"new")
    assert target.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["r.obj"]


def test_a_stopped_run_records_what_it_did_and_resumes(dataset, tmp_path):
    cat = read_catalogue(dataset, source="round")
    out = tmp_path / "out"
    # Stop after the fourth pair's record, as Ctrl+C would.
    s = run_batch(cat, out, workers=1, progress=lambda d, n, r: d >= 4)
    assert s.interrupted and not s.ok
    assert s.counts["done"] + s.counts["not run"] == 9 and s.counts["done"] >= 4
    assert json.loads((out / "summary.json").read_text())["interrupted"] is True
    assert not leftovers(out)
    again = run_batch(cat, out, workers=1)
    assert again.ok and again.counts["skipped"] == s.counts["done"]
    assert again.counts["done"] == s.counts["not run"]


@pytest.mark.parametrize("workers", ["1", "2"])
def test_ctrl_c_stops_cleanly_with_exit_130_and_only_whole_files(tmp_path, workers):
    # Enough work (3 garments x 12 targets, finer meshes: about 4 s of transfers on 2 cores) that some is left
    # when the first record appears, even when this test is slow to see it on a busy machine: the run is stopped
    # then.
    shapes = dict(SHAPES, **{f"wide{k}": (1.0 + 0.03 * k, 1.0, 1.0) for k in range(1, 10)})
    ds = make_dataset(tmp_path / "data", shapes=shapes, subdivisions=4)
    out = tmp_path / "out"
    # Started as a terminal starts it, with Ctrl+C's default: a test run started in the background by a
    # script ignores SIGINT, its children inherit that, and Python then installs no KeyboardInterrupt.
    as_in_a_terminal = ("import runpy, signal; signal.signal(signal.SIGINT, signal.default_int_handler); "
                        "runpy.run_module('garment_transfer', run_name='__main__', alter_sys=True)")
    cmd = [sys.executable, "-c", as_in_a_terminal, "batch", str(ds), "--source", "round",
           "--out", str(out), "--workers", workers]
    proc = subprocess.Popen(cmd, env=PYTHON_ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)
    deadline = time.monotonic() + 120
    while not list(out.glob("*/*.json")) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.01)
    # Ctrl+C reaches every process of the terminal's group: the driver and its workers.
    os.killpg(proc.pid, signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "(interrupted)" in stdout
    assert not leftovers(out)
    doc = json.loads((out / "summary.json").read_text())
    assert doc["interrupted"] and doc["counts"]["not run"] > 0
    n = read_obj(ds / "garments" / "band" / "round.obj").n_vertices
    for p in out.glob("*/*.obj"):
        if p.stem in ("wide", "tall", "flat") and p.parent.name == "band":
            assert read_obj(p).n_vertices == n
        record = batch.read_record(p.with_suffix(".json"))
        if record is not None:
            assert record["output_sha256"] == batch.file_digest(p)
    # The re-run does the rest and only the rest.
    again = subprocess.run(cmd[:-2] + ["--workers", "2", "--json"], env=PYTHON_ENV, capture_output=True,
                           text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    counts = json.loads(again.stdout)["counts"]
    assert counts["skipped"] == doc["counts"]["done"] and counts["done"] == 3 * 12 - counts["skipped"]


# --- Dask ----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def dask_client():
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=None, env={"PYTHONPATH": PYTHON_ENV["PYTHONPATH"]})
    client = distributed.Client(cluster)
    yield client
    client.close()
    cluster.close()


@pytest.mark.slow
def test_a_two_worker_dask_cluster_gives_the_same_bits_as_a_serial_run(dataset, tmp_path, dask_client):
    cat = read_catalogue(dataset, source="round")
    serial = run_batch(cat, tmp_path / "serial", workers=1)
    dask = run_batch(cat, tmp_path / "dask", client=dask_client)
    assert serial.ok and dask.ok and dask.counts["done"] == 9
    assert dask.info["executor"] == "dask" and dask.info["workers"] == 2
    assert results(tmp_path / "dask") == results(tmp_path / "serial")
    assert metrics(tmp_path / "dask") == metrics(tmp_path / "serial")
    # Both workers took part.
    assert len({r["worker"] for r in dask.records}) == 2


@pytest.mark.slow
def test_makehuman_on_dask_matches_serial_bit_for_bit(tmp_path, dask_client):
    root = require_makehuman()
    cat = read_catalogue(root, source="female_average", targets=["female_pear"],
                         garments=["female_sportsuit01", "male_casualsuit04"])
    serial = run_batch(cat, tmp_path / "serial", workers=1)
    dask = run_batch(cat, tmp_path / "dask", client=dask_client)
    assert serial.ok and dask.ok and dask.counts["done"] == 2
    assert results(tmp_path / "dask") == results(tmp_path / "serial")
    assert metrics(tmp_path / "dask") == metrics(tmp_path / "serial")


@pytest.mark.slow
def test_a_worker_killed_mid_garment_the_batch_completes_with_every_pair_done_once(tmp_path, dask_client):
    targets = {f"t{i}": (1.0 + 0.04 * i, 1.0, 1.0 + 0.03 * i) for i in range(1, 7)}
    ds = make_dataset(tmp_path / "data", shapes={"round": (1.0, 1.0, 1.0), **targets},
                      garments={"band": (-0.5, 0.5), "top": (0.2, 1.1)})
    cat = read_catalogue(ds, source="round")
    out = tmp_path / "dask"
    pids = dask_client.run(os.getpid)
    box = {}
    runner = threading.Thread(target=lambda: box.update(s=run_batch(cat, out, client=dask_client)))
    runner.start()
    victim, garment, before = None, None, []
    deadline = time.monotonic() + 120
    while victim is None and time.monotonic() < deadline and runner.is_alive():
        for folder in out.glob("*"):
            seen = {int(r["worker"].rsplit(":", 1)[1]) for r in records_of(folder).values() if r}
            if seen & set(pids.values()):
                victim, garment = (seen & set(pids.values())).pop(), folder.name
                os.kill(victim, signal.SIGSTOP)
                break
        time.sleep(0.005)
    assert victim is not None, "no result appeared"
    before = sorted(t for t, r in records_of(out / garment).items() if r["worker"].endswith(f":{victim}"))
    os.kill(victim, signal.SIGKILL)
    runner.join(300)
    summary = box["s"]
    # The victim was in the middle of its garment.
    assert 0 < len(before) < len(targets)
    assert summary.ok and summary.counts == {"done": 12, "skipped": 0, "failed": 0, "not run": 0}
    assert sorted((r["garment"], r["target"]) for r in summary.records) == sorted(cat.pairs())
    # What the victim wrote was kept, not done again; the rest was done by the living worker.
    after = sorted(t for t, r in records_of(out / garment).items() if r["worker"].endswith(f":{victim}"))
    assert after == before
    assert not leftovers(out)
    run_batch(cat, tmp_path / "serial", workers=1)
    assert results(out) == results(tmp_path / "serial")


def test_dask_runs_without_dask_installed_say_what_to_install(dataset, tmp_path, monkeypatch, capsys):
    from garment_transfer.cli import main

    monkeypatch.setitem(sys.modules, "distributed", None)
    code = main(["batch", str(dataset), "--source", "round", "--out", str(tmp_path / "out"), "--dask"])
    assert code == 1
    assert "pip install 'dask[distributed]'" in capsys.readouterr().err
    assert not list((tmp_path / "out").glob("*/*.obj"))


def test_every_module_a_transfer_runs_is_in_the_code_version():
    # A result is stale when any code that made it changes: the crossings pass (clearance, intersections) as
    # much as the solve. Every package module a transfer and its metrics load is hashed.
    import sys

    from meshes import icosphere

    from garment_transfer.geometry.mesh import mesh_from_triangles
    from garment_transfer.pipeline.batch import NOT_RESULT_MODULES, result_modules
    from garment_transfer.pipeline.metrics import evaluate
    from garment_transfer.pipeline.transfer import transfer_garment

    V, F = icosphere(2)
    source = mesh_from_triangles(V, F, name="source")
    target = mesh_from_triangles(V * [1.2, 1.2, 1.0], F, name="target")
    GV, GF = icosphere(1, radius=1.03)
    garment = mesh_from_triangles(GV, GF, name="garment")
    result = transfer_garment(source, target, garment)
    evaluate(garment, garment.with_vertices(result.V), target, intersections=True)
    loaded = {name[len("garment_transfer."):] for name in sys.modules if name.startswith("garment_transfer.")}
    loaded = {m for m in loaded if not (ROOT / "garment_transfer" / m.replace(".", "/") / "__init__.py").exists()}
    hashed = set(result_modules())
    not_result = {m for m in loaded if m.replace(".", "/") in NOT_RESULT_MODULES
                  or m.split(".")[0] in NOT_RESULT_MODULES}
    assert {"geometry.clearance", "geometry.intersections", "pipeline.transfer", "geometry.penetration"} <= hashed
    assert loaded - not_result <= hashed
    assert not hashed & not_result


def test_a_catalogue_onto_a_body_of_another_mesh_registers_it_once_for_every_garment(tmp_path, monkeypatch):
    from lab.registration import remesh

    from garment_transfer.pipeline.any_body import registration_for
    from garment_transfer.geometry.intersections import crossings
    from garment_transfer.geometry.readings import readings_of

    root = require_makehuman()
    pear = read_obj(root / "bodies" / "female_pear.obj")
    write_obj(tmp_path / "pear_remeshed.obj", mesh_from_triangles(*remesh(pear.V, pear.F, 30000)))
    garments = ("female_sportsuit01", "female_casualsuit01")
    cat = {"source": "female_average", "targets": ["female_pear", "pear_remeshed"],
           "bodies": {"female_average": str(root / "bodies" / "female_average.obj"),
                      "female_pear": str(root / "bodies" / "female_pear.obj"), "pear_remeshed": "pear_remeshed.obj"},
           "garments": [{"name": g, "file": str(root / "garments" / g / "female_average.obj")} for g in garments]}
    (tmp_path / "cat.json").write_text(json.dumps(cat))
    fits = []

    def counted(*args, **kwargs):
        fits.append(args[1].name)
        logging.getLogger("garment_transfer.fitting.registration").warning("a warning of the fit")
        return registration_for(*args, **kwargs)

    monkeypatch.setattr(batch, "registration_for", counted)
    batch.clear_input_cache()
    summary = run_batch(read_catalogue(tmp_path / "cat.json"), tmp_path / "out", workers=1)
    assert summary.ok and summary.counts["done"] == 4
    # Registered once for both garments; the pear's own mesh not at all. The summary says which pairs were, also
    # when a run finds them done.
    assert fits == ["pear_remeshed"]
    import csv

    for run in (summary, run_batch(read_catalogue(tmp_path / "cat.json"), tmp_path / "out", workers=1)):
        rows = list(csv.DictReader((tmp_path / "out" / "summary.csv").open()))
        assert {(r["target"], r["registered"]) for r in rows} == {("female_pear", "False"), ("pear_remeshed", "True")}
        assert [r["registered"] for r in run.records] == [False, True, False, True]
    assert fits == ["pear_remeshed"]
    body = read_obj(tmp_path / "pear_remeshed.obj")
    for g in garments:
        record = json.loads((tmp_path / "out" / g / "pear_remeshed.json").read_text())
        own = json.loads((tmp_path / "out" / g / "female_pear.json").read_text())
        assert record["registered"] and not own["registered"] and "registration" not in own
        assert record["registration"]["quality"]["to_target_mean"] < 0.01
        # What the fit logged is in each record that used it (a worker's log is not the user's).
        assert "a warning of the fit" in record["warnings"] and "a warning of the fit" not in own["warnings"]
        # The file as written, against the body given: clean under every split, as the record says.
        written = read_obj(tmp_path / "out" / g / "pear_remeshed.obj")
        c = crossings(written.V, readings_of(written), body.V, body.F)
        assert c["a_edge_pairs"] == c["b_edge_pairs"] == 0 == record["crossings_left"]
        # Near the transfer onto the pear's own mesh (the registration's error; measured: 2.3 and 2.6 mm on average).
        assert np.linalg.norm(written.V - read_obj(tmp_path / "out" / g / "female_pear.obj").V, axis=1).mean() < 0.04


def test_a_catalogue_with_a_rig_poses_the_source_into_a_target_standing_otherwise(tmp_path):
    from garment_transfer import Rig, bvh_rotations, read_bvh, read_joints, read_skeleton, read_weights
    from garment_transfer.pipeline.transfer import transfer_garment
    from lab.rest_pose_study import bones_data, named_bones

    root = require_makehuman()
    skeleton = read_skeleton(root / "rig" / "skeleton.json")
    pear = read_obj(root / "bodies" / "female_pear.obj")
    rig = Rig(skeleton, read_joints(root / "rig" / "joints" / "female_pear.json"),
              read_weights(root / "rig" / "weights.json", pear.n_vertices))
    T = rig.transforms(bvh_rotations(read_bvh(root / "poses" / "fight01.bvh"), skeleton))
    write_obj(tmp_path / "kicking.obj", pear.with_vertices(rig.pose(pear.V, T)))
    # The same kick as another mesh with more vertices than the source's (registered).
    from lab.registration import remesh

    write_obj(tmp_path / "kicking_remeshed.obj", mesh_from_triangles(*remesh(rig.pose(pear.V, T), pear.F, 32000)))
    # Its armature's bones as they stand, each with its roll (its Z axis): the kick's frames, not only its joints.
    joints, frames = rig.posed_joints(T), rig.posed_frames(T)
    (tmp_path / "kicking.json").write_text(json.dumps({"bones": {
        b: {"parent": None if p < 0 else skeleton.names[p], "head": joints[h].tolist(), "tail": joints[t].tolist(),
            "z_axis": frames[i][:, 2].tolist()}
        for i, (b, p, h, t) in enumerate(zip(skeleton.names, skeleton.parents, skeleton.heads, skeleton.tails))}}))
    # The same character with a Mixamo skeleton: its bones as they stand.
    bones = named_bones(skeleton, rig.posed_joints(T), "Mixamo", prefix="mixamorig:")
    (tmp_path / "kicking_mixamo.json").write_text(json.dumps(bones_data(bones)))
    joints = root / "rig" / "joints"
    cat = {"source": "female_average", "targets": ["female_pear", "kicking", "kicking_mixamo", "kicking_remeshed"],
           "bodies": {"female_average": str(root / "bodies" / "female_average.obj"),
                      "female_pear": str(root / "bodies" / "female_pear.obj"), "kicking": "kicking.obj",
                      "kicking_mixamo": "kicking.obj", "kicking_remeshed": "kicking_remeshed.obj"},
           "rig": {"skeleton": str(root / "rig" / "skeleton.json"), "weights": str(root / "rig" / "weights.json"),
                   "joints": {"female_average": str(joints / "female_average.json"),
                              "female_pear": str(joints / "female_pear.json"), "kicking": "kicking.json",
                              "kicking_mixamo": "kicking_mixamo.json", "kicking_remeshed": "kicking.json"}},
           "garments": [{"name": "suit", "file": str(root / "garments" / "female_sportsuit01" /
                                                      "female_average.obj")}]}
    (tmp_path / "cat.json").write_text(json.dumps(cat))
    catalogue = read_catalogue(tmp_path / "cat.json")
    assert str(tmp_path / "kicking.json") in catalogue.inputs()[0]
    summary = run_batch(catalogue, tmp_path / "out", workers=1)
    assert summary.ok and summary.counts["done"] == 4
    # Another mesh: registered, counted as written where the source at rest (through the registration) says which
    # parts the kick pressed together.
    remeshed = json.loads((tmp_path / "out" / "suit" / "kicking_remeshed.json").read_text())
    assert remeshed["rest_pose"]["posed"] and remeshed["rest_pose"]["twist"] == "frames"
    assert remeshed["rest_pose"]["written"]["crossings_outside_contact"] == 0
    kicking = json.loads((tmp_path / "out" / "suit" / "kicking.json").read_text())
    # Matched by its landmarks, said in the record with what they leave out; clean away from the body's contact.
    mixamo = json.loads((tmp_path / "out" / "suit" / "kicking_mixamo.json").read_text())
    assert kicking["rest_pose"]["skeletons"] == {"by": "names"}
    assert mixamo["rest_pose"]["skeletons"]["by"] == "landmarks" and mixamo["rest_pose"]["posed"]
    assert mixamo["rest_pose"]["written"]["crossings_outside_contact"] == 0
    assert any("its Mixamo skeleton was matched" in w for w in mixamo["warnings"])
    pear_record = json.loads((tmp_path / "out" / "suit" / "female_pear.json").read_text())
    # The kicking target: posed into first, counted as written apart where the kick makes the body cross itself.
    assert kicking["rest_pose"]["posed"] and kicking["rest_pose"]["largest_turn"] > 45
    assert kicking["rest_pose"]["twist"] == "frames" and mixamo["rest_pose"]["twist"] == "body"
    assert kicking["rest_pose"]["written"]["crossings_outside_contact"] == 0
    assert set(kicking["rest_pose"]["written"]["warnings"]) <= set(kicking["warnings"])
    # The kick folds the suit through itself where its source is not (measured: 25 pairs): said, naming the remedy.
    assert kicking["check"]["self_intersections_new"] > 0 and "untangle" not in kicking["settings"]
    assert any("the setting untangle (batch --untangle) undoes it" in w for w in kicking["warnings"])
    # Untangled (a setting, so the pair is done again): none left, counted on the file as written; the record keeps
    # both steps' figures and the setting, and the kick is crossed no more away from the body's contact.
    again = run_batch(read_catalogue(tmp_path / "cat.json", targets=["kicking"], settings={"untangle": True}),
                      tmp_path / "out", workers=1)
    assert again.ok and again.counts["done"] == 1
    untangled = json.loads((tmp_path / "out" / "suit" / "kicking.json").read_text())
    assert untangled["settings"]["untangle"] is True and untangled["rest_pose"]["untangle"]["fit"]["kept"]
    assert untangled["check"]["self_intersections_new"] == 0
    assert untangled["rest_pose"]["written"]["crossings_outside_contact"] == 0
    assert not any("undoes it" in w for w in untangled["warnings"])
    # The pear stands as the source does: the plain transfer, bit for bit.
    assert pear_record["rest_pose"]["posed"] is False
    source = read_obj(root / "bodies" / "female_average.obj")
    garment = read_obj(root / "garments" / "female_sportsuit01" / "female_average.obj")
    plain = transfer_garment(source, pear, garment).V
    assert np.abs(read_obj(tmp_path / "out" / "suit" / "female_pear.obj").V - plain).max() < 1e-8
    # A joints file of a body the catalogue lacks is named.
    cat["rig"]["joints"]["nobody"] = "kicking.json"
    (tmp_path / "cat.json").write_text(json.dumps(cat))
    with pytest.raises(CatalogueError, match=r"cat.json: rig.joints.nobody: 'nobody' is not a body"):
        read_catalogue(tmp_path / "cat.json")
