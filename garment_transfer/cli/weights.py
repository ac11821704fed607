"""``python -m garment_transfer weights``: a garment's skinning weights from the body it is dressed on."""

from __future__ import annotations

import os
import time

from ..errors import RigError
from ..files import check_output
from ..geometry.obj import read_obj
from ..rigging.skinning import read_weights, write_weights
from ..rigging.weight_transfer import (MATCH_ANGLE, MAX_INFLUENCES, inpainted_weights, nearest_weights,
                                      unweighted_vertices)
from .options import emit, number_option

RULES = ("inpaint", "nearest")


def add_weights_arguments(p):
    p.description = (
        "Skinning weights for a garment from the body it is dressed on. 'inpaint' (the default) takes the "
        "body's weights where the garment lies close to the body and faces the same way, and fills the rest "
        "(a skirt between the legs, a loose sleeve, a collar) by the smoothest field over the garment, so that "
        "it holds in motion; 'nearest' takes every vertex's weights at its nearest body point. Weights are "
        "written as {\"weights\": {group: [[vertex, weight], ...]}} (the layout of MakeHuman's weights), "
        "normalised, at most --max-influences per vertex.")
    p.add_argument("--body", required=True, help="OBJ: the body the garment is dressed on")
    p.add_argument("--weights", required=True, help="JSON: the body's weights, {group: [[vertex, weight], ...]}")
    p.add_argument("--garment", required=True, help="OBJ: the garment, dressed on the body (same units, space)")
    p.add_argument("--out", required=True, help="JSON to write: the garment's weights")
    p.add_argument("--rule", choices=RULES, default="inpaint", help="how weights are carried (default inpaint)")
    p.add_argument("--max-influences", type=number_option(int, 1, what="a whole number"), default=MAX_INFLUENCES,
                   help=f"groups kept per vertex, the largest (default {MAX_INFLUENCES}; game engines take 4 or 8)")
    p.add_argument("--match-distance", type=number_option(float, 0.0, low_inclusive=False, what="a distance"),
                   help="inpaint: the farthest a garment vertex may be from the body to take its weights, in the "
                        "files' units (default 2%% of the body's size)")
    p.add_argument("--match-angle", type=number_option(float, 0.0, what="an angle"), default=MATCH_ANGLE,
                   help=f"inpaint: the largest angle between the garment's and the body's normals, in degrees "
                        f"(default {MATCH_ANGLE:g})")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=weights_main)


def weights_main(args):
    inputs = [args.body, args.weights, args.garment]
    check_output(args.out, inputs, "--out")
    t = time.perf_counter()
    body = read_obj(args.body)
    garment = read_obj(args.garment)
    body_weights = read_weights(args.weights, body.n_vertices)
    if args.rule == "inpaint":
        weights, info = inpainted_weights(body.V, body.F, body_weights, garment.V, garment.F,
                                          distance=args.match_distance, angle=args.match_angle,
                                          max_influences=args.max_influences, name=garment.name)
    else:
        weights = nearest_weights(body.V, body.F, body_weights, garment.V, max_influences=args.max_influences,
                                  name=garment.name)
        unweighted, warnings = unweighted_vertices(weights, body_weights, garment.name)
        info = {"unweighted": unweighted, "warnings": warnings}
    if info["unweighted"] == garment.n_vertices:
        # Weights that move nothing: refused, nothing written.
        raise RigError(args.weights, info["warnings"][-1])
    weights.name = f"{os.path.basename(args.garment)} weights from {os.path.basename(args.body)} ({args.rule})"
    write_weights(args.out, weights, inputs=inputs)
    used = weights.W.getnnz(axis=0) > 0
    out = {"out": args.out, "rule": args.rule, "vertices": garment.n_vertices,
           "groups": int(used.sum()), "max_influences": args.max_influences,
           "most_influences": int(weights.influences().max(initial=0)),
           "seconds": time.perf_counter() - t, **{k: v for k, v in info.items() if k != "warnings"},
           "warnings": info["warnings"]}
    lines = [f"wrote {args.out}: {out['groups']} groups on {garment.n_vertices} vertices, at most "
             f"{out['most_influences']} per vertex ({args.rule})"]
    if args.rule == "inpaint":
        lines.append(f"{info['matched']} vertices matched the body, {info['inpainted']} inpainted")
    emit(args, out, lines + [f"warning: {w}" for w in info["warnings"]])
