"""A skeleton: bones between named joints, placed on a body by that body's own joint positions.

The skeleton file (MakeHuman's ``.mhskel`` layout as JSON, e.g. the shared ``rig/skeleton.json``) names, for
every bone, its ``parent``, its ``head`` and ``tail`` joints and a ``rotation_plane``: three joints whose
plane fixes the bone's roll. A joints file (``rig/joints/<body>.json``) gives every joint's position on one
body. A bone's rest frame (``bone_frames``) is MakeHuman's: Y along the bone, Z perpendicular to the bone and
the plane's normal, X the third axis; Blender's bone roll is the same frame (``align_roll`` to Z).

Bones are kept in an order where every parent comes before its children, so posing is one pass.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from ..errors import RigError

#: Below this share of the skeleton's size a bone or a plane has no direction of its own.
DEGENERATE_SHARE = 1e-9


@dataclass(frozen=True)
class Skeleton:
    """The bones of a skeleton, parents first.

    Attributes
    ----------
    names : tuple of str
        (b,) bone names.
    parents : (b,) int64
        Index of each bone's parent, -1 for a root.
    heads, tails : tuple of str
        (b,) each bone's head and tail joint.
    planes : tuple of tuple of str or None
        (b,) the three joints whose plane fixes each bone's roll (None: no plane, world Z is used).
    name : str
        The file or object it was read from (for messages).
    """

    names: tuple
    parents: np.ndarray
    heads: tuple
    tails: tuple
    planes: tuple
    name: str = "skeleton"

    @property
    def n_bones(self) -> int:
        return len(self.names)

    def index(self, bone) -> int:
        """The index of the bone named ``bone`` (RigError when there is none)."""
        try:
            return self.names.index(bone)
        except ValueError:
            raise RigError(self.name, f"has no bone named {bone!r}") from None

    def joint_names(self):
        """Every joint a bone or a plane refers to, sorted."""
        used = set(self.heads) | set(self.tails)
        for plane in self.planes:
            used.update(plane or ())
        return sorted(used)

    def missing_joints(self, joints):
        """The joints of its bones and planes that ``joints`` (a mapping) lacks, sorted."""
        return [j for j in self.joint_names() if j not in joints]

    def rest(self, joints):
        """The bones' rest heads and tails on one body.

        Parameters
        ----------
        joints : dict of str to (3,) float
            Joint positions on the body (``read_joints``).

        Returns
        -------
        heads, tails : (b,3) float64
        """
        missing = self.missing_joints(joints)
        if missing:
            raise RigError(self.name, f"the joints given lack {len(missing)} joints of its bones "
                                      f"(first: {', '.join(missing[:3])})")
        heads = np.array([joints[j] for j in self.heads], dtype=np.float64).reshape(-1, 3)
        tails = np.array([joints[j] for j in self.tails], dtype=np.float64).reshape(-1, 3)
        return heads, tails


def skeleton_from_dict(data, name="skeleton") -> Skeleton:
    """A Skeleton from the skeleton file's content (``{"bones": {...}, "planes": {...}}``)."""
    bones = data.get("bones") if isinstance(data, dict) else None
    if not isinstance(bones, dict) or not bones:
        raise RigError(name, "has no \"bones\" (a mapping of bone name to parent, head, tail)")
    plane_joints = data.get("planes") or {}
    for bone, spec in bones.items():
        if not isinstance(spec, dict) or not isinstance(spec.get("head"), str) or not isinstance(spec.get("tail"), str):
            raise RigError(name, f"bone {bone!r} needs a \"head\" and a \"tail\" joint name")
        parent = spec.get("parent")
        if parent is not None and parent not in bones:
            raise RigError(name, f"bone {bone!r} has parent {parent!r}, which is not a bone")
    order = _parents_first(bones, name)
    index = {bone: i for i, bone in enumerate(order)}
    parents = np.array([index[bones[b]["parent"]] if bones[b].get("parent") is not None else -1 for b in order],
                       dtype=np.int64)
    planes = []
    for bone in order:
        plane = bones[bone].get("rotation_plane")
        if isinstance(plane, str):
            plane = plane_joints.get(plane)
        if plane is None or (isinstance(plane, list) and all(p is None for p in plane)):
            planes.append(None)
        elif isinstance(plane, list) and len(plane) == 3 and all(isinstance(p, str) for p in plane):
            planes.append(tuple(plane))
        else:
            raise RigError(name, f"bone {bone!r}: its rotation plane must be three joint names, got {plane!r}")
    return Skeleton(tuple(order), parents, tuple(bones[b]["head"] for b in order),
                    tuple(bones[b]["tail"] for b in order), tuple(planes), name)


def _parents_first(bones, name):
    """Bone names ordered so that a parent comes before its children (the file's order otherwise)."""
    order, placed = [], set()
    pending = list(bones)
    while pending:
        ready = [b for b in pending if bones[b].get("parent") is None or bones[b]["parent"] in placed]
        if not ready:
            raise RigError(name, f"bones {', '.join(pending[:3])} are their own ancestors (a parent loop)")
        order += ready
        placed.update(ready)
        pending = [b for b in pending if b not in placed]
    return order


def read_json(path):
    """A rig file's JSON content (RigError naming the file where it cannot be read or is not JSON)."""
    try:
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)
    except OSError as e:
        raise RigError(str(path), f"cannot be read ({e.strerror or e})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise RigError(str(path), f"is not a JSON file ({e})") from None


def read_skeleton(path) -> Skeleton:
    """Read a skeleton file (``rig/skeleton.json``).

    Returns
    -------
    Skeleton
    """
    return skeleton_from_dict(read_json(path), str(path))


def point_of(value):
    """``value`` as a (3,) float64 point where it is a list of three finite numbers, else None."""
    if not isinstance(value, list) or len(value) != 3 or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
        return None
    p = np.asarray(value, dtype=np.float64)
    return p if np.isfinite(p).all() else None


def read_joints(path, skeleton: Skeleton | None = None, what="the joints file"):
    """Read a joints file: ``{joint: [x, y, z]}`` (``rig/joints/<body>.json``).

    Parameters
    ----------
    path : path
    skeleton : Skeleton, optional
        With it, the file must hold every joint of its bones and planes (RigError naming the file otherwise).
    what : str
        What the file is given as (an option, an entry), for that error's remedy.

    Returns
    -------
    dict of str to (3,) float64
    """
    return joints_from_dict(read_json(path), str(path), skeleton, what)


def joints_from_dict(data, name, skeleton: Skeleton | None = None, what="the joints file"):
    """A joints file's content (``{joint: [x, y, z]}``, or those under ``"joints"``) as ``read_joints`` returns it;
    ``name`` (the file) in its errors."""
    if isinstance(data, dict) and isinstance(data.get("joints"), dict):
        data = data["joints"]
    if not isinstance(data, dict) or not data:
        raise RigError(name, "is not a mapping of joint names to [x, y, z] positions")
    joints = {}
    for joint, value in data.items():
        p = point_of(value)
        if p is None:
            raise RigError(name, f"joint {joint!r} is not three finite numbers: {value!r}")
        joints[joint] = p
    missing = [] if skeleton is None else skeleton.missing_joints(joints)
    if missing:
        raise RigError(name, f"lacks {len(missing)} joints of the skeleton {skeleton.name} (first: "
                             f"{', '.join(missing[:3])}): give {what} the joints of that skeleton")
    return joints


def plane_normals(skeleton: Skeleton, joints):
    """Each bone's roll-plane normal on a body: ``(p3 - p2) x (p2 - p1)`` normalised, MakeHuman's.

    Parameters
    ----------
    skeleton : Skeleton
    joints : dict of str to (3,) float

    Returns
    -------
    N : (b,3) float64
        World Z where a bone has no plane or its plane has no area.
    """
    N = np.tile([0.0, 0.0, 1.0], (skeleton.n_bones, 1))
    for i, plane in enumerate(skeleton.planes):
        if plane is None:
            continue
        p1, p2, p3 = (np.asarray(joints[j], dtype=np.float64) for j in plane)
        n = np.cross(p3 - p2, p2 - p1)
        size = max(np.linalg.norm(p3 - p2) * np.linalg.norm(p2 - p1), 1e-300)
        if np.linalg.norm(n) > DEGENERATE_SHARE * size:
            N[i] = n / np.linalg.norm(n)
    return N


def bone_frames(skeleton: Skeleton, joints):
    """Each bone's rest frame on a body: columns X, Y (head to tail), Z (normal x Y), as MakeHuman builds it.

    Parameters
    ----------
    skeleton : Skeleton
    joints : dict of str to (3,) float

    Returns
    -------
    frames : (b,3,3) float64
        Rotation matrices (columns are the bone's axes in the body's space); the identity for a bone of no
        length.
    """
    heads, tails = skeleton.rest(joints)
    normals = plane_normals(skeleton, joints)
    frames = np.tile(np.eye(3), (skeleton.n_bones, 1, 1))
    scale = max(float(np.ptp(np.concatenate([heads, tails]), axis=0).max()), 1e-300)
    for i in range(skeleton.n_bones):
        y = tails[i] - heads[i]
        if np.linalg.norm(y) <= DEGENERATE_SHARE * scale:
            continue
        y = y / np.linalg.norm(y)
        z = np.cross(normals[i], y)
        if np.linalg.norm(z) < 1e-6:
            # The plane's normal lies along the bone: any axis across the bone will do.
            helper = np.array([0.0, 0.0, 1.0]) if abs(y[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
            z = np.cross(helper, y)
        z = z / np.linalg.norm(z)
        frames[i] = np.stack([np.cross(y, z), y, z], axis=1)
    return frames
