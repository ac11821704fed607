"""What each command reads and writes, declared per command and checked in one place before any work.

``main`` runs ``check_command_paths`` before every command: the command's declaration (``DECLARED``) names
the files and folders it reads and the files and folders it writes, and ``files.check_outputs`` refuses an
output that is an input, lies inside an input folder, or (batch) an output folder that holds an input,
however the path is spelled, as well as an output whose folder is missing, a file or read-only. A command
without a declaration does not run.
"""

from __future__ import annotations

import os

from ..errors import GarmentTransferError
from ..files import check_outputs
from ..learning.dataset import dataset_inputs
from ..pipeline.batch import batch_paths
from ..pipeline.catalogue import read_catalogue
from ..pipeline.shape_keys import shapes_outputs


def outfit_out_paths(garments, outs):
    """Output files of an outfit: one --out per garment, or one existing folder for all
    (``<garment file name>`` inside it)."""
    if len(outs) == 1 and os.path.isdir(outs[0]):
        paths = [os.path.join(outs[0], os.path.basename(g)) for g in garments]
    elif len(outs) == len(garments):
        paths = list(outs)
    else:
        raise GarmentTransferError(f"{len(garments)} garments need {len(garments)} --out files or one "
                                   f"existing --out folder, got {len(outs)} --out")
    if len({os.path.realpath(p) for p in paths}) != len(paths):
        raise GarmentTransferError(f"two layers would be written to the same file: {', '.join(paths)}")
    return paths


def transfer_out_paths(args):
    """The files ``transfer`` writes: one per garment."""
    if len(args.garment) > 1:
        return outfit_out_paths(args.garment, args.out)
    if len(args.out) != 1:
        raise GarmentTransferError(f"one garment needs one --out, got {len(args.out)}")
    return list(args.out)


def _transfer(args):
    return dict(files=transfer_out_paths(args),
                inputs=[args.source_body, args.target_body, args.target_cage, *args.garment, args.model,
                        *(args.shape_basis or []), args.body_model, args.skeleton, args.source_joints,
                        args.source_weights, args.target_joints])


def _register(args):
    return dict(files=[args.out], inputs=[args.source_body, args.target_body, *(args.shape_basis or []),
                                          args.body_model])


def _shapes(args):
    outs, summary = shapes_outputs(args.target_body or [], args.garment, args.out)
    if getattr(args, "poses", False):
        summary = summary.with_name("poses.json")
    return dict(files=[*outs.values(), summary, *([args.cache] if getattr(args, "cache", None) else [])],
                folders=[args.out],
                inputs=[args.source_body, *(args.target_body or []), getattr(args, "target_cache", None),
                        args.garment])


def _weights(args):
    return dict(files=[args.out], inputs=[args.body, args.weights, args.garment])


def _evaluate(args):
    # It writes nothing: declared so that an output added to it one day is declared too.
    return dict(inputs=[args.source, args.result, args.target_body, args.reference, args.source_body])


def _train(args):
    files, folders = dataset_inputs(args.dataset)
    return dict(files=[args.out], inputs=files, input_folders=folders)


def batch_catalogue(args):
    """The catalogue of ``batch``'s arguments (read and checked; no mesh is read)."""
    def split(text):
        return None if text is None else [x for x in text.split(",") if x]

    settings = {}
    if args.method:
        settings["method"] = args.method
    if args.model:
        settings["model"] = os.path.abspath(args.model)
    if args.offset is not None:
        settings["offset"] = args.offset
    if args.field_share is not None:
        settings["field_share"] = args.field_share
    if args.no_fix:
        settings["fix_penetration"] = False
    if args.no_interpolate:
        settings["interpolate"] = False
    if args.untangle:
        settings["untangle"] = True
    return read_catalogue(args.catalogue, source=args.source, targets=split(args.targets),
                          garments=split(args.garments), settings=settings)


def batch_log(args):
    """The log file ``batch`` appends to."""
    return args.log or os.path.join(args.out, "batch.log")


def _batch(args):
    return batch_paths(batch_catalogue(args), args.out, log=batch_log(args))


#: Command -> its declaration: a function of the parsed arguments giving ``files.check_outputs``'s
#: arguments (``files``, ``folders`` written; ``inputs``, ``input_folders`` read).
DECLARED = {"transfer": _transfer, "register": _register, "shapes": _shapes, "evaluate": _evaluate,
            "train": _train, "batch": _batch, "weights": _weights}


def command_paths(args) -> dict:
    """What the command of ``args`` reads and writes (``check_outputs``'s arguments).

    Raises
    ------
    GarmentTransferError
        A command without a declaration.
    """
    if args.command not in DECLARED:
        raise GarmentTransferError(f"the command {args.command!r} does not declare what it reads and writes "
                                   "(garment_transfer/cli/paths.py), so it cannot be checked; it does not run")
    return DECLARED[args.command](args)


def check_command_paths(args):
    """Raise ``files.OutputError`` (one line naming the path) unless the command's outputs harm none of its
    inputs and can be written: run before any work."""
    check_outputs(**command_paths(args))
