"""The main job on the built-in demo data: train, transfer the test garments, measure, report.

The demo dataset (``data/demo``, made by ``lab/blender/make_demo_data.py`` with Blender's cloth solver)
has procedural mannequins (a banana-shaped source and five targets) and 20 garments draped on each: 15
for training, 5 complex ones for testing; ``data/extra/garments.npz`` holds 40 more training garments
draped the same way (``lab.garment_data``). "Ours" is what the product recommends: the garment fit model
and its learned placement, trained as ``train`` trains it by default on the 55 training garments and used
as ``transfer --model`` uses it; "paper" is the paper's shared deformation model as written, trained on
the demo's 15. For every test garment and target body this writes the transferred garment of every
method, the simulation on that body as the reference, and a report in the form of the paper's table 1.
Renders and a .blend come from ``lab/blender/render_demo.py`` (Blender), run as a separate process.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from garment_transfer.files import write_json_atomic, write_text_atomic
from garment_transfer.geometry.obj import write_obj
from garment_transfer.learning.dataset import Dataset, load_dataset
from garment_transfer.pipeline.metrics import per_vertex_change

from .experiment import METHODS as ALL_METHODS
from .experiment import run_experiment
from .garment_data import PACKED, unpack
from .outfits import outfits_markdown, run_outfits
from .paths import BLENDER_SCRIPTS, DEMO_DATA

log = logging.getLogger(__name__)

#: Methods compared, in report order.
METHODS = ["ours", "paper", "direct", "surface"]
#: The quick demo's training of "ours" (for tests): far fewer passes and one placement network, so its
#: figures are not the product's.
QUICK_PRODUCT = {"epochs": 1, "placement_epochs": 3, "placement_members": 1}


@dataclass
class KeptGarments(Dataset):
    """A dataset whose garments are read once and kept: the demo reads each garment several times (the
    training fields, the feature tables, the placement's, the transfers), and all of them fit in memory."""

    kept: dict = field(default_factory=dict, repr=False)

    def garment(self, garment, body):
        key = (garment, body)
        if key not in self.kept:
            mesh = super().garment(garment, body)
            # Shared by every reader from now on: a change in place would fail, not spread.
            mesh.V.flags.writeable = False
            self.kept[key] = mesh
        return self.kept[key]


def kept_garments(folder):
    """``load_dataset(folder)`` as a ``KeptGarments``."""
    ds = load_dataset(folder)
    return KeptGarments(ds.folder, ds.bodies, ds.garments, ds.units, ds.up_axis, ds.manifest)


def run_demo(out="results", quick=False, progress=None, dataset=DEMO_DATA, epochs=None, render=True,
             extra=PACKED):
    """Run the whole method on the demo dataset and write ``out/``.

    Parameters
    ----------
    out : str or Path
        Results folder (created).
    quick : bool
        Two test garments, two targets, fewer epochs, no extra garments, "ours" trained briefly
        (``QUICK_PRODUCT``; for tests).
    progress : callable, optional
        ``progress(fraction, stage)``.
    dataset : str or Path
        A dataset folder whose manifest names ``source``, ``targets``, ``train_garments`` and
        ``test_garments``.
    epochs : int, optional
        Training epochs of the paper's model (default 400, quick: 60).
    render : bool
        Run the Blender renders (needs the bpy module).
    extra : str or Path, optional
        Packed training garments draped on the same bodies (``lab.garment_data``; default
        ``data/extra/garments.npz``) that "ours" trains on too; None: the dataset's own only.

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
    with tempfile.TemporaryDirectory(prefix="gt_demo_data_") as work:
        data, extra_garments = dataset, []
        if extra is not None and not quick:
            data = Path(work) / "dataset"
            extra_garments = unpack(data, packed=extra, demo=dataset, between=None)
        return _run_demo(out, meshes, quick, progress, dataset, data, extra_garments, epochs, render, t_start)


def _run_demo(out, meshes, quick, progress, dataset, data, extra_garments, epochs, render, t_start):
    """``run_demo`` on ``data``: ``dataset`` with ``extra_garments`` added (or ``dataset`` itself)."""
    man = json.loads((Path(dataset) / "manifest.json").read_text(encoding="utf-8"))
    source = man["source"]
    targets = list(man["targets"])
    shared_train = list(man["train_garments"])
    train = shared_train + list(extra_garments)
    test = list(man["test_garments"])
    if quick:
        targets, test = targets[:2], test[:2]
    epochs = epochs or (60 if quick else 400)

    def step(fraction, stage):
        if progress:
            progress(fraction, stage)

    def save_models(_fold, models):
        models["paper"].save(out / "model_paper.npz")
        step(0.45, "trained ours (the garment fit model and its placement) and the paper's model")

    def save_result(g, t, key, garment, V):
        write_obj(meshes / f"{g}__{t}__{key}.obj", garment, V)
        if key == "ours":
            np.save(meshes / f"{g}__{t}__ours_change.npy", per_vertex_change(garment.V, V).astype(np.float32))

    step(0.0, f"training ours on {len(train)} garments and the paper's model on {len(shared_train)}")
    res = run_experiment(kept_garments(data), source, targets, [(train, test)], METHODS, epochs,
                         reference="simulation",
                         on_result=save_result, on_models=save_models, shared_garments=shared_train,
                         model_file=lambda _fold: out / "model_ours.npz",
                         product_options=QUICK_PRODUCT if quick else None,
                         progress=lambda f, stage: step(0.45 + 0.45 * f, stage))
    ds = load_dataset(dataset)
    for g in test:
        write_obj(meshes / f"{g}__{source}__source.obj", ds.garment(g, source))
    for b in [source] + targets:
        write_obj(meshes / f"body__{b}.obj", ds.body(b))

    t_outfits = time.perf_counter()
    # Quick: one target, so that the tests stay short; the refusal of the reversed order is kept.
    outfits = run_outfits(dataset, targets[:1] if quick else targets,
                          progress=lambda f, stage: step(0.9 + 0.02 * f, stage))
    # By the method each training serves: "ours" is the product variant's model file.
    training = {{"product": "ours"}.get(t["variant"], t["variant"]): {k: v for k, v in t.items() if k != "curve"}
                for t in res["trainings"]}
    seconds = {"outfits": time.perf_counter() - t_outfits, "total_before_render": time.perf_counter() - t_start}
    summary = {"dataset": str(dataset), "source": source, "targets": targets, "train_garments": train,
               "paper_train_garments": shared_train, "extra_garments": list(extra_garments),
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


def _mean(rows, name):
    vals = [r[name] for r in rows if r.get(name) is not None]
    return float(np.mean(vals)) if vals else None


def _ratio(a, b):
    return "-" if a is None or not b else f"{a / b:.2f}x"


def _header(summary):
    """The report's title and what was trained on what."""
    tr = summary["training"]
    ours, paper = tr.get("ours", {}), tr.get("paper", {})
    extra = summary.get("extra_garments") or []
    where = (f" (the demo's {len(summary['paper_train_garments'])} and {len(extra)} more from "
             "`data/extra/garments.npz`)" if extra else "")
    placement = ours.get("placement") or {}
    return [
        "# Garment Transfer demo report", "",
        f"Source body `{summary['source']}`; targets {', '.join(f'`{t}`' for t in summary['targets'])}; "
        f"{len(summary['test_garments'])} test garments no model saw. The reference on each target is the "
        "garment draped there by Blender's cloth solver.", "",
        f"**Ours** is what the product recommends: the garment fit model and its learned placement, trained "
        f"as `python -m garment_transfer train` trains it by default on {len(summary['train_garments'])} "
        f"garments{where} ({ours.get('epochs')} passes of the field model, {placement.get('epochs')} of each "
        f"of {placement.get('members')} placement networks; {ours.get('seconds', 0.0):.1f} s; `model_ours.npz`), "
        "used as `transfer --model model_ours.npz` uses it: half of its field, the placement mixed half and "
        "half with the nearest training garments'. **Paper**: the paper's shared deformation model as written, "
        f"trained on the demo's {len(summary['paper_train_garments'])} garments for {summary['epochs']} epochs "
        f"({paper.get('seconds', 0.0):.1f} s; `model_paper.npz`).", ""]


def _against_direct(summary, by):
    """Per target: ours' vertex error, MDC and drape error against direct transfer's, and vertices inside."""
    lines = ["## Ours against direct transfer", "",
             "Means over the test garments. Vertex error: mean distance to the simulated garment, vertex to "
             "vertex. Drape: surface distance to the simulated garment after the same low-pass filter, relative "
             "to the untransferred garment (1 = did not move toward the target fit, 0 = perfect). MDC: design "
             "change (lower = design kept).", "",
             "| target | vertex error ours (mm) | x direct | drape ours (rel.) | drape direct | MDC ours | x direct "
             "| vertices inside (ours) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for t in summary["targets"]:
        o = [by[(g, t, "ours")] for g in summary["test_garments"] if (g, t, "ours") in by]
        d = [by[(g, t, "direct")] for g in summary["test_garments"] if (g, t, "direct") in by]
        if not o or not d:
            continue
        ve, mdc = _mean(o, "vertex_error_mean"), _mean(o, "mdc")
        lines.append(f"| {t} | {_fmt(None if ve is None else 1000 * ve, '.1f')} | "
                     f"{_ratio(ve, _mean(d, 'vertex_error_mean'))} | {_fmt(_mean(o, 'drape_error_relative'))} | "
                     f"{_fmt(_mean(d, 'drape_error_relative'))} | {_fmt(mdc, '.4f')} | {_ratio(mdc, _mean(d, 'mdc'))} "
                     f"| {sum(int(r['penetrating_vertices']) for r in o)} |")
    return lines + [""]


def _table1(summary, by):
    """The paper's table 1 for ours, source to the first target."""
    first = summary["targets"][0]
    lines = [f"## Table 1 (source to `{first}`)", "",
             "MDC: mean discrete curvature difference to the source garment (lower = design kept). "
             "Drape: as above. Penetration: share of vertices inside the target body.", "",
             "| garment | vertices | triangles | MDC ours | MDC simulation | penetration ours | "
             "penetration simulation | drape ours (rel.) | time ours (s) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for g in summary["test_garments"]:
        o, s = by.get((g, first, "ours")), by.get((g, first, "simulation"))
        if not o:
            continue
        lines.append(f"| {g} | {o['vertices']} | {o['triangles']} | {o['mdc']:.4f} | {s['mdc']:.4f} | "
                     f"{100 * o['penetration_ratio']:.2f}% | {100 * s['penetration_ratio']:.2f}% | "
                     f"{_fmt(o['drape_error_relative'])} | {o['seconds']:.3f} |")
    return lines + [""]


def _every_method(summary, by):
    """Every method's means over the test garments, per target."""
    lines = ["## Every method, mean over test garments, per target", "",
             "| target | method | MDC | penetration | max depth (m) | drape error (m) | drape rel. | "
             "vertex error vs simulation (m) | time (s) |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for t in summary["targets"]:
        for key in ["simulation"] + METHODS:
            rs = [by[(g, t, key)] for g in summary["test_garments"] if (g, t, key) in by]
            if not rs:
                continue
            secs = [r["seconds"] for r in rs if r.get("seconds")]
            lines.append(f"| {t} | {key} | {_mean(rs, 'mdc'):.4f} | {100 * _mean(rs, 'penetration_ratio'):.2f}% | "
                         f"{_mean(rs, 'max_penetration_depth'):.4f} | {_fmt(_mean(rs, 'drape_error'), '.4f')} | "
                         f"{_fmt(_mean(rs, 'drape_error_relative'))} | {_fmt(_mean(rs, 'vertex_error_mean'), '.4f')} | "
                         f"{_fmt(float(np.mean(secs)) if secs else None)} |")
    return lines + ["", "Methods:", ""] + [f"- `{k}`: {ALL_METHODS[k].label}" for k in METHODS] + [
        "- `simulation`: the garment draped on the target body by Blender's cloth solver (the reference).", ""]


def format_report(summary) -> str:
    """The markdown report: ours against direct transfer, the paper's table 1 for ours, then every method side
    by side and the outfits."""
    by = {(r["garment"], r["target"], r["method"]): r for r in summary["rows"]}
    lines = (_header(summary) + _against_direct(summary, by) + _table1(summary, by)
             + _every_method(summary, by))
    if "outfits" in summary:
        lines += outfits_markdown(summary["outfits"])
    lines += [f"Written by `python -m lab demo` in "
              f"{summary['seconds']['total_before_render']:.0f} s (before rendering).", ""]
    return "\n".join(lines)
