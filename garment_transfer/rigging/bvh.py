"""BVH motion files: a joint hierarchy with offsets, and per frame each joint's channels.

A joint's rotation is the product of its rotation channels in the order they are listed
(``Xrotation Yrotation Zrotation`` is ``Rx Ry Rz``), in degrees, acting on column vectors, relative to a rest
frame aligned with the file's axes. MakeHuman's BVH files are Z up with joints named as the bones of its
skeleton; a body in Y up (MakeHuman's OBJ files) takes them through ``axes_between``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import RigError

_AXES = {"X": 0, "Y": 1, "Z": 2}
_CHANNELS = {f"{a}{kind}" for a in "XYZ" for kind in ("position", "rotation")}


@dataclass(frozen=True)
class Motion:
    """A BVH file's content.

    Attributes
    ----------
    names : tuple of str
        (j,) joint names, in the file's order (parents first).
    parents : (j,) int64
        Each joint's parent, -1 for the root.
    offsets : (j,3) float64
        Each joint's offset from its parent, in the file's axes and units.
    channels : tuple of tuple of str
        (j,) each joint's channels, in order.
    frames : (f,c) float64
        Every channel's value per frame (c = all joints' channels in order).
    frame_time : float
        Seconds per frame.
    name : str
    """

    names: tuple
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple
    frames: np.ndarray
    frame_time: float
    name: str = "motion"

    @property
    def n_frames(self) -> int:
        return int(self.frames.shape[0])

    def _columns(self):
        start = np.cumsum([0] + [len(c) for c in self.channels])
        return start

    def rotations(self, frame=0):
        """Each joint's rotation at a frame, relative to its parent, in the file's axes.

        Returns
        -------
        R : (j,3,3) float64
        """
        if not 0 <= frame < self.n_frames:
            raise RigError(self.name, f"has {self.n_frames} frames; there is no frame {frame}")
        values = self.frames[frame]
        start = self._columns()
        R = np.tile(np.eye(3), (len(self.names), 1, 1))
        for j, chans in enumerate(self.channels):
            for k, channel in enumerate(chans):
                if channel.endswith("rotation"):
                    R[j] = R[j] @ axis_rotation(channel[0], values[start[j] + k])
        return R

    def root_position(self, frame=0):
        """The root's position channels at a frame (its offset where it has none), (3,) float64."""
        values = self.frames[frame]
        p = self.offsets[0].copy()
        for k, channel in enumerate(self.channels[0]):
            if channel.endswith("position"):
                p[_AXES[channel[0]]] = values[k]
        return p


def axis_rotation(axis, degrees):
    """(3,3) rotation by ``degrees`` about the X, Y or Z axis (right-handed, column vectors)."""
    a = np.radians(float(degrees))
    c, s = np.cos(a), np.sin(a)
    i = _AXES[axis]
    j, k = (i + 1) % 3, (i + 2) % 3
    R = np.eye(3)
    R[j, j], R[j, k], R[k, j], R[k, k] = c, -s, s, c
    return R


def axes_between(file_up="Z", body_up="Y"):
    """The rotation taking a file's axes to a body's, for the two usual conventions of the up axis.

    Z up to Y up maps (x, y, z) to (x, z, -y): the front (-Y in a Z-up file) becomes +Z, MakeHuman's; the same
    up axis gives the identity.

    Returns
    -------
    M : (3,3) float64
        Rotations in the file's axes become ``M R M^T`` in the body's.
    """
    file_up, body_up = file_up.upper(), body_up.upper()
    if {file_up, body_up} - {"Y", "Z"}:
        raise ValueError(f"up axes must be Y or Z, got {file_up!r} and {body_up!r}")
    if file_up == body_up:
        return np.eye(3)
    M = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    return M if file_up == "Z" else M.T


def read_bvh(path) -> Motion:
    """Read a BVH file.

    Returns
    -------
    Motion
    """
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            text = fh.read()
    except OSError as e:
        raise RigError(str(path), f"cannot be read ({e.strerror or e})") from None
    return parse_bvh(text, str(path))


def parse_bvh(text, name="motion") -> Motion:
    """A Motion from a BVH file's text (see ``read_bvh``)."""
    tokens = text.split()
    if not tokens or tokens[0] != "HIERARCHY":
        raise RigError(name, "is not a BVH file (it does not start with HIERARCHY)")
    names, parents, offsets, channels = [], [], [], []
    pos = _hierarchy(tokens, 1, names, parents, offsets, channels, name)
    if not names:
        raise RigError(name, "has no joints")
    frames, frame_time = _motion(tokens, pos, sum(len(c) for c in channels), name)
    return Motion(tuple(names), np.array(parents, dtype=np.int64), np.array(offsets, dtype=np.float64),
                  tuple(channels), frames, frame_time, name)


def _hierarchy(tokens, pos, names, parents, offsets, channels, name):
    """Parse the joints from ``tokens[pos]`` to MOTION; returns the position after MOTION."""
    stack = []
    try:
        while tokens[pos] != "MOTION":
            word = tokens[pos]
            if word in ("ROOT", "JOINT"):
                if (word == "ROOT") != (not stack):
                    raise RigError(name, f"{word} {tokens[pos + 1]} is not where a {word.lower()} can be")
                names.append(tokens[pos + 1])
                parents.append(stack[-1] if stack else -1)
                pos = _expect(tokens, pos + 2, "{", name)
                stack.append(len(names) - 1)
                pos = _joint_body(tokens, pos, offsets, channels, name)
            elif word == "End":
                pos = _expect(tokens, pos + 2, "{", name)
                pos = _expect(tokens, pos, "OFFSET", name) + 3
                pos = _expect(tokens, pos, "}", name)
            elif word == "}":
                if not stack:
                    raise RigError(name, "has a '}' that closes nothing")
                stack.pop()
                pos += 1
            else:
                raise RigError(name, f"has {word!r} where a JOINT, End Site, '}}' or MOTION was expected")
    except IndexError:
        raise RigError(name, "ends before its MOTION section") from None
    if stack:
        raise RigError(name, "has joints left open before MOTION")
    return pos + 1


def _joint_body(tokens, pos, offsets, channels, name):
    pos = _expect(tokens, pos, "OFFSET", name)
    offsets.append(_numbers(tokens[pos:pos + 3], name, "OFFSET"))
    pos = _expect(tokens, pos + 3, "CHANNELS", name)
    count = int(_numbers(tokens[pos:pos + 1], name, "CHANNELS")[0])
    chans = tokens[pos + 1:pos + 1 + count]
    wrong = [c for c in chans if c not in _CHANNELS]
    if wrong or len(chans) != count:
        raise RigError(name, f"has unknown channels {wrong or chans}")
    channels.append(tuple(chans))
    return pos + 1 + count


def _motion(tokens, pos, n_channels, name):
    try:
        pos = _expect(tokens, pos, "Frames:", name)
        n_frames = int(tokens[pos])
        pos = _expect(tokens, pos + 1, "Frame", name)
        pos = _expect(tokens, pos, "Time:", name)
        frame_time = float(tokens[pos])
    except (IndexError, ValueError):
        raise RigError(name, "has no readable 'Frames:' and 'Frame Time:' lines") from None
    values = tokens[pos + 1:]
    if n_frames < 1 or len(values) != n_frames * n_channels:
        raise RigError(name, f"says {n_frames} frames of {n_channels} channels but has {len(values)} values")
    frames = _numbers(values, name, "MOTION").reshape(n_frames, n_channels)
    return frames, frame_time


def _expect(tokens, pos, word, name):
    if pos >= len(tokens) or tokens[pos] != word:
        found = tokens[pos] if pos < len(tokens) else "the end of the file"
        raise RigError(name, f"has {found!r} where {word!r} was expected")
    return pos + 1


def _numbers(words, name, where):
    try:
        values = np.array([float(w) for w in words], dtype=np.float64)
    except ValueError:
        raise RigError(name, f"has a value in {where} that is not a number") from None
    if not np.isfinite(values).all():
        raise RigError(name, f"has a value in {where} that is not finite")
    return values
