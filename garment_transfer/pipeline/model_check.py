"""How a trained model does on garments it was not trained on, against the body alone.

A studio trains a model on its own catalogue; before it uses the model it wants to know whether the model
beats what the body alone predicts (direct transfer) on garments of that catalogue. ``check_model`` takes
garments held out of training, transfers each to every target with the model file, read as ``transfer
--model`` reads it (``model_files.read_model_file``: its default field share and placement), and with direct
transfer, and measures both against the garment's own drape on that target (``metrics.evaluate``): the
mean vertex error, MDC (the mean curvature difference) and the vertices left inside the body. Per target the
two methods' means over the held-out garments are compared as the studies compare them (docs/garment-model.md):
the model's mean over direct's.
"""

from __future__ import annotations

import os
import time

import numpy as np

from ..errors import Cancelled, GarmentTransferError, SettingError
from ..learning.dataset import load_dataset
from ..learning.model_files import read_model_file
from .metrics import evaluate
from .transfer import prepare_garment, transfer_garment

#: The figures kept per garment, target and method (``metrics.evaluate``'s keys).
FIGURES = ("vertex_error_mean", "mdc", "penetrating_vertices")
METHODS = ("model", "direct")


def training_garments(dataset, source, targets, garments, held):
    """The garments to train on when ``held`` are held out for ``check_model``: ``garments`` (None: all the
    dataset's) but those, checked before any training.

    Raises
    ------
    DatasetError
        Naming the folder or file: a held-out garment the dataset does not have, or without its drape on
        ``source`` or a target.
    SettingError
        A held-out garment also among ``garments``; every garment held out.
    """
    ds = dataset if hasattr(dataset, "garment") else load_dataset(dataset)
    held = list(held)
    for g in held:
        ds.require_garment(g)
    both = [g for g in held if g in (garments or [])]
    if both:
        raise SettingError("held-out garments", f"{', '.join(both)} {'is' if len(both) == 1 else 'are'} also "
                                                "among the garments to train on: a held-out garment is not trained on")
    ds.require_complete(held, [source, *targets])
    left = [g for g in (ds.garments if garments is None else garments) if g not in held]
    if not left:
        raise SettingError("held-out garments", f"every garment of {ds.folder} is held out: none is left to train on")
    return left


def check_model(dataset, source, targets, garments, model_path, progress=None) -> dict:
    """Transfer held-out ``garments`` with the model in ``model_path`` and with direct transfer; compare.

    Parameters
    ----------
    dataset : Dataset or str or Path
        Holds every garment on ``source`` and on every target.
    source : str
    targets : list of str
        Bodies the model was trained for (the model is told each target's label).
    garments : list of str
        Garments the model was not trained on.
    model_path : str or Path
        A model file of either kind (``train``'s output).
    progress : callable(fraction, stage), optional
        Returning True cancels (raises Cancelled; the model file is left as it is).

    Returns
    -------
    dict
        JSON-serialisable: ``model``, ``garments``, ``targets``, ``units``, ``seconds``; ``rows``: per
        garment, target and method the ``FIGURES``; ``targets_summary``: per target the two methods' means
        (``model`` and ``direct``, each ``FIGURES``; ``penetrating_vertices`` summed) and ``vertex_ratio`` and
        ``mdc_ratio`` (the model's mean over direct's; None where direct's is 0); ``beats_direct``: the targets
        where the model's mean vertex error is below direct's.

    Raises
    ------
    DatasetError
        Naming the dataset folder or file: an unknown body or garment, a garment without its drape on the
        source or on a target.
    ModelError
        Naming the model file.
    """

    t0 = time.perf_counter()
    ds = dataset if hasattr(dataset, "garment") else load_dataset(dataset)
    targets, garments = list(targets), list(garments)
    ds.require_body(source)
    for t in targets:
        ds.require_body(t)
    for g in garments:
        ds.require_garment(g)
    ds.require_complete(garments, [source, *targets])
    loaded = read_model_file(model_path)
    source_body = ds.body(source)
    rows = []
    steps = max(len(garments) * len(targets), 1)
    for i, g in enumerate(garments):
        garment = ds.garment(g, source)
        prepared = prepare_garment(source_body, garment)
        for j, t in enumerate(targets):
            if progress is not None and progress((i * len(targets) + j) / steps, f"{g} on {t}"):
                raise Cancelled(f"the check of {os.fspath(model_path)} on held-out garments was cancelled (the model "
                                "file is written)")
            body = ds.body(t)
            reference = garment.with_vertices(ds.garment_pair(g, source, t)[1])
            results = {
                "model": transfer_garment(source_body, body, garment, method="model", model=loaded.model, target=t,
                                          placement=loaded.placement, prepared=prepared),
                "direct": transfer_garment(source_body, body, garment, method="direct", prepared=prepared)}
            for method, r in results.items():
                e = evaluate(garment, garment.with_vertices(r.V), body, reference=reference, intersections=False)
                rows.append({"garment": g, "target": t, "method": method,
                             **{k: (int(e[k]) if k == "penetrating_vertices" else float(e[k])) for k in FIGURES}})
    if progress is not None:
        progress(1.0, "checked")
    summary = {}
    for t in targets:
        per = {}
        for method in METHODS:
            mine = [r for r in rows if r["target"] == t and r["method"] == method]
            per[method] = {k: (int(sum(r[k] for r in mine)) if k == "penetrating_vertices"
                               else float(np.mean([r[k] for r in mine]))) for k in FIGURES}
        summary[t] = {**per, **{f"{name}_ratio": (None if per["direct"][key] == 0
                                                  else per["model"][key] / per["direct"][key])
                                for name, key in (("vertex", "vertex_error_mean"), ("mdc", "mdc"))}}
    return {"model": os.fspath(model_path), "garments": garments, "targets": targets, "units": ds.units,
            "rows": rows, "targets_summary": summary,
            "beats_direct": [t for t in targets if summary[t]["model"]["vertex_error_mean"]
                             < summary[t]["direct"]["vertex_error_mean"]],
            "seconds": round(time.perf_counter() - t0, 2)}


def check_after_training(dataset, source, targets, garments, model_path, progress=None) -> dict:
    """``check_model`` of a model file just written by training: a failure says that the file was written
    (only the check failed), and names what failed."""

    try:
        return check_model(dataset, source, targets, garments, model_path, progress)
    except Cancelled:
        raise
    except GarmentTransferError as exc:
        raise GarmentTransferError(f"{os.fspath(model_path)} was written, but its check on the held-out garments "
                                   f"failed: {exc}") from exc


def check_lines(check) -> list:
    """``check_model``'s result as lines of text, one per target."""
    units = f" {check['units']}" if check.get("units") else ""
    lines = [f"held out of training: {', '.join(check['garments'])}; each transferred with the model and with "
             "direct transfer, against its own drape:"]
    for t in check["targets"]:
        s = check["targets_summary"][t]
        ratio = s["vertex_ratio"]
        mdc = s["mdc_ratio"]
        lines.append(f"  {t}: vertex error {s['model']['vertex_error_mean']:.4g}{units} against direct transfer's "
                     f"{s['direct']['vertex_error_mean']:.4g}{units}"
                     f"{'' if ratio is None else f' ({ratio:.2f}x)'}, MDC "
                     f"{'n/a' if mdc is None else f'{mdc:.2f}x'} direct's, "
                     f"{s['model']['penetrating_vertices']} vertices inside the body")
    n, k = len(check["beats_direct"]), len(check["targets"])
    lines.append(f"the model's vertex error is below direct transfer's on {n} of {k} target{'s' if k != 1 else ''}")
    return lines
