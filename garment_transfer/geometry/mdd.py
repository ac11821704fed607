"""Point caches as MDD files: one mesh's vertex positions over time.

MDD is the point cache of LightWave's Motion Designer that Blender's Mesh Cache modifier reads beside PC2 (and
Houdini, Cinema 4D and 3ds Max write): big-endian throughout, the number of frames and the number of points
(int32), each frame's time in seconds (float32), then every frame's points as float32 x, y, z. It has no magic
bytes: a file is taken as MDD by its name (``.mdd``) and checked by its size against its header.
"""

from __future__ import annotations

import os
import struct

import numpy as np

from ..errors import MeshError
from ..files import write_atomic
from .pc2 import cache_bytes

#: frames, points.
HEADER = struct.Struct(">ii")


def is_mdd_name(path) -> bool:
    """Whether ``path`` is named as an MDD file (``.mdd``, any case)."""
    return os.fspath(path).lower().endswith(".mdd")


def is_mdd(path) -> bool:
    """Whether ``path`` is a file named as an MDD file whose size matches its header."""
    if not is_mdd_name(path):
        return False
    try:
        with open(path, "rb") as fh:
            head = fh.read(HEADER.size)
        size = os.path.getsize(path)
    except OSError:
        return False
    if len(head) < HEADER.size:
        return False
    frames, points = HEADER.unpack(head)
    return frames >= 1 and points >= 1 and size == HEADER.size + 4 * frames + 12 * points * frames


def mdd_bytes(positions, times) -> bytes:
    """The MDD file of ``positions`` (k,n,3): k frames of n points, at ``times`` (k,) seconds."""
    P = np.asarray(positions, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)
    if P.ndim != 3 or P.shape[2] != 3 or P.shape[0] < 1 or P.shape[1] < 1:
        raise ValueError(f"positions must have shape (frames, points, 3), got {P.shape}")
    if t.shape != (P.shape[0],) or not np.isfinite(t).all():
        raise ValueError(f"times must be {P.shape[0]} finite numbers, one a frame, got shape {t.shape}")
    if not np.isfinite(P).all() or np.abs(P).max() > np.finfo(np.float32).max:
        raise ValueError("positions must be finite float32 numbers")
    return HEADER.pack(P.shape[0], P.shape[1]) + t.astype(">f4").tobytes() + P.astype(">f4").tobytes()


def write_mdd(path, positions, times, inputs=(), what="point cache"):
    """Write ``positions`` (k,n,3) at ``times`` (k,) to ``path`` as an MDD file, whole or not at all
    (``files.write_atomic``: never onto one of ``inputs``)."""
    data = mdd_bytes(positions, times)
    write_atomic(path, lambda fh: fh.write(data), inputs, what, binary=True)


def read_mdd(path):
    """Read an MDD file.

    Returns
    -------
    positions : (k,n,3) float32
    times : (k,) float32
        Each frame's time in seconds.

    Raises
    ------
    MeshError
        Naming the file: unreadable, or a size that does not match its header (another kind of file, cut off).
    """
    name = os.fspath(path)
    data = cache_bytes(path)
    if len(data) < HEADER.size:
        raise MeshError(name, f"holds {len(data)} bytes, fewer than an MDD header: not an MDD point cache")
    frames, points = HEADER.unpack_from(data)
    size = HEADER.size + 4 * frames + 12 * points * frames if frames >= 1 and points >= 1 else -1
    if len(data) != size:
        raise MeshError(name, f"holds {len(data)} bytes, but an MDD file of the {frames} frames of {points} points its "
                              "header says would hold "
                              f"{max(size, 0)}: cut off or not an MDD point cache")
    times = np.frombuffer(data, dtype=">f4", count=frames, offset=HEADER.size).astype(np.float32)
    P = np.frombuffer(data, dtype=">f4", offset=HEADER.size + 4 * frames).reshape(frames, points, 3)
    return P.astype(np.float32), times
