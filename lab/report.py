"""Benchmark report: the shared deformation model against the paper, the baselines and simulation, side by side.

``python -m lab report DIR [--quick]`` writes ``DIR/report.md``, ``DIR/report.json``
and plots (PNG). Every figure comes from the run that writes it; the only numbers typed in are the
paper's published ones (``PAPER_TABLE1``, ``PAPER_TRAINING``, ``bench.PAPER_SECONDS``), always labelled
as the paper's.

Sections:

* **Quality**, on every test garment of the demo data (the reference on each target body is the garment
  draped there by Blender's cloth solver) and, leave-one-garment-out, on every MakeHuman fixture garment
  (the reference is the garment fitted on each body). Methods: the shared deformation model with our changes
  (``shared``: masked loss, interpolated field, penetration fix; the product's own method, the garment fit
  model with its placement, is measured by the demo, ``python -m lab demo``), the paper as written
  (nearest-triangle embedding, unmasked loss, no fix),
  direct deformation transfer (the body's own gradients), Blender's Surface Deform modifier (bound to
  the source body, evaluated on the target shape; ``lab/blender/surface_deform_baseline.py`` in a
  subprocess) and the reference itself (simulation or fitted garment). Figures: ``metrics.evaluate``.
* **Outfits** of several layers (``lab/outfits.py``): two outfits of demo garments transferred together to
  the demo targets, per layer crossings with the body and the layers under it, self-intersections,
  smallest distances, MDC, and the refusal of each outfit's reversed order.
* **Speed and scale**: ``lab.bench.run_bench`` per stage, cold and with the garment's factor reused, from
  28K to 300K triangles, against the paper's times; one garment to six bodies.
* **Peak memory**: the largest benchmark size and a 1M-triangle garment, each in a fresh process
  (``resource.getrusage`` high-water mark).
* **Training** at the paper's scale (a 37,744-triangle body, 15 garments, 1000 epochs) on the synthetic
  fields of ``lab/training_scale.py``, with its loss curve.

The core never imports bpy: Blender runs in subprocesses only.
"""

from __future__ import annotations

import json
import logging
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from garment_transfer.files import json_default, write_text_atomic

from .bench import PAPER_SECONDS, TUBE_CROSSINGS, machine_description, solver_text
from .experiment import METHODS as ALL_METHODS
from .experiment import curve_recorder, run_experiment, thin
from .outfits import outfits_markdown, run_outfits
from .paths import BLENDER_SCRIPTS, DEMO_DATA, MAKEHUMAN_SOURCE, MAKEHUMAN_TARGETS, ROOT, makehuman_folder, mm_per_unit

log = logging.getLogger(__name__)

#: The paper's table 1 (Shi et al.), published figures: vertices, triangles, MDC of their transfer and of
#: the simulation on the target, total transfer time (s) on an i7-8750H laptop. Keyed by the demo data's
#: garment of the same name.
PAPER_TABLE1 = {
    "shift_dress": {"name": "Shift Dress", "vertices": 14149, "triangles": 28004, "mdc": 0.0203,
                    "mdc_simulation": 0.0541, "seconds": 0.764},
    "formal_dress": {"name": "Formal Dress", "vertices": 23262, "triangles": 46081, "mdc": 0.0223,
                     "mdc_simulation": 0.0640, "seconds": 1.301},
    "wrap_dress": {"name": "Wrap Dress", "vertices": 78169, "triangles": 156054, "mdc": 0.0108,
                   "mdc_simulation": 0.1156, "seconds": 5.928},
    "shorts": {"name": "Conjoined Shorts", "vertices": 13289, "triangles": 26288, "mdc": 0.0224,
               "mdc_simulation": 0.1939, "seconds": 0.711},
    "tshirt": {"name": "T-shirt", "vertices": 41970, "triangles": 83814, "mdc": 0.0119,
               "mdc_simulation": 0.0797, "seconds": 2.822},
}
#: The paper's training (sect. 6.1), published: body triangles, garments, epochs, latent size, seconds.
PAPER_TRAINING = {"triangles": 37744, "garments": 15, "epochs": 1000, "latent": 30, "seconds": 35 * 60}
PAPER_MACHINE = "laptop Intel Core i7-8750H 2.2 GHz, 16 GB RAM, RTX 2070 Max-Q"

#: Methods in report order; the first is the model the report measures against the others.
METHODS = ["shared", "paper", "direct", "surface_deform"]
MODEL = METHODS[0]
#: Figures summarised per method (lower is better for all).
FIGURES = ["mdc", "penetration_ratio", "max_penetration_depth", "drape_error", "drape_error_relative",
           "vertex_error_mean", "seconds"]
_LENGTHS = {"max_penetration_depth", "drape_error", "vertex_error_mean", "vertex_error_max",
            "drape_error_source"}

@dataclass
class ReportSettings:
    """What the report measures; ``quick_settings()`` is the small version the tests run.

    Attributes
    ----------
    sizes : tuple of int
        Garment triangle counts of the speed benchmark.
    repeats : int
        Runs per size (the best is kept).
    targets : int
        Bodies in the multi-target run.
    memory_sizes : tuple of int
        Garment triangle counts whose peak memory is measured, each in a fresh process.
    demo_epochs, makehuman_epochs, scale_epochs : int
        Training epochs on the demo data, per MakeHuman fold, and at the paper's scale.
    demo_test, demo_targets, demo_train : int or None
        At most this many demo test garments, targets, training garments (None: all).
    makehuman_garments, makehuman_targets : int or None
        At most this many MakeHuman garments and targets (None: all).
    makehuman_folds : int or None
        Hold out only the first this many of those garments (None: each in turn).
    outfit_targets : int or None
        The layered outfits go to at most this many demo targets (None: all).
    exact_sample : int
        Points per speed size whose closest points are checked against brute force.
    quick : bool
    """

    sizes: tuple = (28000, 46000, 84000, 156000, 300000)
    repeats: int = 3
    targets: int = 6
    memory_sizes: tuple = (300000, 1000000)
    demo_epochs: int = 400
    makehuman_epochs: int = 400
    scale_epochs: int = 1000
    demo_test: int | None = None
    demo_targets: int | None = None
    demo_train: int | None = None
    makehuman_garments: int | None = None
    makehuman_targets: int | None = None
    makehuman_folds: int | None = None
    outfit_targets: int | None = None
    exact_sample: int = 500
    quick: bool = False


def quick_settings() -> ReportSettings:
    """Tiny sizes and few epochs: the whole report in seconds (for tests; its numbers mean nothing)."""
    return ReportSettings(sizes=(2000, 4000), repeats=1, targets=2, memory_sizes=(3000,), demo_epochs=5,
                          makehuman_epochs=5, scale_epochs=3, demo_test=1, demo_targets=2, demo_train=2,
                          makehuman_garments=3, makehuman_targets=2, makehuman_folds=1, outfit_targets=1,
                          exact_sample=40,
                          quick=True)


# --------------------------------------------------------------------------------------------------
# Blender baselines (subprocesses)


def surface_deform(source_body: Path, targets: dict, garments: dict, workdir: Path) -> dict:
    """Run ``lab/blender/surface_deform_baseline.py`` on every garment and target.

    Parameters
    ----------
    source_body : Path
        OBJ of the source body.
    targets, garments : dict
        Name to OBJ path.
    workdir : Path
        Where the results go.

    Returns
    -------
    dict
        ``blender`` (version), ``garments`` (name to the script's record: ``bind_seconds`` and
        ``targets``, target name to ``seconds`` and ``out``, or ``error``), ``wall_seconds``; or
        ``error`` alone when the script could not run.
    """
    script = BLENDER_SCRIPTS / "surface_deform_baseline.py"
    if not script.is_file():
        return {"error": f"{script} not found"}
    cmd = [sys.executable, "-m", "lab.blender.surface_deform_baseline",
           "--source-body", str(source_body), "--out", str(workdir)]
    for name, path in targets.items():
        cmd += ["--target-body", f"{name}={path}"]
    for name, path in garments.items():
        cmd += ["--garment", f"{name}={path}"]
    t = time.perf_counter()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=1800)
    except subprocess.TimeoutExpired:
        return {"error": "Surface Deform script timed out"}
    wall = time.perf_counter() - t
    out = Path(workdir) / "surface_deform.json"
    if not out.is_file():
        last = (p.stderr.strip().splitlines() or ["no output"])[-1]
        return {"error": f"Surface Deform script failed (exit {p.returncode}): {last}"}
    data = json.loads(out.read_text())
    return {"blender": data.get("blender"), "wall_seconds": wall,
            "garments": {r["garment"]: r for r in data["garments"]}}


def simulation_seconds(manifest) -> dict:
    """Cloth-solver seconds per garment and body, from the demo data's drape log (``manifest.json``).

    Each garment was draped on the source and then morphed into each target, every run with the same
    number of frames; the log records the garment's total, so one body's share is the total divided
    by the number of runs.

    Returns
    -------
    dict
        Garment name to seconds per body; empty when the log is missing.
    """
    entries = manifest.get("drape_log") or []
    runs = 1 + len(manifest.get("targets") or [])
    return {e["garment"]: float(e["seconds"]) / runs for e in entries if e.get("seconds") is not None}


# --------------------------------------------------------------------------------------------------
# Quality


def quality(folder, source, targets, folds, epochs, reference_kind, sim_seconds=None, seed=0,
            progress=None):
    """Every method on held-out garments, against the reference on each target body.

    Parameters
    ----------
    folder : Path
        Dataset folder (``dataset.load_dataset``).
    source : str
    targets : list of str
    folds : list of (list of str, list of str)
        (training garments, test garments): one model pair (the shared model, the paper's) is trained per fold.
    epochs : int
    reference_kind : str
        Method name of the reference rows: ``simulation`` or ``fitted``.
    sim_seconds : dict, optional
        Garment to seconds per body of the reference (simulation time).
    progress : callable(fraction, stage), optional

    Returns
    -------
    dict
        ``rows`` (one per fold, garment, target and method: ``metrics.evaluate``'s figures plus
        ``seconds``), ``trainings`` (per fold and variant: seconds, epochs, losses, loss ``curve``),
        ``surface_deform`` (the script's run), ``read_seconds``, ``units``, ``mm_per_unit``.
    """
    from garment_transfer.geometry.obj import read_obj
    from garment_transfer.learning.dataset import load_dataset

    ds = load_dataset(folder)
    tests = [g for g in ds.garments if any(g in te for _, te in folds)]
    external, sd_summary = {}, {}
    with tempfile.TemporaryDirectory(prefix="gt_surface_deform_") as work:
        if progress:
            progress(0.0, "Surface Deform (Blender)")
        sd = surface_deform(ds.body_path(source), {b: ds.body_path(b) for b in targets},
                            {g: ds.garment_path(g, source) for g in tests}, Path(work))
        if "error" in sd:
            log.warning("Surface Deform baseline: %s", sd["error"])
        for g, rec in sd.get("garments", {}).items():
            for b, res in rec.get("targets", {}).items():
                if "out" in res:
                    external[(g, b)] = (read_obj(res["out"]).V, rec["bind_seconds"] + res["seconds"],
                                        res["seconds"])
        sd_summary = {k: v for k, v in sd.items() if k != "garments"}
        if "garments" in sd:
            sd_summary["failures"] = {g: r["error"] for g, r in sd["garments"].items() if "error" in r}
    out = run_experiment(folder, source, targets, folds, METHODS, epochs, reference=reference_kind, seed=seed,
                         reference_seconds=sim_seconds, external={"surface_deform": external},
                         progress=progress)
    out.update(surface_deform=sd_summary, mm_per_unit=mm_per_unit(ds.units))
    return out


def summarise(result) -> dict:
    """Per method: the mean of each figure over every (garment, target) pair, and pair counts.

    Lengths are also given in millimetres (``<figure>_mm``) when the dataset states its units.

    Returns
    -------
    dict
        Method name to {figure: mean, ``pairs``: count}.
    """
    mm = result.get("mm_per_unit")
    out = {}
    methods = [result["reference"]] + METHODS
    for m in methods:
        rs = [r for r in result["rows"] if r["method"] == m]
        if not rs:
            continue
        s = {"pairs": len(rs)}
        for f in FIGURES:
            vals = [r[f] for r in rs if r.get(f) is not None]
            s[f] = float(np.mean(vals)) if vals else None
            if f in _LENGTHS and mm and s[f] is not None:
                s[f + "_mm"] = s[f] * mm
        out[m] = s
    return out


def worse_than_ours(result, summary) -> list:
    """Where a baseline's mean beats the shared model's (``MODEL``), with the share of pairs where it does.

    The reference itself is left out of the drape and vertex errors (it is what they measure against).

    Returns
    -------
    list of dict
        ``method``, ``figure``, ``ours``, ``theirs``, ``share_of_pairs`` (pairs where the baseline is
        lower than ours).
    """
    ours = summary.get(MODEL)
    if not ours:
        return []
    by = {}
    for r in result["rows"]:
        by[(r["fold"], r["garment"], r["target"], r["method"])] = r
    out = []
    for m, s in summary.items():
        if m == MODEL:
            continue
        for f in FIGURES:
            if m == result["reference"] and f in ("drape_error", "drape_error_relative", "vertex_error_mean"):
                continue
            a, b = ours.get(f), s.get(f)
            if a is None or b is None or not b < a:
                continue
            pairs = [(by[k[:3] + (MODEL,)][f], r[f]) for k, r in by.items()
                     if k[3] == m and k[:3] + (MODEL,) in by and r.get(f) is not None
                     and by[k[:3] + (MODEL,)].get(f) is not None]
            share = float(np.mean([t < o for o, t in pairs])) if pairs else None
            out.append({"method": m, "figure": f, "ours": a, "theirs": b, "share_of_pairs": share})
    return out


def demo_quality(settings, dataset=DEMO_DATA, progress=None):
    """Quality on the demo data's test garments; ``{"skipped": why}`` without a complete dataset."""
    manifest_path = Path(dataset) / "manifest.json"
    if not manifest_path.is_file():
        return {"skipped": f"no demo data manifest at {manifest_path} (the data is not generated)"}
    man = json.loads(manifest_path.read_text())
    need = ("source", "targets", "train_garments", "test_garments")
    if any(k not in man for k in need):
        return {"skipped": f"{manifest_path} lacks one of {', '.join(need)}"}
    targets = list(man["targets"])[:settings.demo_targets]
    train = list(man["train_garments"])[:settings.demo_train]
    test = list(man["test_garments"])[:settings.demo_test]
    out = quality(dataset, man["source"], targets, [(train, test)], settings.demo_epochs, "simulation",
                  simulation_seconds(man), progress=progress)
    out["simulation_time_source"] = (
        "the data generation's drape log in manifest.json (the garment's total over the source and every "
        "target, divided by the number of runs, all of the same length)" if man.get("drape_log")
        else "not recorded")
    out["dataset"] = os.path.relpath(dataset, ROOT) if Path(dataset).is_relative_to(ROOT) else str(dataset)
    return out


def demo_outfits(settings, dataset=DEMO_DATA, progress=None):
    """The layered outfits (``lab.outfits``) on the demo targets; ``{"skipped": why}`` without the data."""
    manifest_path = Path(dataset) / "manifest.json"
    if not manifest_path.is_file():
        return {"skipped": f"no demo data manifest at {manifest_path} (the data is not generated)"}
    targets = list(json.loads(manifest_path.read_text())["targets"])[:settings.outfit_targets]
    return run_outfits(dataset, targets, progress=progress)


def makehuman_quality(settings, folder=None, progress=None):
    """Leave-one-garment-out quality on the MakeHuman fixtures; ``{"skipped": why}`` without them."""
    from garment_transfer.learning.dataset import load_dataset

    folder = folder or makehuman_folder()
    if folder is None:
        return {"skipped": "MakeHuman fixtures not found (../shared/data/makehuman)"}
    ds = load_dataset(folder)
    garments = list(ds.garments)[:settings.makehuman_garments]
    targets = list(MAKEHUMAN_TARGETS)[:settings.makehuman_targets]
    folds = [([o for o in garments if o != g], [g]) for g in garments[:settings.makehuman_folds]]
    out = quality(folder, MAKEHUMAN_SOURCE, targets, folds, settings.makehuman_epochs, "fitted",
                  progress=progress)
    out["dataset"] = "MakeHuman fixtures (../shared/data/makehuman)"
    return out


# --------------------------------------------------------------------------------------------------
# Memory and training at scale


def peak_rss_mb():
    """This process's peak resident memory in MB.

    ``VmHWM`` of ``/proc/self/status`` where there is one: the high-water mark of this process's own
    address space. ``resource.getrusage``'s ``ru_maxrss`` would do in a process started from a small one,
    but Linux carries the parent's size across fork and exec into it, so from a big parent it reports
    the parent. Elsewhere, ``ru_maxrss`` (kilobytes on Linux, bytes on macOS).
    """
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return r / 2.0 ** 20 if sys.platform == "darwin" else r / 1024.0


def memory_case(triangles) -> dict:
    """One cold transfer of a benchmark dress of ``triangles`` triangles, in this process.

    Run it in a fresh process (``measure_memory``), so that the high-water mark is the transfer's.

    Returns
    -------
    dict
        ``triangles``, ``vertices``, ``seconds`` (per stage), ``rss_before_mb`` (peak once the bodies
        and the garment are built), ``peak_rss_mb``, ``penetrating_vertices``.
    """
    from garment_transfer.pipeline.transfer import transfer_garment

    from .bench import bench_bodies, tube_dress

    source, bodies = bench_bodies(1)
    garment = tube_dress(source, int(triangles))
    before = peak_rss_mb()
    t = time.perf_counter()
    r = transfer_garment(source, bodies[0], garment, resolve_crossings=TUBE_CROSSINGS)
    wall = time.perf_counter() - t
    peak = peak_rss_mb()
    return {"triangles": garment.n_triangles, "vertices": garment.n_vertices,
            "seconds": dict(r.seconds, wall=wall), "rss_before_mb": before, "peak_rss_mb": peak,
            "penetrating_vertices": r.penetrating_vertices}


def measure_memory(triangles, timeout=1200) -> dict:
    """``memory_case(triangles)`` in a fresh Python process, so that its peak RSS is its own."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    cmd = [sys.executable, "-m", "lab.report", "--memory-case", str(int(triangles))]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, cwd=str(ROOT))
    except subprocess.TimeoutExpired:
        return {"triangles": int(triangles), "error": f"timed out after {timeout} s"}
    if p.returncode != 0:
        last = (p.stderr.strip().splitlines() or ["no output"])[-1]
        return {"triangles": int(triangles), "error": f"exit {p.returncode}: {last}"}
    return json.loads(p.stdout.strip().splitlines()[-1])


def training_at_scale(epochs) -> dict:
    """Train at the paper's scale on ``lab/training_scale.py``'s synthetic fields.

    Returns
    -------
    dict
        Body triangles, garments, active triangles, epochs, seconds (set-up included), ms per epoch
        (steady), threads, the loss ``curve`` (``[epoch, seconds, loss]``), the paper's time and its ratio
        to ours (with the paper's epoch count only); or ``skipped``.
    """
    from garment_transfer.learning.training import train_model

    from . import training_scale as bt

    fields = bt.synthetic_fields(PAPER_TRAINING["garments"], 1)
    curve = []
    _, info = train_model(fields, latent=PAPER_TRAINING["latent"], epochs=epochs,
                          progress=curve_recorder(curve))
    # Steady cost of an epoch: between the first and the last epoch (the set-up before is left out).
    per_epoch = (curve[-1][1] - curve[0][1]) / (len(curve) - 1) if len(curve) > 1 else None
    return {"data": "synthetic fields of lab/training_scale.py (timing only; no dataset of the "
                    "paper's size is at hand)",
            "body_triangles": fields.body.n_triangles, "garments": len(fields.garments),
            "targets": len(fields.targets), "active_triangles": info["active_triangles"],
            "latent": info["latent"], "epochs": info["epochs"], "optimizer": info["optimizer"],
            "masked": info["masked"], "threads": info["threads"], "seconds": info["seconds"],
            "ms_per_epoch": per_epoch * 1000.0 if per_epoch is not None else None,
            "final_loss": info["final_loss"], "curve": thin(curve),
            "paper_seconds": PAPER_TRAINING["seconds"],
            "paper_ms_per_epoch": 1000.0 * PAPER_TRAINING["seconds"] / PAPER_TRAINING["epochs"],
            "paper_over_ours": (PAPER_TRAINING["seconds"] / info["seconds"]
                                if info["epochs"] == PAPER_TRAINING["epochs"] and info["seconds"] else None)}


# --------------------------------------------------------------------------------------------------
# The whole report


SECTIONS = ("quality", "outfits", "speed", "memory", "training")


def run_report(out, settings: ReportSettings | None = None, quick=False, progress=None,
               demo_dataset=DEMO_DATA, makehuman=None, command=None, only=None) -> dict:
    """Measure everything and write ``out/report.md``, ``out/report.json`` and the plots.

    Parameters
    ----------
    out : str or Path
        Folder (created).
    settings : ReportSettings, optional
        Default: ``quick_settings()`` with ``quick``, else ``ReportSettings()``.
    progress : callable(fraction, stage), optional
    demo_dataset : Path
        The demo dataset folder.
    makehuman : Path, optional
        The MakeHuman fixtures (default: ``bench.makehuman_folder()``).
    command : str, optional
        The command line, written into the report.
    only : sequence of str, optional
        Measure only these of ``SECTIONS`` again and keep the others from the report already in
        ``out`` (its ``report.json``); the report says which sections were measured when.

    Returns
    -------
    dict
        What ``report.json`` holds.
    """
    from .bench import run_bench

    settings = settings or (quick_settings() if quick else ReportSettings())
    out = Path(out)
    only = tuple(SECTIONS if only is None else only)
    unknown = sorted(set(only) - set(SECTIONS))
    if unknown:
        raise ValueError(f"unknown report sections {', '.join(unknown)}; choose from {', '.join(SECTIONS)}")
    earlier = None
    if set(only) != set(SECTIONS):
        try:
            earlier = json.loads((out / "report.json").read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"{out / 'report.json'}: cannot keep the sections not measured again "
                             f"({exc}); run the whole report first") from None
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    seconds = {}
    # Share of the run each section takes at full size (measured), for progress only.
    spans = [("quality_demo", 0.13), ("outfits", 0.02), ("quality_makehuman", 0.35), ("speed", 0.2),
             ("memory", 0.1), ("training", 0.2)]
    bounds, acc = {}, 0.0
    for name, share in spans:
        bounds[name] = (acc, acc + share)
        acc += share

    def section(name):
        lo, hi = bounds[name]

        def sub(fraction, stage):
            if progress:
                progress(lo + (hi - lo) * fraction, f"{name}: {stage}")
            return False
        return sub

    machine = dict(machine_description(), load_average_start=list(os.getloadavg()))
    try:
        import torch

        machine["torch"] = torch.__version__
    except ImportError:
        machine["torch"] = None
    report = {"title": "Garment Transfer benchmark report", "date": time.strftime("%Y-%m-%d %H:%M %Z"),
              "command": command, "machine": machine, "settings": asdict(settings),
              "paper": {"machine": PAPER_MACHINE, "table1": PAPER_TABLE1, "training": PAPER_TRAINING,
                        "seconds_by_triangles": {str(k): v for k, v in PAPER_SECONDS.items()},
                        "note": "published figures of Shi et al., typed in from the paper"}}

    if earlier is not None:
        for key in SECTIONS:
            if key not in only:
                report[key] = earlier.get(key)
        report["measured"] = dict(earlier.get("measured") or {key: earlier["date"] for key in SECTIONS
                                                              if earlier.get(key) is not None})
        seconds.update({k: v for k, v in earlier["seconds"].items() if not k.startswith("total")})
    report.setdefault("measured", {})
    for key in only:
        report["measured"][key] = report["date"]

    if "quality" in only:
        t = time.perf_counter()
        demo = demo_quality(settings, demo_dataset, progress=section("quality_demo"))
        seconds["quality_demo"] = time.perf_counter() - t
        t = time.perf_counter()
        mh = makehuman_quality(settings, makehuman, progress=section("quality_makehuman"))
        seconds["quality_makehuman"] = time.perf_counter() - t
        report["quality"] = {}
        for key, res in (("demo", demo), ("makehuman", mh)):
            if "skipped" not in res:
                res["summary"] = summarise(res)
                res["worse_than_ours"] = worse_than_ours(res, res["summary"])
            report["quality"][key] = res

    if "outfits" in only:
        t = time.perf_counter()
        report["outfits"] = demo_outfits(settings, demo_dataset, progress=section("outfits"))
        seconds["outfits"] = time.perf_counter() - t

    if "speed" in only:
        t = time.perf_counter()
        report["speed"] = run_bench(sizes=settings.sizes, repeats=settings.repeats, targets=settings.targets,
                                    progress=section("speed"), exact_sample=settings.exact_sample)
        seconds["speed"] = time.perf_counter() - t

    if "memory" in only:
        t = time.perf_counter()
        mem_progress = section("memory")
        report["memory"] = []
        for i, n in enumerate(settings.memory_sizes):
            mem_progress(i / len(settings.memory_sizes), f"{n} triangles in a fresh process")
            report["memory"].append(measure_memory(n))
        seconds["memory"] = time.perf_counter() - t

    if "training" in only:
        t = time.perf_counter()
        section("training")(0.0, "paper scale")
        report["training"] = training_at_scale(settings.scale_epochs)
        seconds["training"] = time.perf_counter() - t

    machine["load_average_end"] = list(os.getloadavg())
    seconds["total_before_writing"] = time.perf_counter() - t_start
    report["seconds"] = seconds
    if progress:
        progress(0.98, "writing")
    report["plots"] = write_plots(report, out)
    seconds["total"] = time.perf_counter() - t_start
    write_text_atomic(out / "report.md", format_report(report))
    write_text_atomic(out / "report.json", _json_text(report))
    if progress:
        progress(1.0, "done")
    return report


_NUMBER_LIST = re.compile(r"\[\s*(-?[\d.eE+-]+(?:,\s*-?[\d.eE+-]+)*)\s*\]")


def _json_text(report):
    """report.json: indented, floats to 5 significant digits, lists of numbers on one line."""
    text = json.dumps(_rounded(report), indent=1, default=json_default)
    return _NUMBER_LIST.sub(lambda m: "[" + ", ".join(v.strip() for v in m.group(1).split(",")) + "]",
                            text) + "\n"


def _rounded(x, digits=5):
    """``x`` with every float rounded to ``digits`` significant digits (a smaller report.json)."""
    if isinstance(x, dict):
        return {k: _rounded(v, digits) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_rounded(v, digits) for v in x]
    if isinstance(x, (float, np.floating)):
        return float(f"{float(x):.{digits}g}")
    return x


# --------------------------------------------------------------------------------------------------
# Plots

_COLOURS = {"ours": "#1b7837", "shared": "#1b7837", "paper": "#762a83", "direct": "#2166ac",
            "surface_deform": "#e08214", "simulation": "#7f7f7f", "fitted": "#7f7f7f"}


def write_plots(report, out) -> list:
    """The report's PNG plots (matplotlib, Agg); the file names written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    for name, fn in (("quality.png", _plot_quality), ("speed.png", _plot_speed),
                     ("training.png", _plot_training)):
        fig = fn(plt, report)
        if fig is None:
            continue
        fig.savefig(Path(out) / name, dpi=80)
        plt.close(fig)
        written.append(name)
    return written


def _plot_quality(plt, report):
    sets = [(k, v) for k, v in report["quality"].items() if "skipped" not in v and v.get("rows")]
    if not sets:
        return None
    panels = [("mdc", "MDC (design change)", 1.0),
              ("penetration_ratio", "penetration (% of vertices)", 100.0),
              ("drape_error_relative", "drape error, relative", 1.0),
              ("vertex_error_mean", "vertex error (mm)", None)]
    fig, axes = plt.subplots(len(sets), len(panels), figsize=(13, 3.3 * len(sets)), squeeze=False)
    rng = np.random.default_rng(0)
    for row, (key, res) in enumerate(sets):
        methods = [m for m in [_model_key(res)] + METHODS[1:] + [res["reference"]]
                   if any(r["method"] == m for r in res["rows"])]
        for col, (fig_key, label, scale) in enumerate(panels):
            ax = axes[row, col]
            s = scale if scale is not None else (res.get("mm_per_unit") or 1.0)
            for j, m in enumerate(methods):
                vals = np.array([r[fig_key] for r in res["rows"] if r["method"] == m
                                 and r.get(fig_key) is not None], float) * s
                if not len(vals):
                    continue
                ax.bar(j, vals.mean(), color=_COLOURS.get(m, "k"), alpha=0.75)
                ax.scatter(j + rng.uniform(-0.25, 0.25, len(vals)), vals, s=7, color="k", alpha=0.5, lw=0)
            ax.set_xticks(range(len(methods)))
            ax.set_xticklabels([m.replace("_", "\n") for m in methods], fontsize=7)
            unit = "" if scale is not None or res.get("mm_per_unit") else " (file units)"
            ax.set_title(f"{key}: {label}{unit}", fontsize=9)
            ax.tick_params(labelsize=7)
    fig.suptitle("Quality: bars are means over (garment, target) pairs, dots the pairs; lower is better",
                 fontsize=10)
    fig.tight_layout()
    return fig


def _plot_speed(plt, report):
    sp = report.get("speed") or {}
    sizes = sp.get("sizes") or []
    if not sizes:
        return None
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    ax = axes[0]
    n = np.array([r["triangles"] for r in sizes], float)
    ax.loglog(n, [r["cold"]["wall"] for r in sizes], "o-", color=_COLOURS["ours"], label="ours, cold")
    ax.loglog(n, [r["reused"]["wall"] for r in sizes], "s--", color=_COLOURS["ours"], mfc="none",
              label="ours, factor reused")
    mem = [m for m in report.get("memory") or [] if "error" not in m]
    if mem:
        ax.loglog([m["triangles"] for m in mem], [m["seconds"]["wall"] for m in mem], "^", color="k",
                  label="ours, cold, fresh process")
    pt = sorted((v["triangles"], v["seconds"]) for v in PAPER_TABLE1.values())
    ax.loglog([p[0] for p in pt], [p[1] for p in pt], "D", color="#b2182b",
              label="paper, published (i7-8750H laptop)")
    ax.set_xlabel("garment triangles")
    ax.set_ylabel("seconds per transfer")
    ax.set_title("Transfer time against garment size", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)

    ax = axes[1]
    stages = ["field", "bind", "embed", "factor", "solve", "fix"]
    bottom = np.zeros(len(sizes))
    x = np.arange(len(sizes))
    for st in stages:
        v = np.array([r["cold"].get(st, 0.0) for r in sizes])
        ax.bar(x, v, bottom=bottom, label=st)
        bottom += v
    ax.set_xticks(x)
    ax.set_xticklabels([f"{r['triangles'] // 1000}K" for r in sizes])
    ax.set_xlabel("garment triangles")
    ax.set_ylabel("seconds (cold)")
    ax.set_title("Per stage, cold", fontsize=10)
    ax.legend(fontsize=7)

    ax = axes[2]
    mt = sp.get("multi_target")
    if mt:
        k = np.arange(1, len(mt["per_target_seconds"]) + 1)
        reuse = mt["prepare_seconds"] + np.cumsum(mt["per_target_seconds"])
        cold = k * mt["without_reuse_seconds"] / len(k)
        ax.plot(k, reuse, "o-", color=_COLOURS["ours"], label="prepare once, factor reused")
        ax.plot(k, cold, "s--", color="k", label="cold every time")
        ax.set_xlabel("target bodies")
        ax.set_ylabel("cumulative seconds")
        ax.set_title(f"One garment ({mt['triangles'] // 1000}K triangles) to several bodies", fontsize=10)
        ax.legend(fontsize=7)
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    return fig


def _plot_training(plt, report):
    panels = []
    tr = report.get("training") or {}
    if tr.get("curve"):
        panels.append(("paper scale", [(f"ours, {tr['body_triangles']} body triangles, {tr['garments']} "
                                        f"garments: {tr['seconds']:.0f} s", tr["curve"], _COLOURS["ours"])]))
    for key, res in (report.get("quality") or {}).items():
        if "skipped" in res or not res.get("trainings"):
            continue
        lines, seen = [], set()
        for t in res["trainings"]:
            if not t["curve"]:
                continue
            label = f"{t['variant']} ({'masked' if t['masked'] else 'unmasked'} loss)"
            # One legend entry per variant; the folds of a leave-one-out run share it.
            lines.append((None if label in seen else label, t["curve"], _COLOURS.get(t["variant"], "k")))
            seen.add(label)
        if lines:
            panels.append((key, lines))
    if not panels:
        return None
    fig, axes = plt.subplots(1, len(panels), figsize=(4.6 * len(panels), 3.8), squeeze=False)
    for ax, (title, lines) in zip(axes[0], panels):
        for label, curve, colour in lines:
            c = np.asarray(curve, float)
            ax.semilogy(c[:, 0], c[:, 2], color=colour, lw=1.0, alpha=0.8,
                        label=label)
        ax.set_xlabel("epoch")
        ax.set_ylabel("training loss (normalised)")
        ax.set_title(f"Training loss: {title}", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


# --------------------------------------------------------------------------------------------------
# Markdown


def _f(v, spec=".3f", scale=1.0):
    return "-" if v is None else format(v * scale, spec)


def _intersections_md(res, unit, scale):
    """Exact intersection counts per method: pairs left crossing the body (either way), pairs where the
    result crosses itself more than the source garment does, and the smallest distance kept."""
    rows = [r for r in res["rows"] if r.get("garment_edges_through_body") is not None]
    if not rows:
        return []
    lines = ["", "Intersections, checked exactly (orientation predicates with an exact fallback), per method "
             "over the same pairs: pairs where a garment edge passes through the body or a body edge through "
             "the garment; pairs where the garment crosses itself at more edge-triangle pairs than the "
             "source garment does, and the self-intersections added over all pairs; the smallest distance "
             "between garment and body over all pairs.", "",
             f"| method | pairs crossing the body | garment / body edges through (sum) | pairs adding "
             f"self-intersections | self-intersections added | smallest distance ({unit}) |",
             "|---|---:|---:|---:|---:|---:|"]
    for m in METHODS + [res["reference"]]:
        rs = [r for r in rows if r["method"] == m]
        if not rs:
            continue
        crossing = sum(1 for r in rs if r["garment_edges_through_body"] or r["body_edges_through_garment"])
        g = sum(r["garment_edges_through_body"] for r in rs)
        b = sum(r["body_edges_through_garment"] for r in rs)
        more = [r["self_intersections"] - r["self_intersections_source"] for r in rs]
        dmin = min(r["min_body_distance"] for r in rs)
        lines.append(f"| {m} | {crossing} of {len(rs)} | {g} / {b} | {sum(1 for x in more if x > 0)} | "
                     f"{sum(x for x in more if x > 0)} | {_f(dmin, '.2f', scale)} |")
    return lines


def _model_key(res):
    """The shared model's method key in a quality result: ``MODEL``, or ``ours`` in a section kept by ``--only``
    from a report.json written when the report called the shared model "ours"."""
    return MODEL if MODEL in (res.get("summary") or {}) else "ours"


def _quality_md(key, res):
    title = {"demo": "Demo data: procedural mannequins, garments draped by Blender's cloth solver",
             "makehuman": "MakeHuman fixtures: leave one garment out"}[key]
    lines = [f"### {title}", ""]
    if "skipped" in res:
        return lines + [f"Skipped: {res['skipped']}.", ""]
    mm = res.get("mm_per_unit")
    unit = "mm" if mm else "file units"
    scale = mm or 1.0
    ref = res["reference"]
    model = _model_key(res)
    tests = sorted({g for f in res["folds"] for g in f["test"]})
    if key == "demo":
        tr = [t for t in res["trainings"] if t["variant"] == model][0]
        lines += [f"Source body `{res['source']}`, targets {', '.join(f'`{t}`' for t in res['targets'])}; "
                  f"trained on {len(res['folds'][0]['train'])} garments ({res['epochs']} epochs, "
                  f"{tr['seconds']:.1f} s for the shared model), tested on {len(tests)} garments the model never saw: "
                  f"{', '.join(tests)}. Reference: the garment draped on each target by Blender's cloth "
                  f"solver; its time: {res.get('simulation_time_source', 'not recorded')}.", ""]
    else:
        secs = [t["seconds"] for t in res["trainings"] if t["variant"] == model]
        lines += [f"Source body `{res['source']}`, targets {', '.join(f'`{t}`' for t in res['targets'])}. "
                  f"For each of the {len(tests)} garments: train on the "
                  f"{len(res['folds'][0]['train'])} others ({res['epochs']} epochs, {np.mean(secs):.1f} s "
                  "per model for the shared model), transfer the held-out one. Reference: the garment fitted on each "
                  "body by MakeHuman (no simulation time).", ""]
    lines += [f"Means over {res['summary'].get(model, {}).get('pairs', 0)} (garment, target) pairs. "
              "MDC: against the source garment (lower = design kept). Penetration: share of vertices inside "
              "the target body, and the deepest. Drape: surface distance to the reference after the same "
              "low-pass filter, and relative to the untransferred garment (1 = did not move toward the "
              "target fit, 0 = perfect). Vertex error: mean distance to the reference, vertex to vertex. "
              "Time: one garment to one body, cold: the garment's preparation (binding, embedding, "
              "factor; for Surface Deform, the bind) plus the transfer, inside one process, reading files "
              "and starting Blender left out.", "",
              f"| method | MDC | penetration | max depth ({unit}) | drape error ({unit}) | drape rel. | "
              f"vertex error ({unit}) | time (s) |",
              "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for m in [model] + METHODS[1:] + [ref]:
        s = res["summary"].get(m)
        if not s:
            lines.append(f"| {m} | not run | | | | | | |")
            continue
        lines.append(f"| {m} | {_f(s['mdc'], '.4f')} | {_f(s['penetration_ratio'], '.2%')} | "
                     f"{_f(s['max_penetration_depth'], '.2f', scale)} | "
                     f"{_f(s['drape_error'], '.2f', scale)} | "
                     f"{_f(s['drape_error_relative'], '.3f')} | {_f(s['vertex_error_mean'], '.2f', scale)} | "
                     f"{_f(s['seconds'], '.3f')} |")
    lines += _intersections_md(res, unit, scale)
    rs = res["summary"].get(ref, {})
    if rs.get("penetration_ratio"):
        inside = [m for m in METHODS if (res["summary"].get(m) or {}).get("penetration_ratio")]
        lines += ["", f"The reference itself has {rs['penetration_ratio']:.1%} of its vertices inside the "
                      f"target body (deepest {_f(rs['max_penetration_depth'], '.1f', scale)} {unit} on "
                      "average): a method that pushes the garment out of the body moves away from it; "
                      f"those that leave vertices inside ({', '.join(inside) or 'none here'}) are not "
                      "penalised for it by the drape and vertex errors."]
    sd = res.get("surface_deform", {})
    if sd.get("error"):
        lines += ["", f"Surface Deform could not run: {sd['error']}."]
    elif sd.get("failures"):
        lines += ["", "Surface Deform refused: " + "; ".join(f"{g}: {e}" for g, e in sd["failures"].items())]
    if key == "demo":
        lines += ["", "Per test garment (the shared model and the simulation: means over the targets), beside the "
                  "paper's table 1 for the garment of the same name (**published figures**, the paper's "
                  "own garments and bodies, one target, i7-8750H laptop):", "",
                  "| garment | triangles | MDC shared | MDC paper as written | MDC simulation | "
                  "time shared (s) | paper: triangles | paper: MDC | paper: MDC simulation | paper: time (s) |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for g in tests:
            def mean(method, f, g=g):
                v = [r[f] for r in res["rows"] if r["garment"] == g and r["method"] == method
                     and r.get(f) is not None]
                return float(np.mean(v)) if v else None

            tri = next((r["triangles"] for r in res["rows"] if r["garment"] == g), None)
            p = PAPER_TABLE1.get(g)
            pp = (f"{p['triangles']} | {p['mdc']:.4f} | {p['mdc_simulation']:.4f} | {p['seconds']:.3f}"
                  if p else "- | - | - | -")
            lines.append(f"| {g} | {tri} | {_f(mean(model, 'mdc'), '.4f')} | "
                         f"{_f(mean('paper', 'mdc'), '.4f')} | {_f(mean(ref, 'mdc'), '.4f')} | "
                         f"{_f(mean(model, 'seconds'), '.3f')} | {pp} |")
    worse = res.get("worse_than_ours") or []
    lines += ["", "Where a baseline does better than the shared model on average:" if worse else
              "No baseline beats the shared model on average on any figure here.", ""]
    for w in worse:
        f = w["figure"]
        sc = scale if f in _LENGTHS else (100.0 if f == "penetration_ratio" else 1.0)
        u = f" {unit}" if f in _LENGTHS else ("%" if f == "penetration_ratio" else "")
        share = ("" if w["share_of_pairs"] is None
                 else f" (lower than the shared model on {w['share_of_pairs']:.0%} of pairs)")
        lines.append(f"- `{w['method']}`, {f}: {w['theirs'] * sc:.4g}{u} against the shared model's "
                     f"{w['ours'] * sc:.4g}{u}"
                     f"{share}")
    return lines + [""]


def format_report(report) -> str:
    """The markdown report."""
    m = report["machine"]
    s = report["seconds"]
    lines = [f"# {report['title']}", "",
             f"Written on {report['date']} by "
             f"`{report.get('command') or 'lab.report.run_report'}` "
             f"in {s['total']:.0f} s on {m['cpu']} ({m['cores']} cores), Python {m['python']}, numpy "
             f"{m['numpy']}, torch {m.get('torch')}. Load average (1, 5, 15 min) at the start "
             f"{', '.join(f'{x:.1f}' for x in m['load_average_start'])}, at the end "
             f"{', '.join(f'{x:.1f}' for x in m.get('load_average_end', []))}: other work on the machine "
             "slows every time below.", ""]
    measured = report.get("measured") or {}
    if len(set(measured.values())) > 1:
        lines += ["Sections measured at different times (the others kept from an earlier run): " +
                  "; ".join(f"{k} {v}" for k, v in measured.items()) + ".", ""]
    if report["settings"].get("quick"):
        lines += ["**Quick run** (tiny sizes and epochs, for the tests): the figures below mean nothing.", ""]
    lines += ["Every figure here comes from this run, except the paper's published figures (Shi et al., "
              f"{PAPER_MACHINE}), which are marked as such.", "",
              "## Quality", "", "Methods:", ""]
    lines += [f"- `{k}`: {ALL_METHODS[k].label}" for k in METHODS]
    lines += ["- `simulation` (demo data): the garment draped on the target body by Blender's cloth solver "
              "(the reference).",
              "- `fitted` (MakeHuman): the garment fitted on the target body by MakeHuman (the reference).",
              "", "![quality](quality.png)", ""]
    for key in ("demo", "makehuman"):
        lines += _quality_md(key, report["quality"][key])
    if report.get("outfits") is not None:
        lines += outfits_markdown(report["outfits"])

    sp = report["speed"]
    lines += ["## Speed and scale", "",
              "A dress made for the benchmark (`bench.tube_dress`: same shape, only the resolution "
              f"changes) on body `{sp['body']['name']}` ({sp['body']['triangles']} triangles), method "
              "`direct`; best of "
              f"{report['settings']['repeats']} runs. Cold: everything from scratch. Reused: the garment's "
              "embedding, binding and Poisson factor from an earlier call (what a second target costs). "
              "Paper: published total times (i7-8750H laptop) at about the same garment sizes.", "",
              "![speed](speed.png)", "",
              "| triangles | cold (s) | reused (s) | paper, published (s) | paper / cold | paper / reused | "
              "closest points vs brute force | Poisson solver | stages, cold (s) |",
              "|---:|---:|---:|---:|---:|---:|---:|---|---|"]
    for r in sp["sizes"]:
        st = ", ".join(f"{k} {v:.2f}" for k, v in r["cold"].items()
                       if k not in ("wall", "total", "penetrating_vertices"))
        exact = (f"{r['exact']:.1e} ({r['exact_sample']} points)" if r.get("exact") is not None else "-")
        lines.append(f"| {r['triangles']} | {r['cold']['wall']:.3f} | {r['reused']['wall']:.3f} | "
                     f"{_f(r['paper_seconds'])} | {_f(r['speedup_cold'], '.1f')} | "
                     f"{_f(r['speedup_reused'], '.1f')} | {exact} | {solver_text(r)} | {st} |")
    mt = sp.get("multi_target")
    if mt:
        lines += ["", f"One garment ({mt['triangles']} triangles) to {len(mt['targets'])} bodies: "
                      f"{mt['total_seconds']:.2f} s with the garment prepared once "
                      f"({mt['prepare_seconds']:.2f} s) "
                      f"and {np.mean(mt['per_target_seconds']):.2f} s per body, against "
                      f"{mt['without_reuse_seconds']:.2f} s cold each time "
                      f"({mt['without_reuse_seconds'] / mt['total_seconds']:.1f}x)."]
    lines += ["", "### Peak memory", "",
              "One cold transfer (method `direct`) per fresh Python process. Peak RSS: the process's "
              "high-water mark (`VmHWM` in `/proc/self/status`; `resource.getrusage`'s `ru_maxrss` would "
              "report the parent, whose size Linux carries across fork and exec). RSS before: the same "
              "mark once the bodies and the garment are built, before the transfer starts.", "",
              "| triangles | vertices | time (s) | RSS before transfer (MB) | peak RSS (MB) | stages (s) |",
              "|---:|---:|---:|---:|---:|---|"]
    for mrec in report["memory"]:
        if "error" in mrec:
            lines.append(f"| {mrec['triangles']} | failed: {mrec['error']} | | | | |")
            continue
        st = ", ".join(f"{k} {v:.2f}" for k, v in mrec["seconds"].items() if k not in ("wall", "total"))
        lines.append(f"| {mrec['triangles']} | {mrec['vertices']} | {mrec['seconds']['wall']:.2f} | "
                     f"{mrec['rss_before_mb']:.0f} | {mrec['peak_rss_mb']:.0f} | {st} |")

    tr = report["training"]
    lines += ["", "## Training", ""]
    if "skipped" in tr:
        lines += [f"Paper scale skipped: {tr['skipped']}."]
    else:
        lines += [f"At the paper's scale: a body of {tr['body_triangles']} triangles "
                  f"({tr['active_triangles']} covered, in the network), {tr['garments']} garments, "
                  f"latent {tr['latent']}, "
                  f"{tr['epochs']} epochs of {tr['optimizer']} ({'masked' if tr['masked'] else 'unmasked'} "
                  f"loss, torch threads: {tr['threads']}), on {tr['data']}: **{tr['seconds']:.1f} s** "
                  f"with the set-up ({_f(tr['ms_per_epoch'], '.0f')} ms per epoch after it). Paper, "
                  "published: about "
                  f"{PAPER_TRAINING['seconds'] / 60:.0f} minutes for {PAPER_TRAINING['epochs']} epochs of "
                  f"scaled conjugate gradient (laptop with an RTX 2070), "
                  f"{tr['paper_ms_per_epoch']:.0f} ms per epoch"
                  + (f": {tr['paper_over_ours']:.0f}x our time." if tr.get("paper_over_ours") else ".")]
    for key, res in report["quality"].items():
        if "skipped" in res:
            continue
        for variant in (_model_key(res), "paper"):
            ts = [t for t in res["trainings"] if t["variant"] == variant]
            if ts:
                lines.append(f"- {key}, {variant} ({'masked' if ts[0]['masked'] else 'unmasked'} loss): "
                             f"{len(ts)} model(s), {ts[0]['samples']} samples of {ts[0]['active_triangles']} "
                             f"triangles, {ts[0]['epochs']} epochs, "
                             f"{np.mean([t['seconds'] for t in ts]):.1f} s each, final loss "
                             f"{np.mean([t['final_loss'] for t in ts]):.4g}")
    lines += ["", "![training](training.png)", "",
              "## Time spent on this report", "",
              ", ".join(f"{k} {v:.0f} s" for k, v in s.items()), ""]
    return "\n".join(lines)


def main(argv=None):
    """``python -m lab.report --memory-case N``: one ``memory_case``, as JSON on stdout."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m lab.report")
    ap.add_argument("--memory-case", type=int, required=True, help="garment triangles")
    args = ap.parse_args(argv)
    sys.stdout.write(json.dumps(memory_case(args.memory_case), default=json_default) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
