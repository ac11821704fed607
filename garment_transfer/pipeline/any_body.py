"""Transfer onto any target body: the source body registered onto it first when it is another mesh."""

from __future__ import annotations

import time

from ..fitting.registration import Registration, register
from ..fitting.shape_basis import SHAPE_BOUNDS
from ..geometry.embedding import body_scale
from ..geometry.mesh import Mesh, faces_turned
from ..geometry.proximity import as_same_mesh, orientation
from .transfer import (OFFSET_SHARE, check_offset, fit_to_body, pass_inputs_ahead, pose_check, prepare_garment,
                       transfer_garment)


#: The options of ``transfer_to_any_body`` that its registration takes (``registration_for``).
REGISTER_OPTIONS = ("cache", "limits", "progress", "shape_basis", "shape_bounds", "body_model")


def registration_for(source_body: Mesh, target_body: Mesh, registration: Registration | None = None, *, cache=True,
                     limits=None, progress=None, shape_basis=None, shape_bounds=SHAPE_BOUNDS, body_model=False):
    """The registration a transfer onto ``target_body`` goes through: None for the source's own mesh (or that mesh
    with every face turned, ``proximity.as_same_mesh``), else ``registration`` where given, else a new one
    (``register``, with these options; ``progress(fraction, stage)`` over the first 60% of a transfer's)."""
    if as_same_mesh(source_body, target_body) is not None:
        return None
    if registration is not None:
        return registration
    step = None if progress is None else (lambda f, *stage: progress(0.6 * f, *(stage or ("register",))))
    return register(source_body, target_body, cache=cache, limits=limits, progress=step, shape_basis=shape_basis,
                    shape_bounds=shape_bounds, body_model=body_model)


def transfer_to_any_body(source_body: Mesh, target_body: Mesh, garment: Mesh, *, cache=True,
                         limits=None, registration: Registration | None = None, progress=None,
                         shape_basis=None, shape_bounds=SHAPE_BOUNDS, body_model=False, **options):
    """``transfer_garment`` onto any target body: registered first when it is another mesh.

    The garment is solved in the source's frame on the fitted body (so the ``model`` method sees the
    frame and units it was trained in), taken to the target's frame, and there pushed out of the target
    itself and cleared of every crossing with it (``transfer.fit_to_body``): the penetration fix, the crossing
    pass and their figures are those of the body the user gave, not of the fitted one.

    Parameters
    ----------
    source_body, target_body, garment : Mesh
    cache : bool or str
        See ``register``.
    limits : dict, optional
        See ``register``.
    registration : Registration, optional
        A registration of these two bodies made earlier (skips ``register``).
    progress : callable, optional
        ``progress(fraction, stage)``; returning True cancels.
    shape_basis : (k,n,3) float, optional
        See ``register`` (used only when the target is another mesh).
    shape_bounds : (2,) or (k,2) float
        See ``register``.
    body_model : bool
        See ``register``.
    **options
        Passed to ``transfer_garment`` (method, model, target, offset, fix_penetration, prepared, ...);
        ``offset`` is in the target's units.

    Returns
    -------
    result : TransferResult
        In the target's frame; ``info["registration"]`` holds the fit's figures when one was made.
    registration : Registration or None
        None when the two bodies are one mesh (also when the target is the source's mesh with every face
        turned the other way round, an OBJ of the other winding, or with its polygons split, written
        triangulated: ``proximity.as_same_mesh``; ``info["target_faces_turned"]`` and
        ``info["target_faces_split"]`` then say so).
    """
    same = as_same_mesh(source_body, target_body)
    if same is not None:
        result = transfer_garment(source_body, same, garment, progress=progress, **options)
        if same is not target_body:
            # Split: more polygons than the source's; turned: its own faces enclose its shape the other way round.
            split = target_body.face_start.shape != source_body.face_start.shape
            if split:
                result.info["target_faces_split"] = True
            if faces_turned(source_body, target_body) or (
                    split and orientation(target_body.V, target_body.F) != orientation(target_body.V, source_body.F)):
                result.info["target_faces_turned"] = True
        return result, None

    def sub(lo, hi):
        if progress is None:
            return None
        return lambda f, *stage: progress(lo + (hi - lo) * f, *(stage or ("register",)))

    reg = registration_for(source_body, target_body, registration, cache=cache, limits=limits, progress=progress,
                           shape_basis=shape_basis, shape_bounds=shape_bounds, body_model=body_model)
    options = dict(options)
    offset = options.pop("offset", None)
    fix = options.pop("fix_penetration", True)
    resolve = options.pop("resolve_crossings", True)
    prepared = options.pop("prepared", None)
    fitted = source_body.with_vertices(reg.V_source_frame,
                                       name=f"{source_body.name} fitted to {target_body.name}")
    made = prepared is None
    if made:
        prepared = prepare_garment(source_body, garment, interpolate=options.get("interpolate", True),
                                   stiffness=options.get("stiffness"), need_solver=options.get("method") != "surface",
                                   anchoring=options.get("anchoring", "everywhere"), reused=False)
    early = pass_inputs_ahead(prepared, target_body) if fix and resolve else None
    # Solved in the source's frame on the fitted body (a model sees the frame and units it was trained in);
    # the fix and the crossing pass then run on the target itself, in its own frame: the body the user gave.
    pose = (pose_check(source_body, fitted.V, target_body.name, prepared.limbs(), prepared.covered())
            if options.pop("check_pose", True) else None)
    result = transfer_garment(source_body, fitted, garment, progress=sub(0.6, 0.9), fix_penetration=False,
                              prepared=prepared, check_pose=False, **options)
    if pose is not None:
        result.info["limb_angles"] = pose
    if made:
        for stage, seconds in prepared.seconds.items():
            result.seconds[stage] = result.seconds.get(stage, 0.0) + seconds
        result.seconds["total"] += sum(prepared.seconds.values())
    t = time.perf_counter()
    back = reg.alignment.inverse()
    V = back.apply(result.V)
    offset = check_offset(offset, target_body)
    if offset is None:
        offset = OFFSET_SHARE * body_scale(target_body.V)
    result.info.update(offset=float(offset), fix_penetration=bool(fix))
    result.V, result.penetrating_vertices, result.obstacle, result.surface = fit_to_body(
        V, prepared, target_body, offset, fix_penetration=fix, resolve_crossings=resolve,
        source_V=back.apply(garment.V), info=result.info, seconds=result.seconds,
        step=None if progress is None else (lambda f, stage: progress(0.9 + 0.5 * (f - 0.8), stage)), early=early)
    result.info["registration"] = reg.summary()
    result.seconds["register"] = float(reg.seconds.get("total", 0.0)) if not reg.cached else 0.0
    result.seconds["target_fit"] = time.perf_counter() - t
    result.seconds["total"] += result.seconds["register"] + result.seconds["target_fit"]
    return result, reg
