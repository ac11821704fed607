"""A body posed by its skeleton: BVH rotations applied with the body's own joints, and a skeleton posed to
match another's rest pose.

A BVH file's joints are the skeleton's bones; their rotations are relative to rest frames aligned with the
file's axes, so they apply to any body of the skeleton with that body's own joint positions as the bones'
offsets (``bvh_rotations``, ``skinning.pose_transforms``). ``matching_rotations`` finds the rotations that take
one body's skeleton into another's pose (bones with the same names, each bone's frame from its joints and roll
plane).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import RigError
from .bvh import Motion, axes_between
from .skeleton import Skeleton, bone_frames, skeleton_from_dict
from .skinning import SkinWeights, deforming, group_transforms, pose_transforms, skin


@dataclass
class Rig:
    """A skeleton placed on one body, with the body's weights.

    Attributes
    ----------
    skeleton : Skeleton
    joints : dict of str to (3,) float64
        The joints on this body.
    weights : SkinWeights
        The body's weights (only the groups that are bones are used to pose it).
    frames : (b,3,3) float64, optional
        The bones' rest frames on this body (columns X, Y along the bone, Z), where an armature gives them (its
        bones' rolls); by default they are made from the joints and the skeleton's roll planes (``bone_frames``).
    """

    skeleton: Skeleton
    joints: dict
    weights: SkinWeights
    frames: np.ndarray | None = None

    def rest(self):
        """(heads, tails), each (b,3) float64."""
        return self.skeleton.rest(self.joints)

    def rest_frames(self):
        """(b,3,3) float64: the bones' rest frames (``frames``, else ``bone_frames``)."""
        if self.frames is not None:
            return np.asarray(self.frames, dtype=np.float64)
        return bone_frames(self.skeleton, self.joints)

    def transforms(self, rotations, root_position=None):
        """(b,3,4) skinning transforms for local rotations (b,3,3) (``skinning.pose_transforms``)."""
        return pose_transforms(self.skeleton, self.rest()[0], rotations, root_position)

    def pose(self, V, T, weights: SkinWeights | None = None):
        """Vertices ``V`` (n,3) skinned by transforms ``T`` (b,3,4) with ``weights`` (default the body's).

        Returns
        -------
        (n,3) float64
        """
        w = deforming(weights if weights is not None else self.weights, self.skeleton)
        return skin(V, w, group_transforms(w, self.skeleton, T))

    def posed_frames(self, T):
        """(b,3,3) the bones' frames (``bone_frames``) turned by the transforms ``T`` (b,3,4): an armature's
        bones in the pose."""
        return np.einsum("bij,bjk->bik", T[:, :, :3], self.rest_frames())

    def posed_joints(self, T):
        """Every joint moved by the bones that own it (as a head first, else as a tail), with the
        transforms ``T`` (b,3,4); the skeleton on the posed body."""
        heads, tails = self.rest()
        out = {}
        for ends, points in ((self.skeleton.tails, tails), (self.skeleton.heads, heads)):
            for b, joint in enumerate(ends):
                out[joint] = T[b, :, :3] @ points[b] + T[b, :, 3]
        for joint, p in self.joints.items():
            out.setdefault(joint, np.asarray(p, dtype=np.float64))
        return out


def rig_from_bones(bones, weights: SkinWeights, name="armature") -> Rig:
    """A Rig from an armature's bones, placed on its body: each bone's head and tail become its own two joints,
    and its frame (its roll) is kept, so the rig poses and is matched by the bones' frames, not by roll planes.

    Parameters
    ----------
    bones : dict of str to (parent, head, tail, frame)
        Each bone's parent's name (None for a root), head and tail (3,) and rest frame (3,3) (columns X, Y along
        the bone, Z: Blender's bone matrix), in the body's space.
    weights : SkinWeights
        The body's weights, groups named as the bones.
    name : str
        The armature's name, for messages.

    Returns
    -------
    Rig
        Its skeleton's joints are named ``"<bone> head"`` and ``"<bone> tail"``.
    """
    skeleton = skeleton_from_dict({"bones": {b: {"parent": parent, "head": f"{b} head", "tail": f"{b} tail"}
                                             for b, (parent, *_) in bones.items()}}, name)
    joints = {}
    for b, (_, head, tail, _) in bones.items():
        joints[f"{b} head"] = np.asarray(head, dtype=np.float64)
        joints[f"{b} tail"] = np.asarray(tail, dtype=np.float64)
    frames = np.array([bones[b][3] for b in skeleton.names], dtype=np.float64).reshape(-1, 3, 3)
    return Rig(skeleton, joints, weights, frames)


def bvh_rotations(motion: Motion, skeleton: Skeleton, frame=0, file_up="Z", body_up="Y"):
    """Each bone's local rotation at a frame of a BVH file, in the body's axes.

    Parameters
    ----------
    motion : Motion
        Its joints named as the skeleton's bones, each with the skeleton's parent; bones the file lacks stay
        at rest.
    skeleton : Skeleton
    frame : int
    file_up, body_up : {"Y", "Z"}
        The up axes of the file and of the body (MakeHuman: Z and Y).

    Returns
    -------
    R : (b,3,3) float64
    """
    index = {name: i for i, name in enumerate(skeleton.names)}
    unknown = [j for j in motion.names if j not in index]
    if unknown:
        raise RigError(motion.name, f"has joints that are not bones of {skeleton.name}: {', '.join(unknown[:5])}")
    for j, name in enumerate(motion.names):
        parent = motion.names[motion.parents[j]] if motion.parents[j] >= 0 else None
        own = skeleton.parents[index[name]]
        if parent != (skeleton.names[own] if own >= 0 else None):
            raise RigError(motion.name, f"joint {name} hangs from {parent}; in {skeleton.name} its parent is "
                                        f"{skeleton.names[own] if own >= 0 else 'none'}")
    M = axes_between(file_up, body_up)
    R = np.tile(np.eye(3), (skeleton.n_bones, 1, 1))
    local = motion.rotations(frame)
    R[[index[j] for j in motion.names]] = np.einsum("ij,njk,lk->nil", M, local, M)
    return R


def matching_rotations(skeleton: Skeleton, joints, target_joints, target_frames=None, frames=None):
    """The local rotations that pose a body's skeleton (``joints``) into another's pose (``target_joints``).

    Each bone takes the turn ``G_b`` that best carries what it moves rigidly (its tail and its children's heads,
    from its head) onto the target's (Kabsch). Where those all lie on the bone's line, it takes its parent's
    turn followed by the smallest turn that points the bone along the target's (a root: the turn of its frame,
    ``bone_frames``, onto the target's, ``G_b = F_target F_own^T``). Its rotation relative to its parent is
    ``G_parent^T G_b``. Bones of no length follow their parent. A pose made by ``pose_transforms`` is found
    again exactly, joints and turns, wherever a bone carries points off its line.

    Joints alone do not say how far a bone turned about itself (a forearm's twist moves no joint). The target's
    bone frames say it: with ``target_frames`` (an armature's bones, posed), ``G_b = F_target F_own^T`` for
    every bone, exactly the pose's turns when the target is this skeleton posed (``Rig.posed_frames``).

    Parameters
    ----------
    skeleton : Skeleton
    joints, target_joints : dict of str to (3,) float
        The joints on the body to pose and on the body whose pose it takes (the same skeleton's joints).
    target_frames : (b,3,3) float, optional
        The target's bone frames (columns X, Y along the bone, Z), when known.
    frames : (b,3,3) float, optional
        The body's own bone frames at ``joints`` (``Rig.frames``), when known; else ``bone_frames``.

    Returns
    -------
    R : (b,3,3) float64
    angles : (b,) float64
        Each bone's global turn, in degrees (how far the two poses differ there).
    """
    own = bone_frames(skeleton, joints) if frames is None else np.asarray(frames, dtype=np.float64)
    if target_frames is not None:
        G = np.einsum("bij,bkj->bik", np.asarray(target_frames, dtype=np.float64), own)
        R = np.array([G[b] if p < 0 else G[p].T @ G[b] for b, p in enumerate(skeleton.parents)])
        cos = np.clip((np.einsum("bii->b", G) - 1.0) / 2.0, -1.0, 1.0)
        return R, np.degrees(np.arccos(cos))
    target = bone_frames(skeleton, target_joints)
    heads, tails = skeleton.rest(joints)
    heads_t, tails_t = skeleton.rest(target_joints)
    length = np.linalg.norm(tails - heads, axis=1)
    scale = max(float(np.ptp(heads, axis=0).max()), 1e-300)
    G = np.einsum("bij,bkj->bik", target, own)
    children = [[] for _ in range(skeleton.n_bones)]
    for b, parent in enumerate(skeleton.parents):
        if parent >= 0:
            children[parent].append(b)
    R = np.empty_like(G)
    for b, parent in enumerate(skeleton.parents):
        if length[b] <= 0:
            G[b] = G[parent] if parent >= 0 else np.eye(3)
        else:
            # A bone whose points all lie on its line is turned as little as it can be from its parent's turn
            # (its frame's, for a root): a plane through a child's joints would turn with the child's bend.
            own_turn = G[b] if parent < 0 else _swing(G[parent] @ (tails[b] - heads[b]),
                                                      tails_t[b] - heads_t[b]) @ G[parent]
            a = np.vstack([tails[b], heads[children[b]]]) - heads[b]
            c = np.vstack([tails_t[b], heads_t[children[b]]]) - heads_t[b]
            G[b] = _turn(a, c, own_turn, 1e-3 * scale)
        R[b] = G[b] if parent < 0 else G[parent].T @ G[b]
    cos = np.clip((np.einsum("bii->b", G) - 1.0) / 2.0, -1.0, 1.0)
    return R, np.degrees(np.arccos(cos))


#: A bone's twist is measured on the vertices it moves by at least this share of their weight ...
TWIST_WEIGHT = 0.3
#: ... where it has at least this many of them; a bone with fewer keeps the smallest turn from its parent's.
TWIST_VERTICES = 8
#: Rounds of the twists' fit (the vertices two bones share settle in a few: 4.8, 0.70, 0.22, 0.13, 0.10 mm on run01).
TWIST_ROUNDS = 4


def twist_from_body(rig: Rig, rotations, body_V, target_joints, target_V, rounds=TWIST_ROUNDS, free=None):
    """``matching_rotations``'s turns with each bone's turn about itself measured on the target body.

    Joints do not say how far a bone whose points lie on its line (a forearm, a shin, a spine bone with one child)
    turned about itself; the target body does, where it is this body's mesh in another shape and pose. Each such
    bone turns about the target's bone by the angle that best takes the vertices it moves (``TWIST_WEIGHT``), as
    linear blend skinning poses them, to where the target has them: a least-squares step (each vertex's
    displacement across the bone, weighted by its weight), bone by bone from the root with the turns of the others
    as they stand, ``rounds`` times. A bone with too few vertices (``TWIST_VERTICES``) takes its parent's turn
    followed by the smallest turn along the target's bone, as ``matching_rotations`` gives it; the bones whose joints
    fix their turn keep it (their turn in the world, whatever their parent's twist).

    Parameters
    ----------
    rig : Rig
        The body to pose (its skeleton, joints, weights).
    rotations : (b,3,3) float
        ``matching_rotations(rig.skeleton, rig.joints, target_joints)[0]``.
    body_V : (n,3) float
        The rig's body at rest.
    target_joints : dict of str to (3,) float
    target_V : (n,3) float
        The target body: the same mesh in the target's shape and pose.
    rounds : int
    free : (b,) bool, optional
        Bones whose turn about themselves is fitted whatever their joints say (target joints made from landmarks,
        ``naming.pose_to_landmarks``, fix no bone's twist); by default only the bones on their line.

    Returns
    -------
    R : (b,3,3) float64
    angles : (b,) float64
        Each bone's global turn, in degrees.
    """
    skeleton = rig.skeleton
    body_V = np.asarray(body_V, dtype=np.float64)
    target_V = np.asarray(target_V, dtype=np.float64)
    weights = deforming(rig.weights, skeleton).normalised()
    if not body_V.shape[0] == target_V.shape[0] == weights.n_vertices:
        raise ValueError(f"the body has {body_V.shape[0]} vertices, the target {target_V.shape[0]}, the weights "
                         f"{weights.n_vertices}: the target must be the body's own mesh")
    heads, tails = skeleton.rest(rig.joints)
    heads_t, tails_t = skeleton.rest(target_joints)
    scale = max(float(np.ptp(heads, axis=0).max()), 1e-300)
    free = np.zeros(skeleton.n_bones, bool) if free is None else np.asarray(free, dtype=bool)
    W = weights.W.tocsc()
    column = {g: k for k, g in enumerate(weights.groups)}
    children = [[] for _ in range(skeleton.n_bones)]
    for b, parent in enumerate(skeleton.parents):
        if parent >= 0:
            children[parent].append(b)
    R = np.array(rotations, dtype=np.float64)
    given = np.empty_like(R)            # the global turns of ``rotations``
    for b, parent in enumerate(skeleton.parents):
        given[b] = R[b] if parent < 0 else given[parent] @ R[b]
    # Each bone: "rest" (no length: follows its parent), "fixed" (its joints fix its turn) or a bone on its line,
    # whose twist is fitted where it moves enough vertices (``moved``: their indices and weights).
    kind, moved = [], {}
    for b in range(skeleton.n_bones):
        bone, bone_t = tails[b] - heads[b], tails_t[b] - heads_t[b]
        if min(np.linalg.norm(bone), np.linalg.norm(bone_t)) <= 1e-3 * scale:
            kind.append("rest")
        elif not free[b] and not _on_line(np.vstack([tails[b], heads[children[b]]]) - heads[b], 1e-3 * scale):
            kind.append("fixed")
        else:
            kind.append("line")
            k = column.get(skeleton.names[b])
            if k is not None:
                col = W[:, k]
                keep = col.data >= TWIST_WEIGHT
                if keep.sum() >= TWIST_VERTICES:
                    moved[b] = (col.indices[keep], col.data[keep])
    twist = np.zeros(skeleton.n_bones)
    G, out, at = np.empty_like(R), R.copy(), np.empty_like(heads)
    axes = tails_t - heads_t
    axes /= np.maximum(np.linalg.norm(axes, axis=1, keepdims=True), 1e-300)

    def turn(b):
        """Bone b's global turn ``G[b]``, local rotation ``out[b]`` and posed head ``at[b]`` (as
        ``skinning.pose_transforms`` places it), from its parent's as they stand."""
        parent = skeleton.parents[b]
        at[b] = heads[b] if parent < 0 else at[parent] + G[parent] @ (heads[b] - heads[parent])
        if kind[b] == "rest":
            G[b] = out[b] if parent < 0 else G[parent] @ out[b]
            return
        if kind[b] == "fixed" or parent < 0:
            G[b] = given[b]
        else:
            G[b] = _swing(G[parent] @ (tails[b] - heads[b]), axes[b]) @ G[parent]
        if kind[b] == "line":
            G[b] = _about(axes[b], twist[b]) @ G[b]
        out[b] = G[b] if parent < 0 else G[parent].T @ G[b]

    for b in range(skeleton.n_bones):
        turn(b)
    # Bone by bone from the root, ``rounds`` times: each bone's step with the others as they stand (its own turn and
    # its ancestors' made again first, and those of the bones below it that move its vertices; the vertices posed
    # with them), so that a bone's twist, which its bones on its line inherit, is not counted twice.
    bone_of = np.array([skeleton.names.index(g) for g in weights.groups], dtype=np.int64)
    steps = {}
    for b, (idx, w) in moved.items():
        rows = weights.W[idx].toarray()
        used = np.flatnonzero(np.abs(rows).sum(axis=0) > 0)
        # The bones after b that move its vertices, and their ancestors after b: made again before its step (a
        # parent always comes before its children).
        below = set()
        for u in bone_of[used]:
            while u > b and u not in below:
                below.add(int(u))
                u = skeleton.parents[u]
        steps[b] = (idx, w, rows[:, used], bone_of[used], sorted(below))
    for _ in range(rounds if moved else 0):
        done = 0
        for b, (idx, w, rows, bones, below) in steps.items():
            # The bones up to this one since the last step (that one too: its twist moved), and those after it.
            for j in [*range(done, b + 1), *below]:
                turn(j)
            done = b
            T = np.concatenate([G[bones], (at[bones] - np.einsum("bij,bj->bi", G[bones], heads[bones]))[:, :, None]],
                               axis=2).reshape(-1, 12)
            A = rows @ T                        # each vertex's blended transform (linear blend skinning)
            posed = np.einsum("kij,kj->ki", A.reshape(-1, 3, 4)[:, :, :3], body_V[idx]) + A[:, 3::4]
            across = np.cross(axes[b], posed - heads_t[b])
            twist[b] += float(np.einsum("i,ij,ij->", w, across, target_V[idx] - posed)
                              / max(np.einsum("i,ij,ij->", w * w, across, across), 1e-300))
    for b in range(skeleton.n_bones):
        turn(b)
    R = out
    cos = np.clip((np.einsum("bii->b", G) - 1.0) / 2.0, -1.0, 1.0)
    return R, np.degrees(np.arccos(cos))


def _on_line(points, tiny):
    """Whether the vectors ``points`` (k,3) longer than ``tiny`` lie on one line (fewer than two of them do)."""
    keep = np.linalg.norm(points, axis=1) > tiny
    if keep.sum() < 2:
        return True
    unit = points[keep] / np.linalg.norm(points[keep], axis=1, keepdims=True)
    return bool(np.linalg.svd(unit, compute_uv=False)[1] < 0.05)


def _about(axis, angle):
    """The rotation (3,3) by ``angle`` (radians) about the unit ``axis`` (3,)."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def _swing(a, b):
    """The smallest rotation (3,3) that turns the direction of ``a`` (3,) onto that of ``b`` (3,)."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    c = float(a @ b)
    if c < -1.0 + 1e-12:
        # Half a turn: about any axis across ``a``.
        axis = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    v = (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + K + K @ K / (1.0 + c)


def _turn(a, b, fallback, tiny):
    """The rotation that best takes vectors ``a`` (k,3) to ``b`` (k,3) (Kabsch), or ``fallback`` (3,3) when
    the vectors longer than ``tiny`` lie on one line (a turn about that line is then not fixed by them)."""
    keep = (np.linalg.norm(a, axis=1) > tiny) & (np.linalg.norm(b, axis=1) > tiny)
    a, b = a[keep], b[keep]
    if _on_line(a, tiny):
        return fallback
    U, _, Vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    return Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
