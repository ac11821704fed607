"""Point caches: one mesh's vertex positions over frames, as a PC2 file.

PC2 is the point cache Blender's Mesh Cache modifier reads (and 3ds Max, Maya and Houdini): a 32-byte header
(``POINTCACHE2`` and a zero byte, version 1, the number of points, the start frame and the sample rate as floats,
the number of samples), then every sample's points as little-endian float32 x, y, z. A long bake is one file on
disk instead of a shape key per frame in the scene.
"""

from __future__ import annotations

import os
import struct

import numpy as np

from ..errors import MeshError
from ..files import write_atomic

MAGIC = b"POINTCACHE2\0"
#: magic, version, points, start frame, sample rate, samples.
HEADER = struct.Struct("<12siiffi")
VERSION = 1


def pc2_bytes(positions, start_frame=0.0, sample_rate=1.0) -> bytes:
    """The PC2 file of ``positions`` (k,n,3): k samples of n points, from ``start_frame``, ``sample_rate`` frames
    apart."""
    P = np.asarray(positions, dtype=np.float64)
    if P.ndim != 3 or P.shape[2] != 3 or P.shape[0] < 1 or P.shape[1] < 1:
        raise ValueError(f"positions must have shape (samples, points, 3), got {P.shape}")
    if not np.isfinite(P).all() or np.abs(P).max() > np.finfo(np.float32).max:
        raise ValueError("positions must be finite float32 numbers")
    if not (np.isfinite(start_frame) and np.isfinite(sample_rate) and sample_rate > 0):
        raise ValueError(f"start frame {start_frame} and sample rate {sample_rate}: finite, the rate > 0")
    head = HEADER.pack(MAGIC, VERSION, P.shape[1], float(start_frame), float(sample_rate), P.shape[0])
    return head + P.astype("<f4").tobytes()


def write_pc2(path, positions, start_frame=0.0, sample_rate=1.0, inputs=(), what="point cache"):
    """Write ``positions`` (k,n,3) to ``path`` as a PC2 file, whole or not at all (``files.write_atomic``: never
    onto one of ``inputs``)."""
    data = pc2_bytes(positions, start_frame, sample_rate)
    write_atomic(path, lambda fh: fh.write(data), inputs, what, binary=True)


def is_pc2(path) -> bool:
    """Whether ``path`` is a file that starts as a PC2 file does."""
    try:
        with open(path, "rb") as fh:
            return fh.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


def cache_bytes(path) -> bytes:
    """The bytes of a point-cache file, or MeshError naming it where it cannot be read."""
    try:
        with open(path, "rb") as fh:
            return fh.read()
    except OSError as exc:
        raise MeshError(os.fspath(path), f"cannot be read ({exc.strerror or exc})") from None


def read_pc2(path):
    """Read a PC2 file.

    Returns
    -------
    positions : (k,n,3) float32
    start_frame, sample_rate : float

    Raises
    ------
    MeshError
        Naming the file: not a PC2 file, another version, or a size that does not match its header.
    """
    name = os.fspath(path)
    data = cache_bytes(path)
    if len(data) < HEADER.size or data[:len(MAGIC)] != MAGIC:
        raise MeshError(name, "is not a PC2 point cache (it does not start with POINTCACHE2)")
    _, version, points, start, rate, samples = HEADER.unpack_from(data)
    if version != VERSION:
        raise MeshError(name, f"is a PC2 file of version {version}; version {VERSION} is read")
    if points < 1 or samples < 1 or len(data) != HEADER.size + 12 * points * samples:
        raise MeshError(name, f"holds {len(data) - HEADER.size} bytes of points, but its header says {samples} "
                              f"samples of {points} points ({12 * max(points, 0) * max(samples, 0)} bytes): cut "
                              "off or not a PC2 file")
    P = np.frombuffer(data, dtype="<f4", offset=HEADER.size).reshape(samples, points, 3).astype(np.float32)
    return P, float(start), float(rate)
