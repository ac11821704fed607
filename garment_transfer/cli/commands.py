"""Command line: ``python -m garment_transfer <command> ...`` (``--help`` on each).

Exit code 0 on success, 1 on an input or model problem (one line naming the file and what is
wrong, and no output file written), 2 on a usage error (including an option out of its range),
130 when stopped with Ctrl+C (one line, nothing half-written).

Every command declares what it reads and writes (``paths.DECLARED``), and ``main`` checks its outputs
against its inputs before any work (``files.check_outputs``): an output that is an input or lies inside an
input folder (however spelled), a symlink, a special file or a folder, or whose folder is missing or
read-only, is refused at once.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time

from ..errors import GarmentTransferError, MeshError
from ..files import atomic_path
from ..fitting.body_model import makehuman_shape_basis
from ..fitting.registration import register
from ..fitting.shape_basis import shape_basis_from_bodies
from ..geometry.obj import obj_text, read_obj, write_obj
from ..geometry.proximity import one_mesh
from ..geometry.readings import readings_of
from ..learning.garment_training import (
    FIELD_EPOCHS,
    PLACEMENT_EPOCHS,
    PLACEMENT_MEMBERS,
    train_garment_fit_from_dataset,
)
from ..learning.dataset import load_dataset
from ..learning.model_files import DEFAULT_FIELD_SHARE, read_model_file
from ..learning.placement import LIBRARY_SHARE
from ..learning.training import train_from_dataset
from ..rigging.posing import Rig
from ..rigging.naming import read_target_frames, read_target_skeleton
from ..rigging.skeleton import read_joints, read_skeleton
from ..rigging.skinning import read_weights
from ..pipeline.any_body import transfer_to_any_body
from ..pipeline.metrics import evaluate
from ..pipeline.model_check import check_after_training, check_lines, training_garments
from ..pipeline.outfit import transfer_outfit
from ..pipeline.rest_pose import (fold_warnings, outfit_across_rest_poses, target_at_rest, transfer_across_rest_poses,
                                  untangle_text)
from ..pipeline.pose_fit import posed_counts, poses_to_files
from ..pipeline.shape_keys import shapes_to_files
from ..pipeline.result_check import PASS_RESULT_KEYS, check_result, result_warnings
from ..version import __version__
from .batch import add_batch_arguments, batch_main
from .options import WarningLog, emit, number_option, share_option, stderr_progress
from .paths import check_command_paths, outfit_out_paths
from .weights import add_weights_arguments

log = logging.getLogger("garment_transfer")


def cmd_transfer(args):
    if len(args.garment) > 1:
        return cmd_transfer_outfit(args)
    if len(args.out) != 1:
        raise GarmentTransferError(f"one garment needs one --out, got {len(args.out)}")

    args.garment, args.out = args.garment[0], args.out[0]
    inputs = [args.source_body, args.target_body, args.garment, args.model, args.target_cage]
    t = time.perf_counter()
    source_body = read_obj(args.source_body)
    target_body = read_obj(args.target_body)
    garment = read_obj(args.garment)
    model = _model_for(args)
    rig = _rest_pose_rig(args, source_body)
    cage = _target_cage(args, source_body, rig)
    load = time.perf_counter() - t
    shape = _shape_basis_for(args, source_body)
    options = dict(cache=not args.no_cache, **{k: v for k, v in shape.items() if not k.startswith("_")},
                   method=args.method, **(model.transfer_arguments() if model else {}),
                   target=args.target, offset=args.offset, fix_penetration=not args.no_fix,
                   interpolate=not args.no_interpolate, resolve_crossings=not args.no_crossing_pass)
    if rig is not None:
        result, registration = transfer_across_rest_poses(source_body, target_body, garment, *rig,
                                                          untangle=args.untangle, **options)
    else:
        result, registration = transfer_to_any_body(source_body, target_body, garment, target_cage=cage, **options)
    t = time.perf_counter()
    write_obj(args.out, garment, result.V, inputs=inputs,
              header=f"Garment Transfer: {os.path.basename(args.garment)} on "
                     f"{os.path.basename(args.target_body)} ({args.method})")
    write = time.perf_counter() - t
    t = time.perf_counter()
    check, written = written_check(args.out, garment, target_body, result)
    seconds = dict(result.seconds, load=load, write=write, check=time.perf_counter() - t)
    out = {"out": args.out, "method": args.method, "target": args.target,
           "vertices": garment.n_vertices, "triangles": garment.n_triangles,
           "seconds": seconds, "penetrating_vertices": check["inside_vertices"], "check": check,
           "warnings": result_warnings(check, args.out), "info": pass_log(result.info),
           "registered": registration is not None, **_model_summary(model)}
    if _shape_weights_named(shape, registration):
        out["body_model_weights"] = _shape_weights_named(shape, registration)
    lines = [f"wrote {args.out}: {garment.n_vertices} vertices, {garment.n_faces} faces, "
             f"{check['inside_vertices']} inside the target body, {check_line(check)}, "
             f"{result.seconds['total']:.3f} s (transfer)"]
    if model is not None:
        lines.append(f"model: {model.describe()}")
    if registration is not None:
        lines.append(_registration_line(args.source_body, args.target_body, registration))
    pose = result.info.get("rest_pose")
    if pose is not None:
        out["rest_pose"] = pose
        lines.append(_rest_pose_line(pose))
        out["warnings"] += pose["warnings"]
        if pose["posed"]:
            # The file as written, against the target as given: where its body crosses or closes on itself (a
            # pose's bent knee, an arm on the hip) no cloth can be outside both surfaces.
            # The source at rest tells which parts the pose pressed together (through the registration on a
            # target of another mesh).
            pose["written"] = posed_counts(written, garment, target_body, result.info["offset"],
                                           rest_V=target_at_rest(source_body, target_body, registration),
                                           name=os.path.basename(args.target_body), own=False)
            out["warnings"] += pose["written"]["warnings"]
            lines.append(_written_pose_line(args.out, pose["written"]))
            if "untangle" in pose:
                lines.append("untangled (self-intersections its source does not have): "
                             + untangle_text(pose["untangle"]))
            out["warnings"] += fold_warnings(pose, check["self_intersections_new"], os.path.basename(args.out),
                                             "--untangle")
    lines += [f"warning: {w}" for w in out["warnings"]]
    emit(args, out, lines)


REST_POSE_OPTIONS = ("skeleton", "source_joints", "source_weights", "target_joints")


def _target_cage(args, source_body, rig):
    """The target's cage given (``--target-cage``), checked to be the source body's mesh; None when not given."""
    if not args.target_cage:
        return None
    if rig is not None:
        raise GarmentTransferError("--target-cage is for a target in the source's rest pose, not with --target-joints")
    cage = read_obj(args.target_cage)
    if not one_mesh(source_body, cage):
        raise MeshError(args.target_cage, f"is not the source body's mesh ({cage.n_vertices} vertices, "
                                          f"{cage.n_faces} faces; {os.path.basename(args.source_body)} has "
                                          f"{source_body.n_vertices} and {source_body.n_faces}): a cage must be "
                                          "the source's mesh in the target's shape")
    return cage


def _rest_pose_rig(args, source_body):
    """(source Rig, target joints or Landmarks, target frames or None) from the rest-pose options, or None when none
    is given."""
    given = [o for o in REST_POSE_OPTIONS if getattr(args, o, None)]
    if not given:
        return None
    if len(given) < len(REST_POSE_OPTIONS):
        missing = ", ".join("--" + o.replace("_", "-") for o in REST_POSE_OPTIONS if o not in given)
        raise GarmentTransferError(f"a target in another rest pose needs --skeleton, --source-joints, "
                                   f"--source-weights and --target-joints; missing {missing}")
    if args.method == "model":
        raise GarmentTransferError("a target in another rest pose is transferred by the direct or surface method, "
                                   "not by a model (trained on the source's pose)")
    skeleton = read_skeleton(args.skeleton)
    rig = Rig(skeleton, read_joints(args.source_joints, skeleton, "--source-joints"),
              read_weights(args.source_weights, source_body.n_vertices))
    return (rig, read_target_skeleton(args.target_joints, skeleton, "--target-joints"),
            read_target_frames(args.target_joints, skeleton))


def written_check(path, garment, target_body, result=None):
    """``check_result`` of the file as written at ``path`` (read back), against the target body given (``result``:
    the transfer's, for what it prepared and binned), and the positions read back (n,3)."""
    written = read_obj(path)
    prepared = None if result is None else result.prepared
    return check_result(garment, written.V, target_body, obstacle=None if result is None else result.obstacle,
                        surface=None if result is None else result.surface,
                        source_pairs=None if prepared is None else prepared.source_pairs(),
                        readings=None if prepared is None else prepared.readings()), written.V


def check_line(check):
    """The check's figures in a few words (every triangulation of the faces, the file as written)."""
    through = check["garment_edges_through_body"] + check["body_edges_through_garment"]
    return (f"{through} edges through the body or it, self-intersections {check['self_intersections']} "
            f"(source {check['self_intersections_source']}), smallest distance {check['min_body_distance']:.3g} "
            "(as written, any triangulation)")


def pass_log(info):
    """A transfer's info without the figures of the result in memory (the check gives those of the file)."""
    return {k: v for k, v in info.items() if k not in PASS_RESULT_KEYS}


def _registration_line(source, target, reg):
    q = reg.quality
    return (f"registered {os.path.basename(source)} onto {os.path.basename(target)}"
            f"{' (cached)' if reg.cached else ''}: distance to the target mean {q['to_target_mean']:.4g}, "
            f"95% {q['to_target_p95']:.4g}, max {q['to_target_max']:.4g}; from the target mean "
            f"{q['from_target_mean']:.4g}, 95% {q['from_target_p95']:.4g}, max {q['from_target_max']:.4g} "
            f"(target units)")


def _shape_basis_for(args, source_body):
    """The shape basis options for ``register``: the --shape-basis bodies as deltas of the source body,
    or --body-model's sliders; {} for neither."""
    if getattr(args, "body_model", None):
        if getattr(args, "shape_basis", None):
            raise GarmentTransferError("--body-model and --shape-basis are two shape bases: give one")

        model = makehuman_shape_basis(source_body, args.body_model)
        return {"shape_basis": model.basis, "shape_bounds": model.bounds, "body_model": True,
                "_names": model.names}
    if not getattr(args, "shape_basis", None):
        return {}

    return {"shape_basis": shape_basis_from_bodies(source_body, [read_obj(path, name=path)
                                                                for path in args.shape_basis])}


def _shape_weights_named(options, reg):
    """{slider: weight} of a body model's fit, the sliders moved (|weight| >= 0.001); {} otherwise."""
    names = options.get("_names")
    if not names or reg is None or reg.shape_weights is None:
        return {}
    return {n: float(w) for n, w in zip(names, reg.shape_weights) if abs(w) >= 1e-3}


def cmd_register(args):
    source_body = read_obj(args.source_body)
    target_body = read_obj(args.target_body)
    shape = _shape_basis_for(args, source_body)
    reg = register(source_body, target_body, cache=not args.no_cache,
                   **{k: v for k, v in shape.items() if not k.startswith("_")},
                   progress=stderr_progress("register") if args.verbose else None)
    write_obj(args.out, source_body, reg.V, inputs=[args.source_body, args.target_body],
              header=f"Garment Transfer: {os.path.basename(args.source_body)} registered onto "
                     f"{os.path.basename(args.target_body)}")
    out = {"out": args.out, "source_body": args.source_body, "target_body": args.target_body,
           "vertices": source_body.n_vertices, "shape_basis": args.shape_basis or [], **reg.summary()}
    if args.body_model:
        out["body_model"] = args.body_model
        out["body_model_weights"] = _shape_weights_named(shape, reg)
    emit(args, out, [f"wrote {args.out}", _registration_line(args.source_body, args.target_body, reg)])


def cmd_shapes(args):
    if args.poses:
        summary = poses_to_files(args.source_body, args.target_body or [], args.garment, args.out,
                                 body_cache=args.target_cache, offset=args.offset,
                                 progress=stderr_progress("poses") if args.verbose else None, workers=args.workers,
                                 cache=args.cache, untangle=args.untangle)
        emit(args, summary, [f"wrote {s['out']}" + (f" ({s['target']})" if args.target_cache else "")
                             + f": {s['crossings_outside_contact']} crossings, "
                             f"{s['crossings_at_contact']} where the body crosses itself, "
                             f"{s['self_intersections_new']} of the garment with itself beyond its rest shape's"
                             for s in summary["shapes"]] + [f"warning: {w}" for w in summary["warnings"]])
        return
    summary = shapes_to_files(args.source_body, args.target_body, args.garment, args.out,
                              offset=args.offset, margin=args.margin or 0.0,
                              fix_penetration=not args.no_fix, progress=stderr_progress("shapes")
                              if args.verbose else None)
    emit(args, summary, [f"wrote {s['out']}: {s['penetrating_vertices']} vertices inside {s['target']}, "
                          f"{check_line(s['check'])}" for s in summary["shapes"]]
          + [f"{len(summary['shapes'])} shapes, one preparation: {summary['seconds']['total']:.2f} s "
             f"(prepare {summary['seconds']['prepare']:.2f} s); summary in {summary['summary']}"]
          + [f"warning: {w}" for w in summary["warnings"]])


def _check_shapes_options(parser, args):
    """Where the shapes come from: --target-body files, or one --target-cache (poses, fitted into --cache)."""
    if args.target_cache is None and not args.target_body:
        parser.error("give the target shapes as --target-body files (or a body's animation as --target-cache)")
    if args.target_cache is not None:
        if args.target_body:
            parser.error("--target-cache gives every pose: no --target-body files beside it")
        if args.cache is None:
            parser.error("--target-cache needs --cache FILE.pc2: the garment's animation at the body cache's frames")
        args.poses = True
    if args.poses and (args.margin is not None or args.no_fix):
        parser.error("--margin and --no-fix are for target shapes; a pose fit keeps the garment outside the posed body")


def _model_for(args):
    """The ``--model`` file as ``model_files.ModelFile`` (any kind), or None for the other methods."""
    if args.method != "model":
        return None
    if not args.model:
        raise GarmentTransferError("--method model needs --model MODEL.npz (and, for the paper's shared model, "
                                   "--target LABEL)")

    return read_model_file(args.model, field_share=args.field_share, use_placement=not args.no_placement)


def _model_summary(model):
    """What the JSON output says of the model used: file, kind, field share, placement (or all None)."""
    if model is None:
        return {"model": None, "model_kind": None, "field_share": None, "placement": False, "nearest_garments": None}
    return {k: v for k, v in model.summary().items() if k != "targets"}


def write_all_or_nothing(paths, texts, inputs=()):
    """Write every text to its path, or none: all go to checked temporary files first (``files.atomic_path``),
    and are renamed only once every one is written."""
    import contextlib

    with contextlib.ExitStack() as stack:
        temps = [stack.enter_context(atomic_path(p, inputs, "--out")) for p in paths]
        for tmp, text in zip(temps, texts):
            with open(tmp, "wb") as fh:
                fh.write(text.encode("utf-8", errors="surrogateescape"))


def cmd_transfer_outfit(args):
    paths = outfit_out_paths(args.garment, args.out)
    if args.shape_basis or args.body_model:
        raise GarmentTransferError(f"{'--shape-basis' if args.shape_basis else '--body-model'} is for one garment: "
                                   "an outfit onto another mesh is registered without a shape basis")
    if args.no_fix or args.no_crossing_pass:
        raise GarmentTransferError("an outfit of several layers is always separated: "
                                   "--no-fix and --no-crossing-pass apply to one garment only")
    t = time.perf_counter()
    source_body = read_obj(args.source_body)
    target_body = read_obj(args.target_body)
    garments = [read_obj(g, name=g) for g in args.garment]
    model = _model_for(args)
    rig = _rest_pose_rig(args, source_body)
    cage = _target_cage(args, source_body, rig)
    load = time.perf_counter() - t
    options = dict(offsets=args.offset, method=args.method, **(model.transfer_arguments() if model else {}),
                   target=args.target, interpolate=not args.no_interpolate, cache=not args.no_cache)
    if rig is not None:
        result = outfit_across_rest_poses(source_body, target_body, garments, *rig, **options)
    else:
        result = transfer_outfit(source_body, target_body, garments, target_cage=cage, **options)
    t = time.perf_counter()
    on = f"{os.path.basename(args.target_body)} ({args.method})"
    texts = [obj_text(g, V, header=f"Garment Transfer: {os.path.basename(f)} (layer {k + 1} of "
                                   f"{len(garments)}) on {on}", path=p)
             for k, (g, V, f, p) in enumerate(zip(garments, result.V, args.garment, paths))]
    write_all_or_nothing(paths, texts, inputs=[args.source_body, args.target_body, *args.garment, args.model,
                                               args.target_cage])
    write = time.perf_counter() - t
    t = time.perf_counter()
    checks, below = [], []
    for g, p in zip(garments, paths):
        V = read_obj(p).V
        checks.append(check_result(g, V, target_body, layers_below=below))
        below.append((V, readings_of(g)))
    seconds = dict(result.seconds, load=load, write=write, check=time.perf_counter() - t)
    warnings = [w for c, p in zip(checks, paths) for w in result_warnings(c, p)]
    out = {"out": paths, "method": args.method, "target": args.target, "seconds": seconds, **_model_summary(model),
           "warnings": warnings, "registered": result.registration is not None,
           "layers": [{"garment": f, "out": p, "vertices": g.n_vertices, "triangles": g.n_triangles,
                       "penetrating_vertices": c["inside_vertices"], "check": c, "info": pass_log(i)}
                      for f, p, g, i, c in zip(args.garment, paths, garments, result.info, checks)]}
    lines = [f"wrote {p}: layer {k + 1} of {len(paths)}, {check_line(c)}"
             for k, (p, c) in enumerate(zip(paths, checks))]
    if result.registration is not None:
        out["registration"] = result.registration.summary()
        lines.append(_registration_line(args.source_body, args.target_body, result.registration))
    pose = result.rest_pose
    if pose is not None:
        out["rest_pose"] = pose
        lines.append(_rest_pose_line(pose))
        out["warnings"] += pose["warnings"]
        if pose["posed"]:
            # Each layer as written, against the target as given, counted apart where its body crosses itself.
            offsets = [i["offset"] for i in result.info]
            rest = target_at_rest(source_body, target_body, result.registration)
            for layer, g, p, (V, _), offset in zip(out["layers"], garments, paths, below, offsets):
                layer["rest_pose_written"] = posed_counts(V, g, target_body, offset, rest_V=rest,
                                                          name=os.path.basename(args.target_body), own=False)
                out["warnings"] += layer["rest_pose_written"]["warnings"]
                lines.append(_written_pose_line(p, layer["rest_pose_written"]))
    emit(args, out, lines + [f"{result.seconds['total']:.3f} s (outfit transfer)"]
         + ([f"model: {model.describe()}"] if model is not None else []) + [f"warning: {w}" for w in out["warnings"]])


TWIST_FROM = {"frames": "the target's bone frames", "body": "the target's body",
              "joints": "nowhere: joints alone do not tell them"}


def _rest_pose_line(pose):
    return (f"the target's rest pose: {pose['largest_turn_bone']} turned {pose['largest_turn']:.0f} degrees from the "
            "source's; " + (f"the source and its garments were posed into it first (each bone's turn about itself "
                            f"from {TWIST_FROM[pose['twist']]})" if pose["posed"]
                            else "the same pose (a change of shape)"))


def _written_pose_line(path, counts):
    return (f"{path} as written: {counts['crossings_outside_contact']} crossings away from where the target's body "
            f"crosses or closes on itself, {counts['crossings_at_contact']} where it does")


def cmd_evaluate(args):
    source = read_obj(args.source)
    result = read_obj(args.result)
    target_body = read_obj(args.target_body)
    reference = read_obj(args.reference) if args.reference else None
    source_body = read_obj(args.source_body) if args.source_body else None
    out = evaluate(source, result, target_body, reference=reference, source_body=source_body)
    emit(args, out, [f"{k}: {v:.6g}" if isinstance(v, float) else f"{k}: {v}" for k, v in out.items()])


def cmd_train(args):
    targets = [t for t in args.targets.split(",") if t]
    garments = [g for g in args.garments.split(",") if g] if args.garments else None
    held = [g for g in args.hold_out.split(",") if g] if args.hold_out else []
    # The names checked before torch is imported (seconds): a body or garment named wrongly is refused at once.
    dataset = load_dataset(args.dataset)
    for body in [args.source, *targets]:
        dataset.require_body(body)
    for garment in garments or []:
        dataset.require_garment(garment)
    if held:
        garments = training_garments(dataset, args.source, targets, garments, held)
    try:
        import torch  # noqa: F401
    except ImportError as exc:
        raise GarmentTransferError(
            f"training needs torch ({exc}); install it with: pip install torch==2.13.0") from None
    if args.kind == "garment":
        summary, lines = _train_garment(args, targets, garments)
    else:
        summary = train_from_dataset(args.dataset, args.source, targets, garments=garments,
                                     epochs=args.epochs or 1000, latent=args.latent or 30, seed=args.seed,
                                     out=args.out,
                                     progress=stderr_progress("train"),
                                     masked=not args.unmasked, threads=args.threads)
        lines = [f"wrote {args.out}: {summary.get('epochs')} epochs, final loss {summary.get('final_loss')}, "
                 f"{summary.get('seconds', 0):.1f} s"]
    if held:
        summary["check"] = check_after_training(args.dataset, args.source, targets, held, args.out,
                                                progress=stderr_progress("check"))
        lines += check_lines(summary["check"])
    emit(args, summary, lines)


def _train_garment(args, targets, garments):
    summary = train_garment_fit_from_dataset(
        args.dataset, args.source, targets, garments=garments, epochs=args.epochs or FIELD_EPOCHS,
        placement_epochs=args.placement_epochs, placement=not args.no_placement, seed=args.seed, out=args.out,
        progress=stderr_progress("train"), threads=args.threads, placement_members=args.placement_members,
        placement_residual=not args.placement_absolute, library_share=args.nearest_garments)
    parts = [f"field {summary['field']['epochs']} passes over {summary['field']['samples']} samples, final loss "
             f"{summary['field']['final_loss']:.4g}"]
    if summary["placement"]:
        members = summary["placement"].get("members", 1)
        parts.append(f"placement {summary['placement']['epochs']} passes over {summary['placement']['samples']} "
                     f"samples{f' for each of {members} members' if members > 1 else ''}, final loss "
                     f"{summary['placement']['final_loss']:.4g}")
    if summary.get("library"):
        parts.append(f"nearest garments' placement ({summary['library']['entries']} entries) at share "
                     f"{summary['library']['share']:g}")
    what = "garment fit model and learned placement" if summary["placement"] else "garment fit model"
    return summary, [f"wrote {args.out}: {what}; {'; '.join(parts)}; {summary['seconds']:.1f} s"]


def cmd_batch(args):
    return batch_main(args)


def build_parser():
    p = argparse.ArgumentParser(prog="python -m garment_transfer",
                                description="Design-preserving garment transfer between body shapes.",
                                epilog="The demo, benchmarks and studies live in the repository's lab: "
                                       "python -m lab --help.")
    p.add_argument("-v", "--verbose", action="store_true", help="log details on stderr")
    p.add_argument("--version", action="version", version=f"garment_transfer {__version__}",
                   help="print the version (the extension's, the core's and the command line's) and exit")
    sub = p.add_subparsers(dest="command", required=True)

    t = sub.add_parser("transfer", help="move a garment from the source body onto a target body")
    t.add_argument("--source-body", required=True, help="OBJ: the body the garment is dressed on")
    t.add_argument("--target-body", required=True,
                   help="OBJ: the target body; the same mesh in another shape, or any body mesh of a "
                        "person in a similar pose (registered automatically, any units and axes)")
    t.add_argument("--target-cage", metavar="CAGE.obj",
                   help="OBJ: the mesh the target body subdivides (a character written with its Subdivision "
                        "Surface applied, and its base mesh): where it is the source body's mesh, the garment is "
                        "solved on it without a registration, and fitted to and checked against --target-body")
    t.add_argument("--garment", required=True, action="append",
                   help="OBJ: the garment on the source body; repeat it for an outfit of several layers, "
                        "from the body out (each stays outside the ones before it)")
    t.add_argument("--out", required=True, action="append",
                   help="OBJ to write (the garment's own faces, new positions); for an outfit, one per "
                        "--garment in the same order, or one existing folder (files named as the garments)")
    t.add_argument("--method", choices=["direct", "model", "surface"], default=None,
                   help="direct: the body's own deformation (default); model: a trained model, --model "
                        "(the default when --model or --target is given); "
                        "surface: follow the body only (baseline)")
    t.add_argument("--model", help="model file (.npz) written by train, of either kind: the paper's shared "
                                   "deformation model, or the garment fit model with its learned placement "
                                   "(train --kind garment); implies --method model")
    t.add_argument("--target", help="the model's target label; implies --method model. Needed by the shared "
                                    "model; the garment fit model takes any body of the source's mesh without "
                                    "it (weights over its training targets from the body's shape)")
    t.add_argument("--field-share", type=share_option, default=None, metavar="SHARE",
                   help="garment fit model only: how much of its predicted field is used, from 0 (the body's "
                        f"own, as direct) to 1 (default {DEFAULT_FIELD_SHARE:g}: with the learned placement, half "
                        "kept the design (MDC) at direct transfer's and its vertex error 0.63x direct's on the "
                        "demo's unseen garments; docs/garment-model.md)")
    t.add_argument("--no-placement", action="store_true",
                   help="garment fit model only: leave out the learned placement the file holds")
    t.add_argument("--offset", type=number_option(float, 0.0, what="a distance"), default=None,
                   help="distance kept from the body (for an outfit: by each layer from what is under it), in "
                        "the files' units: >= 0 and at most 5%% of the body's size (default about 5 mm on a "
                        "1.7 m body: 0.25%% of its scale)")
    t.add_argument("--no-fix", action="store_true", help="skip the penetration fix (and the crossing pass)")
    t.add_argument("--no-crossing-pass", action="store_true",
                   help="skip the final pass that removes every garment edge through the body and body "
                        "edge through the garment (exact check)")
    t.add_argument("--no-interpolate", action="store_true",
                   help="nearest body triangle only when carrying the field (the paper)")
    t.add_argument("--no-cache", action="store_true",
                   help="do not read or write the registration cache (see docs/registration.md)")
    t.add_argument("--shape-basis", nargs="+", metavar="BODY.obj",
                   help="OBJ files of the source body's mesh in other shapes (its shape keys, other bodies of "
                        "its mesh), same units and axes: when the target is another mesh, the source is first "
                        "fitted as a blend of them (docs/registration.md)")
    t.add_argument("--body-model", metavar="TARGETS.npz",
                   help="MakeHuman's targets archive (makehuman/data/targets.npz of the makehuman wheel: pip "
                        "download --no-deps makehuman==1.3.2): its sliders as the shape basis of a source body "
                        "of MakeHuman's hm08 mesh (docs/registration.md)")
    r = t.add_argument_group(
        "a target in another rest pose",
        "When the target body stands in another pose than the source (arms lower, legs apart), give both bodies' "
        "skeleton: the source body and its garment are posed into the target's rest pose by the source's weights "
        "first, then the shape is transferred (docs/motion.md). All four are needed; an outfit's layers are posed "
        "alike.")
    r.add_argument("--skeleton", metavar="SKELETON.json",
                   help="the bodies' skeleton: bones between named joints, MakeHuman's layout (rig/skeleton.json)")
    r.add_argument("--source-joints", metavar="JOINTS.json",
                   help="the skeleton's joints on the source body, {joint: [x, y, z]} (rig/joints/<body>.json)")
    r.add_argument("--source-weights", metavar="WEIGHTS.json",
                   help="the source body's weights, {group: [[vertex, weight], ...]} (rig/weights.json)")
    r.add_argument("--target-joints", metavar="JOINTS.json",
                   help="the skeleton's joints on the target body, as it stands; or, for a skeleton named "
                        "otherwise (Mixamo's, Rigify's, Unreal's), its bones as they stand: {\"bones\": {bone: "
                        "{\"parent\": ..., \"head\": [x, y, z], \"tail\": [x, y, z]}}}")
    r.add_argument("--untangle", action="store_true",
                   help="one garment: where the pose folds the cloth through itself (the bends: under the arms, the "
                        "lap), undo it without crossing the body more, on the fit to the posed source and on the "
                        "result; seconds more where it does")
    t.add_argument("--json", action="store_true", help="print one JSON object")
    t.set_defaults(func=cmd_transfer)

    h = sub.add_parser("shapes", help="one garment onto many shapes of one body, prepared once",
                       description="Transfer one garment to every target shape of the source body "
                                   "(same mesh, other shapes: the body's shape keys exported one per "
                                   "file). Writes DIR/<garment>_on_<target>.obj for each and "
                                   "DIR/shapes.json; nothing is written unless every shape succeeds.")
    h.add_argument("--source-body", required=True, help="OBJ: the body the garment is dressed on (the basis)")
    h.add_argument("--target-body", action="append",
                   help="OBJ: the same body mesh in another shape; repeat for each shape")
    h.add_argument("--target-cache", metavar="BODY.pc2",
                   help="a point cache of the source body's mesh animated, PC2 or MDD (named .mdd), as Blender's Mesh "
                        "Cache modifier reads them, instead of --target-body files: every sample is a pose to fit "
                        "(implies --poses); the fits go to --cache in the same format at the same frames, nothing "
                        "else but the summary")
    h.add_argument("--garment", required=True, help="OBJ: the garment on the source body")
    h.add_argument("--out", required=True, help="folder to write into (made if missing)")
    h.add_argument("--offset", type=number_option(float, 0.0, what="a distance"), default=None,
                   help="distance kept from the body, in the files' units (default 0.25%% of its scale)")
    h.add_argument("--margin", type=number_option(float, 0.0, what="a distance"), default=None,
                   help="extra distance for every shape, so that blends of the shapes clip less")
    h.add_argument("--no-fix", action="store_true", help="skip the penetration fix")
    h.add_argument("--poses", action="store_true",
                   help="the targets are the source body posed: fit the garment to each pose (the crossing pass "
                        "leaves out where the body crosses itself, and counts it apart); writes DIR/poses.json")
    h.add_argument("--workers", type=number_option(int, 1, what="a whole number"), default=None,
                   help="with --poses: poses fitted at once, in threads (default: the cores, at most 4); every "
                        "pose's result is the same whatever the number")
    h.add_argument("--cache", metavar="FILE.pc2",
                   help="with --poses: also every pose's result, in the order of the --target-body files, as one PC2 "
                        "point cache (frames 1, 2, ...): the garment's animation for Blender's Mesh Cache modifier "
                        "and other tools; with --target-cache, the fits in its format at its frames")
    h.add_argument("--untangle", action="store_true",
                   help="with --poses: undo where a fit makes the cloth cross itself (the bends: the lap sitting, "
                        "under the arms), without crossing the body more; seconds more a pose where it does")
    h.add_argument("--json", action="store_true", help="print one JSON object")
    h.set_defaults(func=cmd_shapes)

    g = sub.add_parser("register", help="fit the source body onto any target body mesh (writes the "
                                        "source mesh in the target's shape)")
    g.add_argument("--source-body", required=True, help="OBJ: the source body (its mesh is kept)")
    g.add_argument("--target-body", required=True, help="OBJ: any body mesh of a person in a similar pose")
    g.add_argument("--out", required=True, help="OBJ to write: the source body in the target's shape")
    g.add_argument("--no-cache", action="store_true", help="do not read or write the registration cache")
    g.add_argument("--shape-basis", nargs="+", metavar="BODY.obj",
                   help="OBJ files of the source body's mesh in other shapes (its shape keys, other bodies of "
                        "its mesh), same units and axes: when the target is another mesh, the source is first "
                        "fitted as a blend of them (docs/registration.md)")
    g.add_argument("--body-model", metavar="TARGETS.npz",
                   help="MakeHuman's targets archive (makehuman/data/targets.npz of the makehuman wheel: pip "
                        "download --no-deps makehuman==1.3.2): its sliders as the shape basis of a source body "
                        "of MakeHuman's hm08 mesh (docs/registration.md)")
    g.add_argument("--json", action="store_true", help="print one JSON object")
    g.set_defaults(func=cmd_register)

    e = sub.add_parser("evaluate", help="quality figures of a transferred garment")
    e.add_argument("--source", required=True, help="OBJ: the garment on the source body")
    e.add_argument("--result", required=True, help="OBJ: the transferred garment")
    e.add_argument("--target-body", required=True, help="OBJ: the target body")
    e.add_argument("--reference", help="OBJ: the garment simulated/fitted on the target body")
    e.add_argument("--source-body", help="OBJ: the source body (drape error without a reference)")
    e.add_argument("--json", action="store_true", help="print one JSON object")
    e.set_defaults(func=cmd_evaluate)

    r = sub.add_parser("train", help="train a model on a dataset folder: the garment fit model with its learned "
                                     "placement (default) or the paper's shared deformation model",
                       description="Train a model on a dataset folder and write it to one .npz file (plain "
                                   "arrays, no pickle), atomically: --kind garment (default), the garment fit "
                                   "model and its learned placement in one file (docs/garment-model.md); --kind "
                                   "shared, the paper's shared deformation model. Give the file to transfer "
                                   "--model.")
    r.add_argument("--kind", choices=["shared", "garment"], default="garment",
                   help="garment (default): the garment fit model and its learned placement, a field and a hang "
                        "of each garment's own (on the demo's unseen garments 0.6x direct transfer's vertex "
                        "error against the simulation); shared: the paper's model, one field per target")
    r.add_argument("--dataset", required=True, help="folder with bodies/ and garments/")
    r.add_argument("--source", required=True, help="source body name")
    r.add_argument("--targets", required=True, help="target body names, comma-separated")
    r.add_argument("--garments", help="garment names to train on, comma-separated (default: all)")
    r.add_argument("--epochs", type=number_option(int, 1, what="a whole number"), default=None,
                   help="training epochs (>= 1; default 1000 for shared; for garment, passes over the field "
                        "model's samples, default 3)")
    r.add_argument("--latent", type=number_option(int, 1, what="a whole number"), default=None,
                   help="shared only: size of the shared deformation space (>= 1, default 30)")
    r.add_argument("--seed", type=number_option(int, 0, what="a whole number"), default=0)
    r.add_argument("--threads", type=number_option(int, 1, what="a whole number"), default=None,
                   help="torch threads (default: half the cores, 1 to 4); the same data, seed and threads give "
                        "the same model")
    r.add_argument("--unmasked", action="store_true", help="shared only: the paper's unmasked loss")
    r.add_argument("--placement-epochs", type=number_option(int, 1, what="a whole number"), default=None,
                   help="garment only: passes over the placement model's samples (default 30)")
    r.add_argument("--placement-members", type=number_option(int, 1, what="a whole number"), default=None,
                   help="garment only: placement models trained with seeds seed, seed+1, ... and averaged "
                        f"(default {PLACEMENT_MEMBERS}, chosen on held-out training garments; 1: one model)")
    r.add_argument("--no-placement", action="store_true",
                   help="garment only: train the garment fit model alone, without the learned placement")
    r.add_argument("--placement-absolute", action="store_true",
                   help="garment only: the placement networks learn the offset itself, not its difference from "
                        "the training garments' mean offset per body triangle (the default, chosen on held-out "
                        "training garments); with --nearest-garments 0 the file then reads with earlier "
                        "versions too")
    r.add_argument("--nearest-garments", type=share_option, default=None, metavar="SHARE",
                   help="garment only: the share of the nearest garments' placement (the training garments' own "
                        "placements, weighted by how alike each is to the new garment around each body triangle) "
                        f"mixed with the networks' (default {LIBRARY_SHARE:g}); 0 leaves it out")
    r.add_argument("--hold-out", metavar="GARMENTS",
                   help="garments to leave out of training, comma-separated: once the model is written, each is "
                        "transferred to every target with it and with direct transfer and measured against its "
                        "own drape there (vertex error, MDC, vertices inside; the summary's 'check'), to see "
                        "whether the model beats the body alone on garments it has not seen")
    r.add_argument("--out", required=True, help="model file to write (.npz); written once training is complete, "
                                                "replacing a writable file of that name")
    r.add_argument("--json", action="store_true", help="print one JSON object")
    r.set_defaults(func=cmd_train)

    add_weights_arguments(sub.add_parser("weights", help="a garment's skinning weights from the body it is dressed "
                                                         "on (matched where close, inpainted elsewhere)"))
    add_batch_arguments(sub.add_parser(
        "batch", help="every garment of a catalogue on every target body, resumable, on this machine "
                      "or a Dask cluster"))

    return p


def _check_train_options(parser, args):
    """Options of one kind given for the other are usage errors, not silently ignored."""
    other = {"shared": [("--placement-epochs", args.placement_epochs is not None),
                        ("--placement-members", args.placement_members is not None),
                        ("--no-placement", args.no_placement),
                        ("--placement-absolute", args.placement_absolute),
                        ("--nearest-garments", args.nearest_garments is not None)],
             "garment": [("--latent", args.latent is not None), ("--unmasked", args.unmasked)]}[args.kind]
    wrong = [name for name, given in other if given]
    if wrong:
        hint = (" (the default): add --kind shared for the paper's shared deformation model"
                if args.kind == "garment" else "")
        parser.error(f"{', '.join(wrong)} {'is' if len(wrong) == 1 else 'are'} not for train --kind {args.kind}"
                     f"{hint}")
    if args.kind == "garment" and args.no_placement and args.nearest_garments is not None:
        parser.error("--nearest-garments mixes the nearest garments' placement with the learned placement, which "
                     "--no-placement leaves out")
    if args.kind == "garment" and args.placement_epochs is None:

        args.placement_epochs = PLACEMENT_EPOCHS
    if args.kind == "garment" and args.placement_members is None:

        args.placement_members = PLACEMENT_MEMBERS


def main(argv=None):
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if args.command == "transfer":
            if args.method is None:
                args.method = "model" if (args.model or args.target) else "direct"
            elif args.method != "model" and (args.model or args.target):
                parser.error(f"--model and --target are for --method model, not --method {args.method}")
            if (args.field_share is not None or args.no_placement) and not args.model:
                parser.error("--field-share and --no-placement are for a garment fit model given with --model")
            if args.untangle and (len(args.garment) > 1 or args.target_joints is None):
                parser.error("--untangle is for one garment onto a target in another rest pose (with --skeleton, "
                             "--source-joints, --source-weights and --target-joints)")
        if args.command == "train":
            _check_train_options(parser, args)
        if args.command == "shapes":
            _check_shapes_options(parser, args)
        if args.command == "shapes" and args.workers is not None and not args.poses:
            parser.error("--workers is for --poses (the poses fitted at once)")
        if args.command == "shapes" and args.cache is not None and not args.poses:
            parser.error("--cache is for --poses (the poses' animation as one point cache)")
        if args.command == "shapes" and args.untangle and not args.poses:
            parser.error("--untangle is for --poses (a fit to a pose folds cloth through itself)")
        logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                            format="%(levelname)s %(name)s: %(message)s")
        check_command_paths(args)
        args.warning_log = WarningLog()
        logging.getLogger().addHandler(args.warning_log)
        try:
            code = args.func(args)
        finally:
            logging.getLogger().removeHandler(args.warning_log)
    except KeyboardInterrupt:
        # Every writer renames a complete temporary file at the end: nothing is half-written.
        print("interrupted (Ctrl+C); no partial file written", file=sys.stderr)
        return 130
    except GarmentTransferError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return code or 0
