"""Transfer many garments to many target bodies in one run, headless.

In Blender:
    blender --background --python-exit-code 1 --python scripts/batch_transfer.py -- \
        --source-body S.obj --target-body T1.obj --target-body T2.obj --garment G1.obj --garment G2.obj \
        --out DIR [--blend out.blend]
With the bpy module (same arguments, ``--`` optional):
    .venv/bin/python scripts/batch_transfer.py --source-body S.obj ... --out DIR
From a catalogue (the format of ``python -m garment_transfer batch``, docs/batch.md: JSON, TOML or a
dataset folder, with each garment's source body, targets, method and settings):
    blender --background --python scripts/batch_transfer.py -- --catalogue CAT.toml --out DIR --scale 0.1

Every (garment, target) pair goes through the add-on's own operator (bpy.ops.garment_transfer.transfer)
and is written to DIR/<garment>_on_<target>.obj (with a catalogue: DIR/<garment>/<target>.obj, the
core batch's layout), in the input files' axes and units, as the garment's own file with the new positions
(its materials, groups and comments kept, its material libraries named from there). A file that cannot
be read or a pair that fails is reported and skipped; the run goes on, writes DIR/summary.json, and
exits with 1 if anything failed (0 otherwise, 2 for bad arguments). Before Blender reads anything, every
output (each result, the summary, --blend) is checked against every file the run reads, with the core's
check (an output that is an input, or a catalogue's results folder holding one, is a bad argument). Every
file is written whole or not at all. Ctrl+C stops the run: what was written stays, summary.json lists it,
and the exit code is 130.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import shutil
import signal
import sys
import threading
import time
import traceback
from pathlib import Path

AXES = ["X", "Y", "Z", "NEGATIVE_X", "NEGATIVE_Y", "NEGATIVE_Z"]


INTERRUPTED = "interrupted (Ctrl+C) before the end of the run"


class InputError(Exception):
    pass


# The checkout's core, for the checks made before Blender imports or writes anything (the same ones
# as the command line's); it needs numpy only.
_ROOT = str(Path(__file__).resolve().parents[1])
if _ROOT not in sys.path:
    sys.path.append(_ROOT)


@contextlib.contextmanager
def atomic_output(path, inputs=()):
    """Yield a temporary path next to ``path`` to write; it becomes ``path`` (one rename) when the block
    ends, and is removed when the block fails or is interrupted, so that no partial file is left.

    The core's ``files.atomic_path``: ``path`` is checked first, as every output of the core is (never
    one of ``inputs``, never a symlink, folder or special file: raises InputError).
    """
    from garment_transfer.errors import GarmentTransferError
    from garment_transfer.files import atomic_path

    try:
        with atomic_path(path, inputs, "--out") as tmp:
            yield Path(tmp)
    except GarmentTransferError as exc:
        raise InputError(str(exc)) from None


_interrupted = False


def _on_sigint(_signum, _frame):
    global _interrupted
    _interrupted = True
    raise KeyboardInterrupt


def stop_if_interrupted(error=None):
    """Raise KeyboardInterrupt when Ctrl+C was pressed, or when ``error`` (a RuntimeError from an
    operator) is one raised inside the operator.

    Blender lets no exception out of an operator or a property callback: it prints it (and for an
    operator, bpy.ops then raises a RuntimeError holding the traceback's text). A Ctrl+C that lands
    there would otherwise only fail one pair, and the run would go on.
    """
    if _interrupted or (error is not None and "KeyboardInterrupt" in str(error).splitlines()):
        raise KeyboardInterrupt


def parse_args(argv):
    parser = argparse.ArgumentParser(
        prog="batch_transfer.py",
        description="Transfer garments (OBJ) from a source body to target bodies with Garment Transfer.")
    parser.add_argument("--catalogue", type=Path,
                        help="a catalogue (.json, .toml or dataset folder; see docs/batch.md) instead of "
                             "--source-body/--target-body/--garment; --method, --model, --offset and "
                             "--no-fix replace its [settings], a garment's own settings win")
    parser.add_argument("--source", help="with a dataset folder as --catalogue: the source body's name")
    parser.add_argument("--source-body", type=Path,
                        help="the body the garments were made on (OBJ)")
    parser.add_argument("--target-body", type=Path, action="append",
                        help="a body to transfer to (OBJ; repeatable)")
    parser.add_argument("--garment", type=Path, action="append",
                        help="a garment on the source body (OBJ; repeatable)")
    parser.add_argument("--out", type=Path, required=True, help="folder for the results")
    parser.add_argument("--blend", type=Path, help="also save every body, garment and result here")
    parser.add_argument("--method", choices=["direct", "model", "surface"], default=None,
                        help="direct (default): the body's own deformation; model: a trained model "
                             "(--model); surface: baseline, the garment follows the body surface only")
    parser.add_argument("--model", type=Path, help="model file (.npz) for --method model")
    parser.add_argument("--target-label", action="append",
                        help="the model's label of each target body, in order "
                             "(default: the target file's name)")
    parser.add_argument("--offset", type=float,
                        help="distance kept from the body, in the files' units: >= 0 and at most 5%% of "
                             "the body's size (default: automatic)")
    parser.add_argument("--no-fix", action="store_true", help="do not fix penetrations")
    parser.add_argument("--scale", type=float, default=1.0,
                        help="scene units per file unit on import (0.1 for decimetre files)")
    parser.add_argument("--up", choices=AXES, default="Y", help="the files' up axis")
    parser.add_argument("--forward", choices=AXES, default="NEGATIVE_Z", help="the files' forward axis")
    args = parser.parse_args(argv)
    if args.catalogue is not None:
        given = [o for o, v in (("--source-body", args.source_body), ("--target-body", args.target_body),
                                ("--garment", args.garment), ("--target-label", args.target_label))
                 if v]
        if given:
            parser.error(f"--catalogue lists the bodies and garments: drop {', '.join(given)}")
    else:
        missing = [o for o, v in (("--source-body", args.source_body), ("--target-body", args.target_body),
                                  ("--garment", args.garment)) if not v]
        if missing:
            parser.error(f"the following arguments are required: {', '.join(missing)} (or --catalogue)")
    args.method_given = args.method is not None
    args.method = args.method or "direct"
    if args.method == "model" and args.model is None and args.catalogue is None:
        parser.error("--method model needs --model FILE")
    if args.target_label and len(args.target_label) != len(args.target_body):
        parser.error("give one --target-label per --target-body")
    if not math.isfinite(args.scale) or args.scale <= 0:
        parser.error("--scale must be a finite number > 0")
    if args.offset is not None and (not math.isfinite(args.offset) or args.offset < 0):
        parser.error(f"--offset {args.offset}: must be a finite distance >= 0")
    return args


def output_problem(args, jobs, reads):
    """The core's objection to this run's outputs (one line), or None: ``files.check_outputs``, the check
    every command of the core makes, of every result, the summary and ``--blend`` against every file the
    run reads (``reads``: files and folders, from ``plan``), before anything is imported or written."""
    from garment_transfer.errors import GarmentTransferError
    from garment_transfer.files import check_outputs

    results = [job.output(args.out, name) for job in jobs for name, _, _ in job.targets]
    files = results + [args.out / "summary.json"] + ([(args.blend, "--blend")] if args.blend else [])
    try:
        # With a catalogue, results go to sub-folders named by its garments: the folder must hold no input.
        check_outputs(files, [args.out], inputs=reads[0], input_folders=reads[1],
                      holds_none=args.catalogue is not None)
    except GarmentTransferError as exc:
        return str(exc)
    return None


def core_batch():
    """The core's batch module (the result layout), from this script's own checkout or extension folder (on
    ``sys.path`` above): the same code as ``python -m garment_transfer batch``."""
    from garment_transfer.pipeline import batch

    return batch


def core_catalogue():
    """The core's catalogue reader, from the same place as ``core_batch``."""
    from garment_transfer.pipeline import catalogue

    return catalogue


@dataclasses.dataclass
class Job:
    """One garment and its targets, from the options or from a catalogue entry."""

    name: str
    garment: Path
    source_name: str
    source: Path
    targets: list          # (name, path, model label or "")
    method: str
    model: Path | None
    offset: float | None
    fix: bool
    catalogue: bool = False
    field_share: float | None = None

    def output(self, out, target):
        if self.catalogue:
            return core_batch().result_paths(out, self.name, target)[0]
        return out / f"{self.name}_on_{target}.obj"


def plan(args):
    """The jobs of a run (one per garment), and what the run reads: ``(files, folders)``."""
    if args.catalogue is None:
        paths = [args.source_body, *args.target_body, *args.garment]
        labels = dict(zip(map(str, paths), unique_labels(paths)))
        targets = [(labels[str(p)], p, args.target_label[i] if args.target_label else p.stem)
                   for i, p in enumerate(args.target_body)]
        jobs = [Job(labels[str(g)], g, labels[str(args.source_body)], args.source_body, targets,
                    args.method, args.model, args.offset, not args.no_fix) for g in args.garment]
        return jobs, ([*paths, args.model], [])
    catalogue = core_catalogue()
    options = {"method": args.method} if args.method_given else {}
    if args.model is not None:
        options["model"] = str(args.model.resolve())
    if args.offset is not None:
        options["offset"] = args.offset
    if args.no_fix:
        options["fix_penetration"] = False
    try:
        cat = catalogue.read_catalogue(args.catalogue, source=args.source, settings=options)
    except catalogue.CatalogueError as exc:
        raise InputError(str(exc)) from None
    jobs = []
    for j in cat.jobs:
        s = j.settings
        if not s.interpolate or s.stiffness is not None:
            raise InputError(f"{j.entry} of {cat.origin}: interpolate and stiffness are not settings of "
                             "the Blender operator; run it with python -m garment_transfer batch")
        jobs.append(Job(j.name, Path(j.file), j.source, Path(j.source_file),
                        [(t.name, Path(t.body), t.label or t.name) for t in j.targets], s.method,
                        None if s.model is None else Path(s.model), s.offset, s.fix_penetration, True,
                        s.field_share))
    files, folders = cat.inputs()
    return jobs, ([*files, args.model], folders)


def script_argv(argv):
    """The script's own arguments: after ``--`` under Blender, else everything after the script."""
    return argv[argv.index("--") + 1:] if "--" in argv else argv[1:]


def ensure_operators():
    """Register the add-on from this checkout unless Blender already has it enabled."""
    import bpy

    if hasattr(bpy.types, "GARMENT_TRANSFER_OT_transfer"):
        return None
    tools = Path(__file__).resolve().parents[1] / "tools"
    if not (tools / "extension_loader.py").is_file():
        raise InputError("the Garment Transfer extension is not enabled in this Blender: enable it in "
                         "Preferences > Add-ons (or run this script from a checkout of the project)")
    sys.path.insert(0, str(tools))
    from extension_loader import load_extension

    try:
        import scipy  # noqa: F401
    except ImportError:
        raise InputError("scipy is missing from this Python: install the extension in Blender "
                         "(it brings scipy), or run this script with the project's .venv/bin/python")
    ext = load_extension()
    ext.register()
    return ext


def unique_labels(paths):
    """A short, distinct label per input file: its name, or folder_name where names repeat."""
    stems = [p.stem for p in paths]
    return [s if stems.count(s) == 1 else f"{p.parent.name}_{s}" for p, s in zip(paths, stems)]


def check_obj(path):
    """Read ``path`` with the core's OBJ reader: the checks of the command line (NaN, damaged lines, a
    cut-off file, ...), which Blender's importer does not make (it reads NaN as 0). Returns the core's Mesh."""
    from garment_transfer.errors import GarmentTransferError
    from garment_transfer.geometry.obj import read_obj

    try:
        return read_obj(path)
    except GarmentTransferError as exc:
        raise InputError(str(exc)) from None


def import_obj(path, label, args):
    """Import one OBJ file as one mesh object named ``label``: (the object, the file as the core read it)."""
    import bpy

    if not path.is_file():
        raise InputError(f"{path}: file not found")
    read = check_obj(path)
    before = set(bpy.data.objects)
    try:
        bpy.ops.wm.obj_import(filepath=str(path), global_scale=args.scale, up_axis=args.up,
                              forward_axis=args.forward, use_split_objects=False,
                              use_split_groups=False)
    except RuntimeError as exc:
        stop_if_interrupted(exc)
        raise InputError(f"{path}: cannot be imported ({exc})") from None
    new = [o for o in bpy.data.objects if o not in before]
    meshes = [o for o in new if o.type == 'MESH']
    if len(meshes) != 1:
        remove_objects(new)
        raise InputError(f"{path}: expected one mesh, found {len(meshes)} (is it an OBJ file?)")
    obj = meshes[0]
    obj.name = label
    obj.data.name = label
    return obj, read


def remove_objects(objects):
    import bpy

    for obj in list(objects):
        data = obj.data
        bpy.data.objects.remove(obj)
        if data is not None and data.users == 0:
            bpy.data.meshes.remove(data)


def export_obj(obj, path, args, garment_mesh=None):
    """Write the result ``obj`` to ``path`` in the input files' units and axes (Blender's exporter); given
    ``garment_mesh`` (the garment's file as the core read it), as that file with the new positions (the core's
    writer: its materials, groups, smoothing, UVs and comments kept, its normals turned with the cloth, its
    material libraries named from ``path``), where the export has the garment's polygons in its vertex order."""
    import bpy

    inputs = [args.source_body, *(args.target_body or []), *(args.garment or []), args.model, args.catalogue]
    for other in bpy.context.view_layer.objects:
        other.select_set(False)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    with atomic_output(path, inputs) as tmp:
        bpy.ops.wm.obj_export(filepath=str(tmp), export_selected_objects=True, apply_modifiers=True,
                              global_scale=1.0 / args.scale, up_axis=args.up,
                              forward_axis=args.forward, export_materials=False,
                              export_normals=False, export_uv=True, export_triangulated_mesh=False)
        if garment_mesh is not None:
            _as_garment_file(tmp, path, garment_mesh)


def _as_garment_file(tmp, path, garment):
    """Rewrite the export ``tmp`` as the garment's own file (``garment``: the core's Mesh of it) with the exported
    positions, where its polygons are the garment file's (the same vertices in the same order)."""
    import numpy as np

    from garment_transfer.geometry.obj import obj_text, read_obj

    exported = read_obj(tmp, name=str(path))
    if (exported.V.shape == garment.V.shape and np.array_equal(exported.face_start, garment.face_start)
            and np.array_equal(exported.face_vertices, garment.face_vertices)):
        tmp.write_bytes(obj_text(garment, exported.V, path=path).encode("utf-8", errors="surrogateescape"))


def run(args, log, records=None, jobs=None):
    """Do the whole batch; return one record per (garment, target) pair, or per unreadable file.

    ``records``, when given, receives the records as they are made (all done so far when the run is
    interrupted). ``jobs``: ``plan(args)``'s, when already made.
    """
    import bpy

    jobs = plan(args)[0] if jobs is None else jobs
    bpy.ops.wm.read_homefile(use_empty=True)
    ensure_operators()
    args.out.mkdir(parents=True, exist_ok=True)
    records = [] if records is None else records
    settings = bpy.context.scene.garment_transfer
    bodies = {}

    def body(path, label, role):
        """The body object of a file, imported once; raises InputError when it cannot be."""
        key = str(path)
        if key not in bodies:
            try:
                bodies[key] = import_obj(path, label, args)[0]
            except InputError as exc:
                bodies[key] = exc
                log(f"FAILED {exc}")
                if role == "target" and not args.catalogue:
                    records.append({"target": key, "error": str(exc)})
        if isinstance(bodies[key], InputError):
            raise bodies[key]
        return bodies[key]

    for job in jobs:
        try:
            source = body(job.source, job.source_name, "source")
        except InputError as exc:
            if not args.catalogue:
                raise
            records.extend({"garment": job.name, "target": t, "error": str(exc)} for t, _, _ in job.targets)
            continue
        targets = []
        for name, path, label in job.targets:
            try:
                targets.append((body(path, name, "target"), name, label))
            except InputError as exc:
                if args.catalogue:
                    records.append({"garment": job.name, "target": name, "error": str(exc)})
        try:
            garment, garment_mesh = import_obj(job.garment, job.name, args)
        except InputError as exc:
            log(f"FAILED {exc}")
            records.append({"garment": str(job.garment), "error": str(exc)})
            continue
        settings.source_body = source
        settings.method = job.method.upper()
        settings.model_path = str(job.model) if job.model else ""
        # Reset for every job: a catalogue's garments may set their own share, or none (the default).
        settings.field_share = (settings.bl_rna.properties["field_share"].default if job.field_share is None
                                else job.field_share)
        settings.fix_penetration = job.fix
        settings.auto_offset = job.offset is None
        if job.offset is not None:
            settings.offset = job.offset * args.scale
        settings.garment = garment
        results = []
        for target, name, label in targets:
            stop_if_interrupted()
            record, result = transfer_pair(garment, target, label, args, log,
                                           job.output(args.out, name), job.method, garment_mesh)
            if args.catalogue:
                record.update(garment=job.name, target=name)
            records.append(record)
            results += [result] if result is not None else []
        if args.blend is None:
            # Nothing is kept for a .blend: free each garment's objects before the next one.
            remove_objects(results + [garment])
    if args.blend is not None:
        bpy.ops.wm.save_as_mainfile(filepath=str(args.blend.resolve()), check_existing=False)
        log(f"saved {args.blend}")
    return records


def transfer_pair(garment, target, label, args, log, output, method, garment_mesh=None):
    """Transfer one garment to one target with the operator and export the result (as ``export_obj``).

    Returns
    -------
    record : dict
        Names, output path, metrics and seconds, or ``error``.
    result : bpy.types.Object or None
    """
    import bpy

    settings = bpy.context.scene.garment_transfer
    settings.target_body = target
    settings.target_label = label if method == "model" else ""
    record = {"garment": garment.name, "target": target.name}
    start = time.perf_counter()
    try:
        bpy.ops.garment_transfer.transfer()
    except RuntimeError as exc:
        stop_if_interrupted(exc)
        record["error"] = str(exc).strip().removeprefix("Error: ")
        log(f"FAILED {garment.name} -> {target.name}: {record['error']}")
        return record, None
    result = settings.result
    output.parent.mkdir(parents=True, exist_ok=True)
    try:
        export_obj(result, output, args, garment_mesh)
    except InputError as exc:
        record["error"] = str(exc)
        log(f"FAILED {garment.name} -> {target.name}: {record['error']}")
        return record, result
    record.update(json.loads(settings.last_metrics or "{}"))
    record.update(output=str(output), seconds=round(time.perf_counter() - start, 3))
    log(f"ok {garment.name} -> {target.name}: {output} (MDC {record.get('mdc', float('nan')):.4f}, "
        f"{record.get('penetration_ratio', 0.0):.1%} inside, {record['seconds']:.2f} s)")
    return record, result


def main(argv=None):
    args = parse_args(script_argv(sys.argv if argv is None else argv))

    def log(text):
        print(f"batch_transfer: {text}", file=sys.stderr, flush=True)

    try:
        jobs, reads = plan(args)
    except InputError as exc:
        log(f"FAILED {exc}")
        return 1
    problem = output_problem(args, jobs, reads)
    if problem:
        # A bad --out or --blend is a bad argument (exit 2), found before Blender reads or writes anything.
        print(f"batch_transfer.py: error: {problem}", file=sys.stderr, flush=True)
        return 2

    global _interrupted
    _interrupted = False
    records = []
    interrupted = False
    # Under Blender, Ctrl+C only sets a flag the first time and ends the process at once the second
    # time; as a KeyboardInterrupt it stops the run cleanly (the bpy module's Python does this already).
    # Blender's own handler is not a Python one: signal.signal returns None for it, nothing to restore.
    previous = (signal.signal(signal.SIGINT, _on_sigint)
                if threading.current_thread() is threading.main_thread() else None)
    try:
        run(args, log, records, jobs)
    except InputError as exc:
        log(f"FAILED {exc}")
        return 1
    except KeyboardInterrupt:
        interrupted = True
        records.append({"error": INTERRUPTED})
        log(INTERRUPTED)
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    failed = [r for r in records if "error" in r]
    summary = args.out / "summary.json"
    if args.out.is_dir():
        with atomic_output(summary) as tmp:
            tmp.write_text(json.dumps(records, indent=1) + "\n", encoding="utf-8")
    done = len(records) - len(failed)
    log(f"{done} transferred, {len(failed) - interrupted} failed; summary in {summary}")
    return 130 if interrupted else 1 if failed else 0


def remove_session_folder():
    """Remove Blender's folder for this session's temporary files (``bpy.app.tempdir``, ``blender_*`` in the
    system's or the preferences' temporary folder), as Blender does when it exits: leaving without exit handlers
    would leave one behind at every run of the batch."""
    bpy = sys.modules.get("bpy")
    folder = Path(bpy.app.tempdir) if bpy is not None else None
    if folder is not None and folder.name.startswith("blender_") and folder.is_dir():
        shutil.rmtree(folder, ignore_errors=True)


def leave():
    """Run the batch and leave with its exit code: 130 on Ctrl+C, a usage error's code, 1 with the traceback on
    an error nothing else caught. Blender's session folder is removed, then the process leaves without exit
    handlers: the bpy 4.5 module can hang in its own (a thread that closes files late waits forever), and
    everything is written by now."""
    try:
        code = main()
    except KeyboardInterrupt:
        code = 130
    except SystemExit as exc:
        # Python's own rule: no code is 0, a number is itself, anything else is said and is 1.
        code = 0 if exc.code is None else exc.code if isinstance(exc.code, int) else 1
        if not isinstance(exc.code, (int, type(None))):
            print(exc.code, file=sys.stderr)
    except Exception:  # noqa: BLE001 - said with its traceback, then the run ends as a failure
        traceback.print_exc()
        print("batch_transfer: FAILED: an error the batch does not know (above)", file=sys.stderr)
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    remove_session_folder()
    os._exit(code)


if __name__ == "__main__":
    leave()
