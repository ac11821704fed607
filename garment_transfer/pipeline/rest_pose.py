"""A target body in another rest pose than the source: the source and its garment posed first, then the shape.

The transfer carries a change of shape; a change of pose (arms lower, legs apart) is not a shape the body's
gradients and the binding carry well, and cloth ends up through the skin. When both bodies have a skeleton with
the same bone names (MakeHuman's, MPFB's), the source body is posed into the target's rest pose by its own rig
(``rigging.matching_rotations``: each bone turned onto the target's; how far it turned about itself from the
target's bone frames, or from a target of the source's own mesh, ``rigging.twist_from_body``), its garment fitted
to that pose (``pose_fit.fit_to_pose``), and the garment then transferred from the posed source to the target as
usual. An outfit is posed layer by layer and then transferred as an outfit (its layers separated on the posed
source and on the target).
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import PoseError
from ..fitting.registration import Registration
from ..geometry.mesh import Mesh, same_mesh
from ..geometry.proximity import TriangleSurface
from ..rigging.naming import Landmarks, naming_of, pose_to_landmarks
from ..rigging.posing import Rig, matching_rotations, twist_from_body
from .any_body import REGISTER_OPTIONS, registration_for, transfer_to_any_body
from .outfit import OutfitResult, transfer_outfit
from .pose_fit import body_contact, clear_posed_body, fit_to_pose, free_body, untangle_fit, untangle_result

#: Bones that carry at least this share of the body's weights say how far two rest poses differ ...
MIN_WEIGHT_SHARE = 0.01
#: ... and two rest poses whose such bones turn less than this (degrees) are one: the transfer carries it as a
#: change of shape. MakeHuman's bodies differ by up to 22 degrees in shape alone (the spine of a male body from
#: the female average); each of its shared poses turns a limb by 24 to 140 degrees.
SAME_POSE_DEGREES = 25.0
#: How far the garment was from the reference (transferred at rest, then fitted to the pose) when the target's
#: skeleton was named otherwise (``lab.rest_pose_study --named``: Mixamo's, onto the pear in MakeHuman's six shared
#: poses), said in the warning.
LANDMARK_FIGURES = "1.1-2.3 mm"
#: The same onto that body re-meshed (another mesh: posed from its joints alone), by MakeHuman's skeleton and by a
#: Mixamo skeleton's landmarks (``lab.rest_pose_study --remeshed --named``).
REMESHED_FIGURES = "4.9-17.5 mm"
REMESHED_LANDMARK_FIGURES = "4.7-23.7 mm"


def pose_difference(source_rig: Rig, target_joints, target_frames=None, source_V=None, target_V=None,
                    free=None):
    """How far the target's rest pose is from the source's: each bone's turn, in degrees.

    The turns come from the joints (``rigging.matching_rotations``); how far a bone turned about itself, which
    joints do not say, from the target's bone frames where given, else from the target body itself where it is
    the source's mesh (``source_V`` at rest and ``target_V``: ``rigging.twist_from_body``; ``free``: the bones whose
    twist the joints do not fix, whatever their children, as ``twist_from_body`` takes it).

    Returns
    -------
    rotations : (b,3,3) float64
        Each bone's local rotation that poses the source like the target.
    degrees : dict of str to float
        The turn of each bone that carries at least ``MIN_WEIGHT_SHARE`` of the body's weights.
    """
    R, angles = matching_rotations(source_rig.skeleton, source_rig.joints, target_joints, target_frames,
                                   source_rig.frames)
    if target_frames is None and source_V is not None and target_V is not None:
        R, angles = twist_from_body(source_rig, R, source_V, target_joints, target_V, free=free)
    weights = source_rig.weights.normalised()
    share = np.asarray(weights.W.sum(axis=0)).ravel() / max(weights.n_vertices, 1)
    carrying = {g for g, s in zip(weights.groups, share) if s >= MIN_WEIGHT_SHARE}
    return R, {b: float(a) for b, a in zip(source_rig.skeleton.names, angles) if b in carrying}


def posed_source(source_body: Mesh, source_rig: Rig, target_joints, target_frames, target_body: Mesh):
    """The source body posed into the target's rest pose, and how.

    ``target_joints`` is the target's joints of the source's skeleton, or, for a skeleton named otherwise
    (Mixamo's, Rigify's, Unreal's), its ``Landmarks`` (``rigging.landmarks_of``): the source's skeleton is then
    posed segment by segment onto them first (``rigging.pose_to_landmarks``), and no bone frames apply.

    Returns
    -------
    info : dict
        ``largest_turn`` (degrees) and ``largest_turn_bone``, ``posed`` (the poses differ by
        ``SAME_POSE_DEGREES`` or more), ``twist`` (how each bone's turn about itself was found: ``"frames"``, the
        target's; ``"body"``, the target being the source's mesh; ``"joints"``, not at all), ``skeletons`` (how the
        two skeletons were matched: ``{"by": "names"}``, or ``{"by": "landmarks", "target": naming, "source":
        naming, "segments": count}``) and ``warnings``.
    V : (n,3) float64 or None
        The source's positions posed, or None when the poses are one.
    """
    matched, free = {"by": "names"}, None
    if isinstance(target_joints, Landmarks):
        target = target_joints
        target_joints, segments = pose_to_landmarks(source_rig, target, target_body.name)
        target_frames = None
        matched = {"by": "landmarks", "target": target.naming, "source": naming_of(source_rig.skeleton.names),
                   "segments": len(segments)}
        # Joints made from landmarks fix no turn of a segment's bones about themselves (a head whose children lie
        # off its line included): each is measured on the body, where it is the source's mesh.
        posed = {b for bones in segments.values() for b in bones}
        free = np.array([b in posed for b in source_rig.skeleton.names])
    body = same_mesh(source_body, target_body) and source_rig.weights.n_vertices == source_body.n_vertices
    R, turns = pose_difference(source_rig, target_joints, target_frames, source_body.V if body else None,
                               target_body.V if body else None, free)
    bone = max(turns, key=turns.get)
    info = {"largest_turn": turns[bone], "largest_turn_bone": bone, "posed": turns[bone] >= SAME_POSE_DEGREES,
            "twist": "frames" if target_frames is not None else ("body" if body else "joints"),
            "skeletons": matched}
    info["warnings"] = rest_pose_warnings(info, target_body.name)
    return info, (source_rig.pose(source_body.V, source_rig.transforms(R)) if info["posed"] else None)


def rest_pose_warnings(info, name) -> list:
    """What a user must be told about how the source was posed into a target's rest pose (``info["rest_pose"]``)."""
    if not info["posed"]:
        return []
    out = []
    matched = info.get("skeletons") or {}
    if matched.get("by") == "landmarks":
        out.append(f"{name}: its {matched['target']} skeleton was matched to the source's {matched['source']} one "
                   f"by {matched['segments']} segments between the joints both have (pelvis, neck, head, shoulders, "
                   "elbows, wrists, hips, knees, ankles, knuckles): a finger's last joint, the toes, the bend of a "
                   "segment without joints between its ends stay as the source has them before the transfer "
                   "(measured with MakeHuman's shared poses taken as rest poses, onto a body of the source's mesh: "
                   f"the garment {LANDMARK_FIGURES} on average from the garment transferred at rest and fitted to the "
                   "pose, against 1.1-1.8 mm with the same skeleton). Look at the result where they matter")
    if info["twist"] == "joints":
        landmarks = matched.get("by") == "landmarks"
        out.append(f"{name}: posed from its joints alone (another mesh than the source's, without bone frames), "
                   "which do not say how far each bone turned about itself: where a limb or the spine twisted, the "
                   "garment may sit turned about it (measured onto a re-meshed body in MakeHuman's six shared poses: "
                   + (f"{REMESHED_LANDMARK_FIGURES} by a Mixamo skeleton's landmarks" if landmarks else
                      f"{REMESHED_FIGURES}")
                   + " on average from the garment transferred at rest and fitted to the pose, against 1.1-1.8 mm "
                   "with the twists known). Give "
                   + ("a target of the source's own mesh, whose shape tells the twists" if landmarks else
                      "the target's armature (Blender) or its bones with each bone's roll (a bones file with each "
                      "bone's z_axis), or a target of the source's own mesh, whose shape tells the twists"))
    return out


def fold_warnings(info, self_intersections_new, name, remedy) -> list:
    """The warning that the file crosses itself where its source does not after a transfer posed into the target's
    rest pose that was not untangled (``info``: ``info["rest_pose"]``; ``self_intersections_new``: counted on the
    file as written), naming ``remedy`` (how the caller's user asks for untangling); else none."""
    if not info.get("posed") or "untangle" in info or not self_intersections_new:
        return []
    return [f"{name}: posing the source into the target's rest pose folded the cloth through itself "
            f"({self_intersections_new} pairs its source does not have); {remedy} undoes it where it can (seconds "
            "more)"]


def untangle_text(untangle) -> str:
    """What untangling did (``info["rest_pose"]["untangle"]``), in words: each step's self-intersections its source
    does not have, before and after, and whether it was kept; "" when nothing was untangled."""
    untangle = untangle or {}
    steps = [(what, u) for what, u in (("the fit to the posed source", untangle.get("fit")),
                                       ("the result on the target", untangle.get("target"))) if u]
    text = ", ".join(f"{what} {u['self_intersections_new_before']} -> {u['self_intersections_new_after']}"
                     + ("" if u["kept"] else " (not kept)") for what, u in steps)
    if (untangle.get("fit") or {}).get("carried") is False:
        a, b = untangle["compared"]["fit"], untangle["compared"]["untangled_fit"]
        text += ("; the result from the fit as it was kept (pairs, crossings with the body away from its contact "
                 "and at it, vertices inside: " + ", ".join(f"{a[k]}" for k in a) + " against the untangled fit's "
                 + ", ".join(f"{b[k]}" for k in a) + ")")
    return text


def target_at_rest(source_body: Mesh, target_body: Mesh, registration: Registration | None):
    """Where the source at rest has each of the target's vertices, in the target's units: what tells which of the
    target's body parts its pose pressed together (``pose_fit.self_contact``'s gap rule: closer than the gap in the
    pose, apart at rest).

    A target of the source's mesh: the source's own vertices at rest. A target of another mesh (``registration``:
    the source posed into the target's rest pose, fitted onto it): each target vertex's closest point on the fitted
    copy, taken at the same place of the source's triangles at rest and into the target's frame. None without a
    registration for another mesh.
    """
    if registration is None:
        return source_body.V if source_body.n_vertices == target_body.n_vertices else None
    _, _, tri, bary = TriangleSurface(registration.V, source_body.F).closest(target_body.V)
    rest = np.einsum("pk,pkj->pj", bary, source_body.V[source_body.F[tri]])
    return registration.alignment.inverse().apply(rest)


def _fit_counts(fit):
    """The figures of the garment's fit to the posed source that ``info["rest_pose"]["pose_fit"]`` keeps."""
    return {k: fit.info[k] for k in ("crossings_outside_contact", "crossings_at_contact", "body_self_crossings")}


def transfer_across_rest_poses(source_body: Mesh, target_body: Mesh, garment: Mesh, source_rig: Rig,
                               target_joints, target_frames=None, untangle=False, **options):
    """Transfer a garment to a target body whose rest pose differs from the source's.

    Parameters
    ----------
    source_body, target_body, garment : Mesh
    source_rig : Rig
        The source body's skeleton, joints and weights.
    target_joints : dict of str to (3,) float
        The target's joints (the same skeleton's joint names), in the target's rest pose.
    target_frames : (b,3,3) float, optional
        The target's bone frames in its rest pose (an armature's bones): they fix how far each bone turned
        about itself, which the joints cannot (``rigging.matching_rotations``). Without them, a target of the
        source's own mesh tells it by its shape (``rigging.twist_from_body``); another mesh is posed by the joints.
    **options
        Passed to ``transfer_to_any_body``; ``prepared`` (the garment prepared on the source at rest) serves only
        a target in the source's pose.

    Returns
    -------
    result : TransferResult
        ``info["rest_pose"]``: ``largest_turn`` (degrees, and its bone), ``posed`` (whether the source was
        posed), ``twist`` (how each bone's turn about itself was found: ``"frames"``, ``"body"`` or, for a target of
        another mesh without frames, ``"joints"``: not known), ``warnings`` (``rest_pose_warnings``), ``pose_fit``
        (the fit's crossing counts), and, untangled, ``untangle`` (``untangle_fit``'s figures of the fit,
        ``"fit"``, and of the result on the target, ``"target"``). Where the fit's untangling was kept, the fit as
        it was is carried to the target too, and the untangled fit's result is kept only where it is no worse
        in any count (pairs the source lacks, crossings with the body away from its contact and at it, vertices
        inside), so that untangling leaves no count worse than the transfer without it:
        ``untangle["fit"]["carried"]`` says which was kept, ``untangle["compared"]`` the counts of each
        (``"untangled_fit"``, ``"fit"``).
    registration : Registration or None

    Raises
    ------
    PoseError
        The target stands in another pose and the method is a model's (trained on the source's pose).
    """
    t = time.perf_counter()
    info, posed_V = posed_source(source_body, source_rig, target_joints, target_frames, target_body)
    if not info["posed"]:
        result, registration = transfer_to_any_body(source_body, target_body, garment, **options)
        result.info["rest_pose"] = info
        result.seconds["rest_pose"] = time.perf_counter() - t - result.seconds["total"]
        result.seconds["total"] += result.seconds["rest_pose"]
        return result, registration
    if options.get("method") == "model":
        raise PoseError(target_body.name, f"stands in another pose than {source_body.name} (its "
                                          f"{info['largest_turn_bone']} turned {info['largest_turn']:.0f} degrees)",
                        "Use the direct method: a model is trained on the source's pose")
    options = {k: v for k, v in options.items() if k != "prepared"}
    clear = options.get("resolve_crossings", True) and options.get("fix_penetration", True)
    posed = source_body.with_vertices(posed_V, name=f"{source_body.name} in the target's rest pose")
    fit = fit_to_pose(source_body, posed_V, garment, name="target's rest pose",
                      offset=_on_posed_source([options.get("offset")], options, posed, target_body)[0])
    # Each fit carried to the target: (positions, counts); the fit as it was too where untangling it was kept, as the
    # untangled fit can leave the target's pass more to fold.
    fits = [(fit.V.copy(), _fit_counts(fit))]
    if untangle:
        untangle_result(fit, garment, posed)
        info["untangle"] = {"fit": fit.info["untangle"]}
        fits.insert(0, (fit.V, _fit_counts(fit)))
        if not (clear and fit.info["untangle"]["kept"]):
            fits = fits[:1]
    registration = options.pop("registration", None)
    outcomes, contact = [], None
    for V, counts in fits:
        result, registration = transfer_to_any_body(posed, target_body, garment.with_vertices(V),
                                                    registration=registration,
                                                    **dict(options, resolve_crossings=False))
        step = None
        if clear:
            # The target stands in a pose: where its body crosses or closes on itself no cloth can clear it.
            if contact is None:
                body_rest = target_at_rest(source_body, target_body, registration)
                contact = body_contact(target_body, result.info["offset"], body_rest)
            free = free_body(target_body, contact[0], garment, result.V)
            result.V, result.penetrating_vertices = clear_posed_body(
                result.V, garment, target_body, result.info, rest_V=body_rest, name=target_body.name,
                contact=contact, free=free, surface=result.surface)
            if untangle:
                result.V, result.penetrating_vertices, step = untangle_fit(
                    result.V, garment, target_body, result.info, contact[0], free, surface=result.surface,
                    inside=result.penetrating_vertices)
        outcomes.append((result, counts, step))
    result, info["pose_fit"], step = outcomes[0]
    if untangle and clear:
        info["untangle"]["target"] = step
        if len(outcomes) == 2:
            # The result from the fit as it was is, count by count, no worse than the transfer not untangled (its
            # untangling on the target is kept only so): the untangled fit's is kept only where it is no worse than
            # that one in any count.
            compared = {k: _outcome_counts(o) for k, o in zip(("untangled_fit", "fit"), outcomes)}
            info["untangle"]["compared"] = compared
            info["untangle"]["fit"]["carried"] = all(compared["untangled_fit"][k] <= compared["fit"][k]
                                                     for k in compared["fit"])
            if not info["untangle"]["fit"]["carried"]:
                result, info["pose_fit"], info["untangle"]["target"] = outcomes[1]
    result.info["rest_pose"] = info
    result.seconds["rest_pose"] = time.perf_counter() - t - result.seconds["total"]
    result.seconds["total"] += result.seconds["rest_pose"]
    return result, registration


def _on_posed_source(offsets, options, posed: Mesh, target_body: Mesh, keys=REGISTER_OPTIONS) -> list:
    """Offsets given (the target's units, as ``transfer_to_any_body`` takes them; None: the default) for fits on the
    source posed into the target's rest pose: onto a target of another mesh, the posed source is registered onto it
    first (with ``options``' ``keys``; kept in ``options["registration"]`` for the transfer) and each scaled into the
    source's units and size."""
    if all(o is None for o in offsets):
        return list(offsets)
    registration = registration_for(posed, target_body, options.get("registration"),
                                    **{k: options[k] for k in keys if k in options})
    if registration is None:
        return list(offsets)
    options["registration"] = registration
    return [None if o is None else float(o) * registration.alignment.scale for o in offsets]


def _outcome_counts(outcome) -> dict:
    """A result on the target (a result, its fit's counts, its untangling): the pairs it crosses itself at that its
    source lacks, its crossings with the body away from the body's contact and at it, its vertices inside."""
    result, _, untangled = outcome
    return {"self_intersections_new": untangled["self_intersections_new_after"],
            "crossings_outside_contact": result.info["crossings_outside_contact"],
            "crossings_at_contact": result.info["crossings_at_contact"], "inside_vertices": result.penetrating_vertices}


def outfit_across_rest_poses(source_body: Mesh, target_body: Mesh, garments, source_rig: Rig, target_joints,
                             target_frames=None, *, offsets=None, **options) -> OutfitResult:
    """Transfer an outfit to a target body whose rest pose differs from the source's.

    Each layer is fitted to the source posed into the target's rest pose (``fit_to_pose``, as for one garment),
    and the layers are then transferred as an outfit from the posed source (``transfer_outfit``: separated on the
    posed source, transferred, separated on the target from the body out). Where the posed target crosses or
    closes on itself no cloth can be outside both surfaces; the separation on the target pushes what it can.

    Parameters
    ----------
    source_body, target_body : Mesh
    garments : sequence of Mesh
        The layers on the source body, innermost first.
    source_rig, target_joints, target_frames
        As ``transfer_across_rest_poses``.
    offsets : float or sequence of (float or None), optional
        As ``transfer_outfit``.
    **options
        Passed to ``transfer_outfit``.

    Returns
    -------
    OutfitResult
        ``rest_pose``: as ``info["rest_pose"]`` of ``transfer_across_rest_poses`` (``pose_fit``: each layer's fit's
        counts).
    """
    t = time.perf_counter()
    garments = list(garments)
    info, posed_V = posed_source(source_body, source_rig, target_joints, target_frames, target_body)
    if not info["posed"]:
        result = transfer_outfit(source_body, target_body, garments, offsets=offsets, **options)
    else:
        each = [offsets] * len(garments) if offsets is None or np.isscalar(offsets) else list(offsets)
        posed = source_body.with_vertices(posed_V, name=f"{source_body.name} in the target's rest pose")
        # Offsets given are the target's: the fits keep them in the posed source's units and size (``transfer_outfit``
        # scales them so too, through the same registration).
        each = _on_posed_source(each, options, posed, target_body, keys=("cache", "limits"))
        fits = [fit_to_pose(source_body, posed_V, g, offset=o, name="target's rest pose")
                for g, o in zip(garments, each)]
        info["pose_fit"] = [_fit_counts(fit) for fit in fits]
        source_body = posed
        # Each layer's own crossing pass would run against the whole posed body, where it crosses itself too: the
        # separation on the target clears the body and the layers under each.
        result = transfer_outfit(source_body, target_body, [g.with_vertices(fit.V) for g, fit in zip(garments, fits)],
                                 offsets=offsets, **dict(options, resolve_crossings=False))
    result.rest_pose = info
    result.seconds["rest_pose"] = time.perf_counter() - t - result.seconds["total"]
    result.seconds["total"] = time.perf_counter() - t
    return result
