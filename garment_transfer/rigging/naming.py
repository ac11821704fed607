"""Skeletons named otherwise: the same body's joints under the names of the rigs artists use.

A character made in another tool has its own skeleton: Mixamo's (``mixamorig:LeftArm``), Rigify's
(``DEF-upper_arm.L``, or the metarig's ``upper_arm.L``), Unreal's mannequin (``upperarm_l``; MPFB's game-engine
rig), MakeHuman's default (``upperarm01.L``). Their bones differ in number (MakeHuman's spine has five bones,
Mixamo's three) but they share the joints a body bends at: the pelvis, the base of the neck and of the head, each
shoulder, elbow, wrist, hip, knee and ankle, the ball of each foot, each finger's first and third knuckle. Those
are the *landmarks* here, each a bone's head (or tail) in every naming.

To pose a body into a target's rest pose when the two skeletons are named otherwise, ``pose_to_landmarks`` turns
the body's skeleton so that each segment between two landmarks (the upper arm from the shoulder to the elbow, the
spine from the pelvis to the neck) points as the target's does, and bends as the target's where both have joints
between its ends (a spine); the pelvis takes the turn of the frame of the hips and the spine's lowest part. What
the landmarks do not tell stays as the body has it: a finger's last joint, the toes, how a segment without joints
between its ends bends, and how far a bone turned about itself (the twist: from the target body where it is the
source's mesh, ``twist_from_body``). Built on ``skeleton`` and ``posing``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import RigError
from .posing import Rig, _swing
from .skeleton import read_json, joints_from_dict, point_of

SIDES = {"L": ("Left", "l"), "R": ("Right", "r")}


def _sided(table):
    """A naming's landmarks ``{landmark: (bone, end)}``, the sided ones written once with ``{s}`` and ``{side}``
    (``L``/``R``: MakeHuman's and Rigify's) or ``{Side}`` (``Left``/``Right``: Mixamo's) or ``{lr}`` (``l``/``r``:
    Unreal's)."""
    out = {}
    for landmark, (bone, end) in table.items():
        if "{s}" in landmark:
            for s, (side, lr) in SIDES.items():
                out[landmark.format(s=s)] = (bone.format(side=s, Side=side, lr=lr), end)
        else:
            out[landmark] = (bone, end)
    return out


#: Each naming's landmarks: the bone whose head (or tail) is there. Names compare without a namespace and case
#: (``bone_key``).
NAMINGS = {
    "MakeHuman": _sided({
        "pelvis": ("spine05", "head"), "neck": ("neck01", "head"), "head": ("head", "head"),
        "head top": ("head", "tail"), "clavicle.{s}": ("clavicle.{side}", "head"),
        "shoulder.{s}": ("upperarm01.{side}", "head"), "elbow.{s}": ("lowerarm01.{side}", "head"),
        "wrist.{s}": ("wrist.{side}", "head"), "hand.{s}": ("finger3-1.{side}", "head"),
        "hip.{s}": ("upperleg01.{side}", "head"), "knee.{s}": ("lowerleg01.{side}", "head"),
        "ankle.{s}": ("foot.{side}", "head"), "ball.{s}": ("toe3-1.{side}", "head")}),
    "Mixamo": _sided({
        "pelvis": ("Hips", "head"), "neck": ("Neck", "head"), "head": ("Head", "head"),
        "head top": ("HeadTop_End", "head"), "clavicle.{s}": ("{Side}Shoulder", "head"),
        "shoulder.{s}": ("{Side}Arm", "head"), "elbow.{s}": ("{Side}ForeArm", "head"),
        "wrist.{s}": ("{Side}Hand", "head"), "hand.{s}": ("{Side}HandMiddle1", "head"),
        "hip.{s}": ("{Side}UpLeg", "head"), "knee.{s}": ("{Side}Leg", "head"),
        "ankle.{s}": ("{Side}Foot", "head"), "ball.{s}": ("{Side}ToeBase", "head")}),
    "Rigify": _sided({
        "pelvis": ("DEF-spine", "head"), "neck": ("DEF-spine.004", "head"), "head": ("DEF-spine.006", "head"),
        "head top": ("DEF-spine.006", "tail"), "clavicle.{s}": ("DEF-shoulder.{side}", "head"),
        "shoulder.{s}": ("DEF-upper_arm.{side}", "head"), "elbow.{s}": ("DEF-forearm.{side}", "head"),
        "wrist.{s}": ("DEF-hand.{side}", "head"), "hand.{s}": ("DEF-f_middle.01.{side}", "head"),
        "hip.{s}": ("DEF-thigh.{side}", "head"), "knee.{s}": ("DEF-shin.{side}", "head"),
        "ankle.{s}": ("DEF-foot.{side}", "head"), "ball.{s}": ("DEF-toe.{side}", "head")}),
    "Rigify metarig": _sided({
        "pelvis": ("spine", "head"), "neck": ("spine.004", "head"), "head": ("spine.006", "head"),
        "head top": ("spine.006", "tail"), "clavicle.{s}": ("shoulder.{side}", "head"),
        "shoulder.{s}": ("upper_arm.{side}", "head"), "elbow.{s}": ("forearm.{side}", "head"),
        "wrist.{s}": ("hand.{side}", "head"), "hand.{s}": ("f_middle.01.{side}", "head"),
        "hip.{s}": ("thigh.{side}", "head"), "knee.{s}": ("shin.{side}", "head"),
        "ankle.{s}": ("foot.{side}", "head"), "ball.{s}": ("toe.{side}", "head")}),
    "Unreal": _sided({
        "pelvis": ("pelvis", "head"), "neck": ("neck_01", "head"), "head": ("head", "head"),
        "clavicle.{s}": ("clavicle_{lr}", "head"), "shoulder.{s}": ("upperarm_{lr}", "head"),
        "elbow.{s}": ("lowerarm_{lr}", "head"), "wrist.{s}": ("hand_{lr}", "head"),
        "hand.{s}": ("middle_01_{lr}", "head"), "hip.{s}": ("thigh_{lr}", "head"),
        "knee.{s}": ("calf_{lr}", "head"), "ankle.{s}": ("foot_{lr}", "head"), "ball.{s}": ("ball_{lr}", "head")}),
}

#: The fingers, from the thumb, and each naming's bone of a finger's phalanx (1 to 3) on a side ("L", "R").
FINGERS = ("thumb", "index", "middle", "ring", "pinky")
PHALANX = {
    "MakeHuman": lambda f, k, s: f"finger{FINGERS.index(f) + 1}-{k}.{s}",
    "Mixamo": lambda f, k, s: f"{SIDES[s][0]}Hand{f.capitalize()}{k}",
    "Rigify": lambda f, k, s: f"DEF-{'thumb' if f == 'thumb' else 'f_' + f}.0{k}.{s}",
    "Rigify metarig": lambda f, k, s: f"{'thumb' if f == 'thumb' else 'f_' + f}.0{k}.{s}",
    "Unreal": lambda f, k, s: f"{f}_0{k}_{SIDES[s][1]}",
}


def _fingers(naming):
    """A naming's landmarks of the fingers: each finger's first and third phalanx's heads (its knuckles; a last
    phalanx's tail is arbitrary in files from other tools)."""
    return {f"{f} {where}.{s}": (PHALANX[naming](f, k, s), "head")
            for f in FINGERS for s in SIDES for where, k in (("base", 1), ("end", 3))}


NAMINGS = {naming: {**table, **_fingers(naming)} for naming, table in NAMINGS.items()}

#: The landmarks a skeleton must have for its naming to be recognised (the rest are used where both have them).
REQUIRED = ("pelvis", "neck", "head") + tuple(f"{j}.{s}" for j in ("shoulder", "elbow", "wrist", "hip", "knee",
                                                                   "ankle") for s in SIDES)

#: The segments posed, from the trunk out: each from its first landmark (a bone's head) to its second.
SEGMENTS = (("pelvis", "neck"), ("neck", "head"), ("head", "head top")) + tuple(
    (a.format(s=s), b.format(s=s)) for s in SIDES for a, b in (
        ("clavicle.{s}", "shoulder.{s}"), ("shoulder.{s}", "elbow.{s}"), ("elbow.{s}", "wrist.{s}"),
        ("wrist.{s}", "hand.{s}"), ("hip.{s}", "knee.{s}"), ("knee.{s}", "ankle.{s}"), ("ankle.{s}", "ball.{s}"))) + \
    tuple((f"{f} base.{s}", f"{f} end.{s}") for s in SIDES for f in FINGERS)


def bone_key(name):
    """A bone's name without a namespace (``mixamorig:``, ``character1:``, ``Armature|``, as FBX files from other
    tools carry them) and in lower case: the same skeleton's bones have the same key."""
    return str(name).replace("|", ":").rsplit(":", 1)[-1].lower()


def naming_of(names):
    """The naming (a key of ``NAMINGS``) whose required landmarks' bones are all among ``names``, or None.

    Parameters
    ----------
    names : iterable of str
        A skeleton's bone names (with or without a namespace).
    """
    keys = {bone_key(n) for n in names}
    for naming, table in NAMINGS.items():
        if all(bone_key(table[m][0]) in keys for m in REQUIRED):
            return naming
    return None


@dataclass(frozen=True)
class Landmarks:
    """A skeleton's landmarks, where its bones are.

    Attributes
    ----------
    naming : str
        Its naming (a key of ``NAMINGS``).
    points : dict of str to (3,) float64
        Each landmark whose bone it has.
    chains : dict of (str, str) to (k,3) float64
        Each segment of ``SEGMENTS`` it has: the joints from its first landmark to its second, through the heads
        of the bones between (the spine's joints between the pelvis and the neck).
    bones : dict of (str, str) to list of str
        Each segment's bones, from the first landmark's on (the bones whose heads ``chains`` passes through).
    """

    naming: str
    points: dict
    chains: dict
    bones: dict


def landmarks_of(bones, name="skeleton"):
    """A skeleton's landmarks and the joints between them.

    Parameters
    ----------
    bones : dict of str to (parent, (3,) head, (3,) tail)
        The skeleton's bones (names with or without a namespace; a root's parent None).
    name : str
        The skeleton (an armature, a file), for the error.

    Returns
    -------
    Landmarks

    Raises
    ------
    RigError
        Naming the skeleton, where it is named in none of the ways of ``NAMINGS``.
    """
    naming = naming_of(bones)
    if naming is None:
        raise RigError(name, "has bones named in none of the ways known (" + ", ".join(NAMINGS) + "): its "
                             "pelvis, neck, head, shoulders, elbows, wrists, hips, knees and ankles are not found")
    by_key = {bone_key(n): n for n in bones}
    table = NAMINGS[naming]
    points = {}
    for m, (bone, end) in table.items():
        b = by_key.get(bone_key(bone))
        if b is not None:
            points[m] = np.asarray(bones[b][1 if end == "head" else 2], dtype=np.float64)
    chains, members = {}, {}
    for a, b in SEGMENTS:
        if a not in points or b not in points or table[a][1] != "head":
            continue
        first, last = by_key[bone_key(table[a][0])], by_key[bone_key(table[b][0])]
        # From the second landmark's bone (its tail: that bone too) up to the first's.
        path = [last] if table[b][1] == "tail" else []
        k = bones[last][0]
        while path[-1:] != [first] and k is not None and k in bones and len(path) <= len(bones):
            path.append(k)
            k = bones[k][0]
        if path[-1:] != [first]:
            # Bones without their parents (a file of heads and tails): the segment from end to end.
            path = [first]
        path.reverse()
        chains[(a, b)] = np.array([np.asarray(bones[p][1], dtype=np.float64) for p in path] + [points[b]])
        members[(a, b)] = path
    return Landmarks(naming, points, chains, members)


def skeleton_bones(skeleton, joints):
    """A skeleton's bones as ``{name: (parent, head, tail)}`` on a body whose joints are ``joints`` (for
    ``landmarks_of``)."""
    heads, tails = skeleton.rest(joints)
    names = skeleton.names
    return {b: (names[p] if p >= 0 else None, heads[i], tails[i]) for i, (b, p) in
            enumerate(zip(names, skeleton.parents))}


def _trunk_frame(points):
    """The frame (3,3) of the hips and the spine: X from the right hip to the left, Y from the pelvis towards
    ``points["neck"]`` (the neck, or a point lower on the spine) across X, Z the third axis; None where either has no
    length."""
    x = points["hip.L"] - points["hip.R"]
    y = points["neck"] - points["pelvis"]
    if min(np.linalg.norm(x), np.linalg.norm(y)) <= 0:
        return None
    x = x / np.linalg.norm(x)
    y = y - (y @ x) * x
    if np.linalg.norm(y) <= 1e-9 * max(np.linalg.norm(points["neck"] - points["pelvis"]), 1e-300):
        return None
    y = y / np.linalg.norm(y)
    return np.stack([x, y, np.cross(x, y)], axis=1)


def _cut(P, Q):
    """Points along the polyline ``P`` (m,3), from its start to its end, as far apart one from the next as the
    joints of ``Q`` (k,3) are, scaled by the two ends' distances: where ``Q`` is ``P`` moved rigidly and cut at some
    of its points, those points (the first such point along ``P`` each time; the end is ``P``'s end).

    Returns
    -------
    points : (k,3) float64
    shares : (k,) float64
        Their shares of ``P``'s length, from its start.
    """
    step = np.linalg.norm(np.diff(P, axis=0), axis=1)
    before = np.concatenate([[0.0], np.cumsum(step)])
    scale = np.linalg.norm(P[-1] - P[0]) / max(np.linalg.norm(Q[-1] - Q[0]), 1e-300)
    points, shares, at, seg, t = [P[0]], [0.0], P[0], 0, 0.0
    for length in np.linalg.norm(np.diff(Q, axis=0), axis=1)[:-1] * scale:
        # The first point after (seg, t) at ``length`` from ``at``: |a + u (b - a) - at| = length, u >= t.
        while seg < len(P) - 1:
            a, d = P[seg], P[seg + 1] - P[seg]
            A, B, C = d @ d, 2.0 * d @ (a - at), (a - at) @ (a - at) - length ** 2
            root = B * B - 4.0 * A * C
            u = (-B + np.sqrt(root)) / (2.0 * A) if A > 0 and root >= 0 else -1.0
            if t <= u <= 1.0:
                t, at = u, a + u * d
                break
            seg, t = seg + 1, 0.0
        else:
            at, t = P[-1], 1.0
        points.append(at)
        shares.append(before[min(seg, len(step) - 1)] + t * step[min(seg, len(step) - 1)])
    points.append(P[-1])
    shares.append(before[-1])
    return np.array(points), np.array(shares) / max(before[-1], 1e-300)


def _bent_turns(bones, P, Q, above):
    """The turns ``{bone: (own direction, target direction)}`` of a segment whose bones (``P``: its joints at rest)
    and the target's joints (``Q``) differ in number: the segment turned as one onto the target's ends first
    (``above``: the turn of the bone it hangs from), then each bone by how the target's part it lies in bends
    compared with the same part of the rig's segment at rest (both cut at the target's joints), then the whole
    turned again so that its end points along the target's."""
    whole = _swing(above @ (P[-1] - P[0]), Q[-1] - Q[0]) @ above
    cut, cut_shares = _cut(P, Q)
    parts = [_swing(whole @ (cut[j + 1] - cut[j]), Q[j + 1] - Q[j]) for j in range(len(Q) - 1)]
    at = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))])
    middle = (at[:-1] + at[1:]) / (2.0 * max(at[-1], 1e-300))
    part_of = np.clip(np.searchsorted(cut_shares, middle, side="right") - 1, 0, len(parts) - 1)
    D = np.array([parts[part_of[m]] @ whole @ (P[m + 1] - P[m]) for m in range(len(bones))])
    end = _swing(D.sum(axis=0), Q[-1] - Q[0])
    return {b: (P[m + 1] - P[m], end @ D[m]) for m, b in enumerate(bones) if np.linalg.norm(D[m]) > 0}


def pose_to_landmarks(rig: Rig, target: Landmarks, name="target"):
    """The rig's joints posed so that its skeleton takes the pose of a skeleton named otherwise, by landmarks.

    The pelvis takes the turn of the frame of the hips and the spine (its lowest part where both spines have
    joints between the pelvis and the neck, else the whole); each segment then turns by the smallest turn that
    points it along the target's: bone by bone where the target has as many joints in it; where both have joints
    between its ends but not as many (MakeHuman's spine of five bones, Mixamo's of three), as one onto the target's
    ends, then each bone by how the target's part it lies in bends compared with the same part of the rig's segment
    (both cut at the target's joints, as far apart: ``_cut``), the end kept on the target's; else as one, by its
    first bone. A pose of the rig itself whose segments turn as wholes is found exactly, whatever the naming.

    Parameters
    ----------
    rig : Rig
        The body to pose; its skeleton's naming must be recognised (``naming_of``).
    target : Landmarks
        The target's (``landmarks_of``), in the target's rest pose.
    name : str
        The target (its armature or file), for messages.

    Returns
    -------
    joints : dict of str to (3,) float64
        Every joint of the rig's skeleton in the target's pose (its own bone lengths), its pelvis on the target's:
        the target joints ``matching_rotations`` and ``twist_from_body`` take.
    segments : dict of (str, str) to list of str
        The segments posed (both skeletons have them), each with the rig's bones in it.
    """
    skeleton = rig.skeleton
    own = landmarks_of(skeleton_bones(skeleton, rig.joints), skeleton.name)
    missing = [m for m in REQUIRED if m not in target.points]
    if missing:
        raise RigError(name, f"lacks the landmarks {', '.join(missing[:4])}: its skeleton must have a bone at "
                             "the pelvis, the neck, the head, each shoulder, elbow, wrist, hip, knee and ankle")
    index = {b: i for i, b in enumerate(skeleton.names)}
    turns, bent, used = {}, {}, {}
    for segment, P in own.chains.items():
        Q = target.chains.get(segment)
        if Q is None:
            continue
        step = np.linalg.norm(np.diff(P, axis=0), axis=1)
        if step.sum() <= 0 or np.linalg.norm(Q[-1] - Q[0]) <= 0:
            continue
        if len(Q) == len(P):
            # As many joints: each bone along the target's.
            for k, bone in enumerate(own.bones[segment]):
                if step[k] > 0 and np.linalg.norm(Q[k + 1] - Q[k]) > 0:
                    turns[index[bone]] = (P[k + 1] - P[k], Q[k + 1] - Q[k])
        elif len(P) > 2 and len(Q) > 2:
            # Joints between the ends on both, fewer or more on the target's (a spine): bent where they are.
            bent[index[own.bones[segment][0]]] = ([index[b] for b in own.bones[segment]], P, Q)
        else:
            # Otherwise the segment turns as one, by its first bone, from its ends.
            turns[index[own.bones[segment][0]]] = (P[-1] - P[0], Q[-1] - Q[0])
        used[segment] = own.bones[segment]
    up = ("pelvis", "neck")
    if up in own.chains and up in target.chains and len(target.chains[up]) > 2 and len(own.chains[up]) > 2:
        # The pelvis turns with the spine's lowest part: the target's first spine joint, and the point as far up
        # the rig's spine.
        low = target.chains[up][1]
        own_low = _cut(own.chains[up], target.chains[up])[0][1]
        F_own = _trunk_frame(dict(own.points, neck=own_low))
        F_target = _trunk_frame(dict(target.points, neck=low))
    else:
        F_own, F_target = _trunk_frame(own.points), _trunk_frame(target.points)
    if F_own is None or F_target is None:
        raise RigError(name if F_target is None else skeleton.name,
                       "has its hips or its neck at one point: its trunk's turn is not defined")
    trunk = F_target @ F_own.T
    G = np.empty((skeleton.n_bones, 3, 3))
    R = np.empty_like(G)
    for k, parent in enumerate(skeleton.parents):
        above = trunk if parent < 0 else G[parent]
        if k in bent:
            turns.update(_bent_turns(*bent[k], above))
        G[k] = above if k not in turns else _swing(above @ turns[k][0], turns[k][1]) @ above
        R[k] = G[k] if parent < 0 else G[parent].T @ G[k]
    joints = rig.posed_joints(rig.transforms(R))
    # The pelvis is required, so its segment to the neck is always there (from end to end at least).
    shift = target.points["pelvis"] - joints[skeleton.heads[index[own.bones[("pelvis", "neck")][0]]]]
    return {j: p + shift for j, p in joints.items()}, used


def bones_from_dict(data, name="bones"):
    """A posed skeleton's bones from ``{"bones": {bone: {"parent": bone or null, "head": [x, y, z], "tail": [x, y,
    z]}}}`` (an armature's bones where they stand, whatever its naming) as ``{bone: (parent, head, tail)}``."""
    bones = data.get("bones") if isinstance(data, dict) else None
    if not isinstance(bones, dict) or not bones:
        raise RigError(name, "has no \"bones\": a mapping of bone name to its parent, head and tail")
    out = {}
    for bone, spec in bones.items():
        ends = []
        for end in ("head", "tail"):
            value = spec.get(end) if isinstance(spec, dict) else None
            p = point_of(value)
            if p is None:
                raise RigError(name, f"bone {bone!r}: its {end} is not three finite numbers: {value!r}")
            ends.append(p)
        parent = spec.get("parent")
        if parent is not None and parent not in bones:
            raise RigError(name, f"bone {bone!r} has parent {parent!r}, which is not a bone")
        out[bone] = (parent, ends[0], ends[1])
    return out


def frames_from_dict(data, skeleton, name="bones"):
    """The target's bone frames from a bones file of ``skeleton``'s own bones that gives each its roll, as
    ``"z_axis": [x, y, z]`` beside its head and tail (the bone's Z axis in the body's space: Blender's bone matrix's
    third column): each frame's columns are X = Y x Z, Y (head to tail) and Z (the axis made square to Y), as
    ``skeleton.bone_frames`` has them. With them the source is turned about each bone exactly as the target is
    (``transfer_across_rest_poses``'s ``target_frames``), which joints alone do not say.

    Returns
    -------
    frames : (b,3,3) float64 or None
        None when the file has no bone with a ``z_axis``, or is not of ``skeleton``'s own bones (a skeleton named
        otherwise: its frames are not the source's bones').

    Raises
    ------
    RigError
        Naming the file and the bone: some bones have a ``z_axis`` and others not, or one is not three finite numbers
        or lies along its bone.
    """
    bones = data.get("bones") if isinstance(data, dict) else None
    if not isinstance(bones, dict):
        return None
    given = {bone_key(b): spec for b, spec in bones.items() if isinstance(spec, dict)}
    if not all(bone_key(b) in given for b in skeleton.names) or not any(
            "z_axis" in given[bone_key(b)] for b in skeleton.names):
        return None
    frames = np.tile(np.eye(3), (skeleton.n_bones, 1, 1))
    for i, b in enumerate(skeleton.names):
        spec = given[bone_key(b)]
        if "z_axis" not in spec:
            raise RigError(name, f"bone {b!r} has no z_axis where others have one: give every bone's z_axis (its "
                                 "roll) or none")
        z = point_of(spec["z_axis"])
        head, tail = point_of(spec.get("head")), point_of(spec.get("tail"))
        if z is None or head is None or tail is None:
            raise RigError(name, f"bone {b!r}: its z_axis, head and tail must be three finite numbers each")
        y = tail - head
        if np.linalg.norm(y) == 0.0:
            continue
        y = y / np.linalg.norm(y)
        z = z - (z @ y) * y
        if np.linalg.norm(z) <= 1e-6 * max(np.linalg.norm(spec["z_axis"]), 1e-300):
            raise RigError(name, f"bone {b!r}: its z_axis lies along the bone, so it does not say its roll")
        z = z / np.linalg.norm(z)
        frames[i] = np.stack([np.cross(y, z), y, z], axis=1)
    return frames


def read_target_frames(path, skeleton):
    """``frames_from_dict`` of a target's joints file (``read_target_skeleton``'s): the target's bone frames where it
    is a bones file of ``skeleton``'s own bones with each bone's ``z_axis``, else None."""
    return frames_from_dict(read_json(path), skeleton, str(path))


def read_target_skeleton(path, skeleton, what="the target's joints"):
    """A target's skeleton as it stands: the joints of ``skeleton`` (a joints file, ``read_joints``, or a bones file
    of ``skeleton``'s own bones, ``bones_from_dict``), or, from a bones file of a skeleton named otherwise (Mixamo's,
    Rigify's, Unreal's), its ``Landmarks``. Either is the ``target_joints`` of ``transfer_across_rest_poses``.

    Raises
    ------
    RigError
        Naming the file: neither the skeleton's joints nor the bones of a naming that is known.
    """
    data = read_json(path)
    if isinstance(data, dict) and isinstance(data.get("bones"), dict) and any(
            isinstance(v, dict) and isinstance(v.get("head"), list) for v in data["bones"].values()):
        bones = bones_from_dict(data, str(path))
        by_key = {bone_key(b): v for b, v in bones.items()}
        if all(bone_key(b) in by_key for b in skeleton.names):
            # The skeleton's own bones: its joints, matched by name as a joints file is.
            joints = {}
            for b, head, tail in zip(skeleton.names, skeleton.heads, skeleton.tails):
                joints.setdefault(head, by_key[bone_key(b)][1])
                joints.setdefault(tail, by_key[bone_key(b)][2])
            if not skeleton.missing_joints(joints):
                return joints
        return landmarks_of(bones, str(path))
    return joints_from_dict(data, str(path), skeleton, what)
