"""Layered outfits made from the demo garments, transferred to every target and measured per layer.

One place for the outfits and their figures: ``lab/intersections.py`` (the study), ``lab/demo.py`` (the
demo report) and ``lab/report.py`` (the benchmark report) all call ``run_outfits``.

Per layer and target: crossings with the body both ways (garment edges through the body, body edges
through the garment; edge-triangle pairs, exact), crossings with the layers under it (both ways), the
garment's self-intersections as given on the source and after, the smallest distance to the body and
to the layers under it, and MDC against the garment as given. Every outfit is also given in the
reversed order, which must be refused (``OutfitError`` naming both garments).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from garment_transfer.geometry.intersections import crossings, intersection_report, minimum_distance
from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.readings import merge_readings, readings_of
from garment_transfer.pipeline.metrics import mdc
from garment_transfer.pipeline.outfit import OutfitError, transfer_outfit

from .paths import DEMO_DATA, mm_per_unit

#: Outfits of the demo garments, from the body out.
OUTFITS = (("tshirt", "shift_dress"), ("shorts", "wrap_dress"))


def crossing_pairs(V_a, F_a, V_b, F_b):
    """Edge-triangle pairs where two meshes cross, both ways."""
    c = crossings(V_a, F_a, V_b, F_b)
    return c["a_edge_pairs"] + c["b_edge_pairs"]


def layer_rows(garments, target_body, result, outfit, target):
    """One row per layer of a transferred outfit.

    Parameters
    ----------
    garments : list of Mesh
        The layers as given on the source body, innermost first.
    target_body : Mesh
    result : OutfitResult
    outfit, target : str
        Labels.

    Returns
    -------
    list of dict
    """
    rows = []
    R = [readings_of(g) for g in garments]
    for k, (g, V) in enumerate(zip(garments, result.V)):
        # Under every triangulation of the layers' and the body's polygons.
        below = [(result.V[i], R[i]) for i in range(k)]
        rep = intersection_report(V, R[k], target_body.V, readings_of(target_body), source_V=g.V, layers_below=below)
        row = {"outfit": outfit, "target": target, "layer": k + 1, "garment": g.name,
               "triangles": g.n_triangles,
               "garment_edge_body_pairs": rep["garment_edge_body_pairs"],
               "body_edge_garment_pairs": rep["body_edge_garment_pairs"],
               "layer_crossings": rep["layer_crossings"],
               "layer_crossings_source": sum(crossing_pairs(g.V, R[k], garments[i].V, R[i]) for i in range(k)),
               "self_intersections_source": rep["self_intersections_source"],
               "self_intersections": rep["self_intersections"],
               "min_body_distance": rep["min_body_distance"],
               "min_layer_distance": (minimum_distance(V, R[k], np.concatenate([b[0] for b in below]),
                                                       merge_readings([(b[0].shape[0], b[1]) for b in below]))
                                      if below else None),
               "offset": result.info[k].get("offset"),
               "mdc": mdc(g.V, V, g.F), "mdc_separated_source": mdc(result.source_V[k], V, g.F)}
        rows.append(row)
    return rows


def load_outfit(dataset, source, layers):
    """The layers of an outfit on the source body (list of Mesh named as the garments)."""
    return [read_obj(Path(dataset) / "garments" / g / f"{source}.obj", name=g) for g in layers]


def run_outfits(dataset=DEMO_DATA, targets=None, outfits=OUTFITS, progress=None, on_row=None):
    """Every outfit on every target, and each outfit's reversed order.

    Parameters
    ----------
    dataset : str or Path
        A dataset folder whose manifest names ``source`` and ``targets``, with the outfits' garments.
    targets : list of str, optional
        Default: the manifest's.
    outfits : sequence of tuple of str
        Garment names from the body out.
    progress : callable, optional
        ``progress(fraction, stage)``.
    on_row : callable, optional
        Called with each layer's row as it is measured.

    Returns
    -------
    dict
        ``rows`` (one per outfit, target and layer), ``refusals`` (per outfit: the reversed order,
        whether it was refused and the message), ``seconds`` (per outfit and target), or ``skipped``
        (why) when the dataset lacks a garment.
    """
    dataset = Path(dataset)
    man = json.loads((dataset / "manifest.json").read_text(encoding="utf-8"))
    source_name = man["source"]
    targets = list(man["targets"] if targets is None else targets)
    missing = sorted({g for layers in outfits for g in layers} - set(man.get("garments", [])))
    if missing:
        return {"skipped": f"the dataset has no {', '.join(missing)}"}
    source = read_obj(dataset / "bodies" / f"{source_name}.obj")
    bodies = {t: read_obj(dataset / "bodies" / f"{t}.obj") for t in targets}
    rows, refusals, seconds = [], [], []
    steps = len(outfits) * (len(targets) + 1)
    done = 0
    for layers in outfits:
        label = " under ".join(layers)
        garments = load_outfit(dataset, source_name, layers)
        for t in targets:
            if progress:
                progress(done / steps, f"outfit {label} on {t}")
            start = time.perf_counter()
            result = transfer_outfit(source, bodies[t], garments)
            seconds.append({"outfit": label, "target": t, "wall": time.perf_counter() - start,
                            **result.seconds})
            for row in layer_rows(garments, bodies[t], result, label, t):
                rows.append(row)
                if on_row:
                    on_row(row)
            done += 1
        reversed_layers = list(layers[::-1])
        try:
            transfer_outfit(source, bodies[targets[0]], garments[::-1])
            refusals.append({"outfit": label, "order": reversed_layers, "refused": False, "message": ""})
        except OutfitError as exc:
            refusals.append({"outfit": label, "order": reversed_layers, "refused": True, "message": str(exc)})
        done += 1
    return {"source": source_name, "units": man.get("units"), "targets": targets,
            "outfits": [list(o) for o in outfits], "rows": rows, "refusals": refusals, "seconds": seconds}


def crossings_left(res):
    """Rows with any crossing left (with the body, either way, or with a layer under it)."""
    return [r for r in res.get("rows", []) if r["garment_edge_body_pairs"] + r["body_edge_garment_pairs"]
            + r["layer_crossings"] > 0]


def _mm(v, unit_mm):
    return "-" if v is None else f"{v * unit_mm:.2f}"


def outfits_markdown(res, command="python -m lab.intersections --only outfits") -> list:
    """The report's outfits section (markdown lines); lengths in mm when the dataset names its units."""
    lines = ["## Outfits of several layers", ""]
    if "skipped" in res:
        return lines + [f"Skipped: {res['skipped']}.", ""]
    unit_mm = mm_per_unit(res.get("units"))
    unit = "mm" if unit_mm else "dataset units"
    unit_mm = unit_mm or 1.0
    lines += [
        f"Two garments worn one over the other, from the body out, on the source body `{res['source']}`, "
        "transferred together (`garment_transfer.outfit.transfer_outfit`) to "
        f"{', '.join(f'`{t}`' for t in res['targets'])}. Crossings are exact edge-triangle pairs: garment "
        "edges through the body / body edges through the garment; with the layers under it, both ways "
        "(as given on the source, each garment draped alone, and after). Self-intersections: pairs, as "
        "given on the source and after. MDC against the garment as given, and against the layer as "
        "separated on the source (the outfit made wearable there; each layer is transferred as given).",
        "",
        "| outfit | target | layer | garment | body crossings (garment / body edges) | crossings with layers "
        f"under (source / after) | self-intersections (source / after) | smallest distance to body ({unit}) | "
        f"to layer under ({unit}) | MDC | MDC vs separated source |",
        "|---|---|---:|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in res["rows"]:
        under = (f"{r['layer_crossings_source']} / {r['layer_crossings']}" if r["layer"] > 1 else "-")
        lines.append(
            f"| {r['outfit']} | {r['target']} | {r['layer']} | {r['garment']} | "
            f"{r['garment_edge_body_pairs']} / {r['body_edge_garment_pairs']} | {under} | "
            f"{r['self_intersections_source']} / {r['self_intersections']} | "
            f"{_mm(r['min_body_distance'], unit_mm)} | {_mm(r['min_layer_distance'], unit_mm)} | "
            f"{r['mdc']:.4f} | {r['mdc_separated_source']:.4f} |")
    left = crossings_left(res)
    transfers = len({(r["outfit"], r["target"]) for r in res["rows"]})
    lines += ["", f"Crossings left: {len(left)} of {len(res['rows'])} layers in {transfers} outfit transfers.", ""]
    for ref in res["refusals"]:
        given = " under ".join(ref["order"])
        lines.append(f"- Reversed order ({given}): "
                     + (f"refused: \"{ref['message']}\"" if ref["refused"] else "**not refused**"))
    lines += ["", f"Also measured by `{command}`.", ""]
    return lines
