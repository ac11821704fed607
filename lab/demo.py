"""The main job on the built-in demo data: train, transfer the test garments, measure, report.

The demo dataset (``data/demo``, made by ``lab/blender/make_demo_data.py`` with Blender's cloth solver)
has procedural mannequins (a banana-shaped source and five targets) and 20 garments draped on each: 15
for training, 5 complex ones for testing. For every test garment and target body this writes the
transferred garment of every method, the simulation on that body as the reference, and a report in the
form of the paper's table 1. Renders and a .blend come from ``lab/blender/render_demo.py`` (Blender), run
as a separate process.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from garment_transfer.files import write_json_atomic, write_text_atomic
from garment_transfer.geometry.obj import write_obj
from garment_transfer.pipeline.metrics import per_vertex_change

from .experiment import METHODS as ALL_METHODS
from .experiment import run_experiment
from .outfits import outfits_markdown, run_outfits
from .paths import BLENDER_SCRIPTS, DEMO_DATA

log = logging.getLogger(__name__)

#: Methods compared, in report order.
METHODS = ["ours", "paper", "direct", "surface"]


def run_demo(out="results", quick=False, progress=None, dataset=DEMO_DATA, epochs=None, render=True):
    """Run the whole method on the demo dataset and write ``out/``.

    Parameters
    ----------
    out : str or Path
        Results folder (created).
    quick : bool
        Two test garments, two targets, fewer epochs (for tests).
    progress : callable, optional
        ``progress(fraction, stage)``.
    dataset : str or Path
        A dataset folder whose manifest names ``source``, ``targets``, ``train_garments`` and
        ``test_garments``.
    epochs : int, optional
        Training epochs (default 400, quick: 60).
    render : bool
        Run the Blender renders (needs the bpy module).

    Returns
    -------
    dict
        ``rows`` (one per garment, target and method), ``outfits`` (``lab.outfits.run_outfits``: the
        layered outfits on the targets, one target when quick), ``training``, ``seconds``, ``report``.
    """
    t_start = time.perf_counter()
    out = Path(out)
    meshes = out / "meshes"
    meshes.mkdir(parents=True, exist_ok=True)
    man = json.loads((Path(dataset) / "manifest.json").read_text(encoding="utf-8"))
    source = man["source"]
    targets = list(man["targets"])
    train = list(man["train_garments"])
    test = list(man["test_garments"])
    if quick:
        targets, test = targets[:2], test[:2]
    epochs = epochs or (60 if quick else 400)

    def step(fraction, stage):
        if progress:
            progress(fraction, stage)

    def save_models(_fold, models):
        for key in ("ours", "paper"):
            models[key].save(out / f"model_{key}.npz")
        step(0.3, "trained the shared model (ours and the paper's)")

    def save_result(g, t, key, garment, V):
        write_obj(meshes / f"{g}__{t}__{key}.obj", garment, V)
        if key == "ours":
            np.save(meshes / f"{g}__{t}__ours_change.npy", per_vertex_change(garment.V, V).astype(np.float32))

    step(0.0, "training the shared model")
    res = run_experiment(dataset, source, targets, [(train, test)], METHODS, epochs, reference="simulation",
                         on_result=save_result, on_models=save_models,
                         progress=lambda f, stage: step(0.3 + 0.6 * f, stage))
    from garment_transfer.learning.dataset import load_dataset

    ds = load_dataset(dataset)
    for g in test:
        write_obj(meshes / f"{g}__{source}__source.obj", ds.garment(g, source))
    for b in [source] + targets:
        write_obj(meshes / f"body__{b}.obj", ds.body(b))

    t_outfits = time.perf_counter()
    # Quick: one target, so that the tests stay short; the refusal of the reversed order is kept.
    outfits = run_outfits(dataset, targets[:1] if quick else targets,
                          progress=lambda f, stage: step(0.9 + 0.02 * f, stage))
    training = {t["variant"]: {k: v for k, v in t.items() if k != "curve"} for t in res["trainings"]}
    seconds = {"outfits": time.perf_counter() - t_outfits, "total_before_render": time.perf_counter() - t_start}
    summary = {"dataset": str(dataset), "source": source, "targets": targets, "train_garments": train,
               "test_garments": test, "epochs": epochs, "training": training, "rows": res["rows"],
               "outfits": outfits, "seconds": seconds}
    report = format_report(summary)
    write_text_atomic(out / "report.md", report)
    write_json_atomic(out / "results.json", summary)
    if render:
        step(0.92, "rendering with Blender (Cycles, CPU)")
        seconds["render"] = render_results(out)
        pictures = sorted((out / "renders").glob("*.png"))
        report += "\n## Pictures\n\n" + "".join(
            f"![{p.stem}](renders/{p.name})\n\n" for p in pictures) + (
            f"The scene with every garment and body: `demo.blend`. Rendered with Cycles (CPU) in "
            f"{seconds['render']:.0f} s.\n")
        write_text_atomic(out / "report.md", report)
    seconds["total"] = time.perf_counter() - t_start
    write_json_atomic(out / "results.json", summary)
    step(1.0, "done")
    summary["report"] = str(out / "report.md")
    summary["summary_lines"] = report.splitlines()[:40]
    return summary


def render_results(out):
    """Run ``lab/blender/render_demo.py`` on the results folder; seconds taken."""
    script = BLENDER_SCRIPTS / "render_demo.py"
    t = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "lab.blender.render_demo", "--results", str(out)],
                       capture_output=True, text=True, env=dict(os.environ))
    if p.returncode != 0:
        raise RuntimeError(f"rendering failed ({script.name}): {p.stderr.strip().splitlines()[-1:]}")
    return time.perf_counter() - t


def _fmt(v, spec=".3f"):
    return "-" if v is None else format(v, spec)


def format_report(summary) -> str:
    """The markdown report: the paper's table 1 for our method, then every method side by side."""
    rows = summary["rows"]
    by = {(r["garment"], r["target"], r["method"]): r for r in rows}
    first = summary["targets"][0]
    lines = [
        "# Garment Transfer demo report",
        "",
        f"Source body `{summary['source']}`; targets {', '.join(f'`{t}`' for t in summary['targets'])}. "
        f"Trained on {len(summary['train_garments'])} garments for {summary['epochs']} epochs "
        f"({summary['training']['ours']['seconds']:.1f} s); tested on {len(summary['test_garments'])} "
        "garments the model never saw. The reference on each target is the garment draped there by "
        "Blender's cloth solver.",
        "",
        f"## Table 1 (source to `{first}`)",
        "",
        "MDC: mean discrete curvature difference to the source garment (lower = design kept). "
        "Drape: surface distance to the simulated garment after the same low-pass filter, relative "
        "to the untransferred garment (1 = did not move toward the target fit, 0 = perfect). "
        "Penetration: share of vertices inside the target body.",
        "",
        "| garment | vertices | triangles | MDC ours | MDC simulation | penetration ours | "
        "penetration simulation | drape ours (rel.) | time ours (s) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for g in summary["test_garments"]:
        o, s = by.get((g, first, "ours")), by.get((g, first, "simulation"))
        if not o:
            continue
        lines.append(f"| {g} | {o['vertices']} | {o['triangles']} | {o['mdc']:.4f} | {s['mdc']:.4f} | "
                     f"{100 * o['penetration_ratio']:.2f}% | {100 * s['penetration_ratio']:.2f}% | "
                     f"{_fmt(o['drape_error_relative'])} | {o['seconds']:.3f} |")
    lines += ["", "## Every method, mean over test garments, per target", "",
              "| target | method | MDC | penetration | max depth (m) | drape error (m) | drape rel. | "
              "vertex error vs simulation (m) | time (s) |",
              "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for t in summary["targets"]:
        for key in ["simulation"] + METHODS:
            rs = [by[(g, t, key)] for g in summary["test_garments"] if (g, t, key) in by]
            if not rs:
                continue

            def mean(name):
                vals = [r[name] for r in rs if r.get(name) is not None]
                return float(np.mean(vals)) if vals else None

            secs = [r["seconds"] for r in rs if r.get("seconds")]
            lines.append(f"| {t} | {key} | {mean('mdc'):.4f} | {100 * mean('penetration_ratio'):.2f}% | "
                         f"{mean('max_penetration_depth'):.4f} | {_fmt(mean('drape_error'), '.4f')} | "
                         f"{_fmt(mean('drape_error_relative'))} | {_fmt(mean('vertex_error_mean'), '.4f')} | "
                         f"{_fmt(float(np.mean(secs)) if secs else None)} |")
    lines += ["", "Methods:", ""] + [f"- `{k}`: {ALL_METHODS[k].label}" for k in METHODS] + [
        "- `simulation`: the garment draped on the target body by Blender's cloth solver (the reference).", ""]
    if "outfits" in summary:
        lines += outfits_markdown(summary["outfits"])
    lines += [f"Written by `python -m lab demo` in "
            f"{summary['seconds']['total_before_render']:.0f} s (before rendering).", ""]
    return "\n".join(lines)
