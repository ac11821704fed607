"""Transfer onto any target body: the source body registered onto it first when it is another mesh."""

from __future__ import annotations

import time

import numpy as np

from ..errors import MeshError
from ..fitting.registration import Registration, register
from ..fitting.shape_basis import SHAPE_BOUNDS
from ..geometry.embedding import body_scale
from ..geometry.mesh import Mesh, faces_turned
from ..geometry.proximity import TriangleSurface, as_same_mesh, common_mesh, one_mesh, orientation
from .transfer import (OFFSET_SHARE, check_offset, fit_to_body, pass_inputs_ahead, pose_check, prepare_garment,
                       transfer_garment)


#: The farthest a subdivided target may lie from the cage given with it, as a share of the body's scale (one or two
#: levels of Catmull-Clark on MakeHuman's bodies lie within 0.18% of their cage; the surface of another body of the
#: same mesh lies 3% and more from it).
CAGE_DISTANCE_SHARE = 0.01

#: The options of ``transfer_to_any_body`` that its registration takes (``registration_for``).
REGISTER_OPTIONS = ("cache", "limits", "progress", "shape_basis", "shape_bounds", "body_model")


def registration_for(source_body: Mesh, target_body: Mesh, registration: Registration | None = None, *, cache=True,
                     limits=None, progress=None, shape_basis=None, shape_bounds=SHAPE_BOUNDS, body_model=False):
    """The registration a transfer onto ``target_body`` goes through: None for the source's own mesh (or that mesh
    with every face turned, or either of the two written triangulated: ``proximity.one_mesh``), else
    ``registration`` where given, else a new one (``register``, with these options; ``progress(fraction, stage)``
    over the first 60% of a transfer's)."""
    if one_mesh(source_body, target_body):
        return None
    if registration is not None:
        return registration
    step = None if progress is None else (lambda f, *stage: progress(0.6 * f, *(stage or ("register",))))
    return register(source_body, target_body, cache=cache, limits=limits, progress=step, shape_basis=shape_basis,
                    shape_bounds=shape_bounds, body_model=body_model)


def transfer_to_any_body(source_body: Mesh, target_body: Mesh, garment: Mesh, *, cache=True,
                         limits=None, registration: Registration | None = None, progress=None,
                         shape_basis=None, shape_bounds=SHAPE_BOUNDS, body_model=False, target_cage=None,
                         **options):
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
    target_cage : Mesh, optional
        The target before a modifier refined its surface (a Subdivision Surface in Blender: ``target_body`` is
        the surface it makes, ``target_cage`` the mesh it subdivides). Where the cage is the source's mesh and
        the target is not, the garment is solved on the cage, with no registration, and fixed and cleared on
        ``target_body`` (``info["target_cage"]`` says so).
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
        ``info["target_faces_split"]`` then say so; and when the source is the target's mesh written
        triangulated, or both are, along other diagonals, ``info["source_faces_split"]``: solved on the
        source's triangles, cleared on the target's own faces: ``proximity.one_mesh``).
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

    common = common_mesh(source_body, target_body)
    if common is not None:
        # The source written triangulated and the target with its polygons, or the two triangulated along other
        # diagonals (either winding): solved on the source's faces in the target's shape, then fixed and cleared
        # on the target's own faces (every split of its polygons read).
        result = _solve_then_fit(source_body, source_body.with_vertices(target_body.V), target_body, garment,
                                 None, progress, options)
        result.info["source_faces_split"] = True
        if common.n_faces != target_body.n_faces:
            result.info["target_faces_split"] = True
        if orientation(target_body.V, target_body.F) != orientation(target_body.V, source_body.F):
            result.info["target_faces_turned"] = True
        return result, None
    if target_cage is not None and one_mesh(source_body, target_cage):
        # The target's own surface refines its cage, the source's mesh: solved on the cage, fitted to the surface.
        require_cage(target_body, target_cage)
        result = _solve_then_fit(source_body, source_body.with_vertices(target_cage.V), target_body, garment,
                                 None, progress, options)
        result.info["target_cage"] = True
        return result, None
    reg = registration_for(source_body, target_body, registration, cache=cache, limits=limits, progress=progress,
                           shape_basis=shape_basis, shape_bounds=shape_bounds, body_model=body_model)
    fitted = source_body.with_vertices(reg.V_source_frame,
                                       name=f"{source_body.name} fitted to {target_body.name}")
    result = _solve_then_fit(source_body, fitted, target_body, garment, reg.alignment.inverse(), progress, options)
    result.info["registration"] = reg.summary()
    result.seconds["register"] = float(reg.seconds.get("total", 0.0)) if not reg.cached else 0.0
    result.seconds["total"] += result.seconds["register"]
    return result, reg


def cage_gap(target_body: Mesh, cage: Mesh):
    """How far ``target_body`` lies from ``cage`` at most, and the body's scale: ``(far, scale)``."""
    far = float(np.abs(TriangleSurface(cage.V, cage.F).signed_distance(target_body.V)[0]).max())
    return far, body_scale(cage.V)


def lies_on_cage(target_body: Mesh, cage: Mesh) -> bool:
    """Whether ``target_body`` lies within ``CAGE_DISTANCE_SHARE`` of the body's scale from ``cage`` everywhere, as
    the surface a subdivision makes of it does (a sculpt on the subdivision may take it farther)."""
    far, scale = cage_gap(target_body, cage)
    return far <= CAGE_DISTANCE_SHARE * scale


def require_cage(target_body: Mesh, cage: Mesh):
    """Raise MeshError unless ``target_body`` lies on ``cage`` (``lies_on_cage``)."""
    far, scale = cage_gap(target_body, cage)
    if not far <= CAGE_DISTANCE_SHARE * scale:
        raise MeshError(target_body.name, f"lies up to {far:.4g} from its cage {cage.name}, more than "
                                          f"{CAGE_DISTANCE_SHARE:.0%} of the body's size ({scale:.4g}): the cage is "
                                          "not the mesh it subdivides")


def _solve_then_fit(source_body, fitted, target_body, garment, back, progress, options):
    """The garment solved on ``fitted`` (the source's mesh in the target's shape, in the source's frame), taken
    to the target's frame by ``back`` (a ``Similarity``; None: the same frame), and there fixed and cleared on
    the target itself (``fit_to_body``)."""

    def sub(lo, hi):
        if progress is None:
            return None
        return lambda f, *stage: progress(lo + (hi - lo) * f, *(stage or ("register",)))

    options = dict(options)
    offset = options.pop("offset", None)
    fix = options.pop("fix_penetration", True)
    resolve = options.pop("resolve_crossings", True)
    prepared = options.pop("prepared", None)
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
    V = result.V if back is None else back.apply(result.V)
    offset = check_offset(offset, target_body)
    if offset is None:
        offset = OFFSET_SHARE * body_scale(target_body.V)
    result.info.update(offset=float(offset), fix_penetration=bool(fix))
    result.V, result.penetrating_vertices, result.obstacle, result.surface = fit_to_body(
        V, prepared, target_body, offset, fix_penetration=fix, resolve_crossings=resolve,
        source_V=None if back is None else back.apply(garment.V), info=result.info, seconds=result.seconds,
        step=None if progress is None else (lambda f, stage: progress(0.9 + 0.5 * (f - 0.8), stage)), early=early)
    result.seconds["target_fit"] = time.perf_counter() - t
    result.seconds["total"] += result.seconds["target_fit"]
    return result
