"""PC2 and MDD point caches: the layouts Blender's Mesh Cache modifier reads, written whole, read back exactly."""

import struct

import numpy as np
import pytest

from garment_transfer import MeshError, OutputError, is_mdd, is_pc2, read_mdd, read_pc2, write_mdd, write_pc2


def test_a_point_cache_has_the_pc2_header_and_float32_points_and_reads_back(tmp_path):
    P = np.random.default_rng(0).normal(size=(4, 5, 3))
    path = tmp_path / "cloth.pc2"
    write_pc2(path, P, start_frame=12, sample_rate=0.5)
    data = path.read_bytes()
    assert data[:12] == b"POINTCACHE2\0" and len(data) == 32 + 4 * 5 * 12
    assert struct.unpack("<iiffi", data[12:32]) == (1, 5, 12.0, 0.5, 4)
    assert np.array_equal(np.frombuffer(data[32:], "<f4"), P.astype(np.float32).ravel())
    Q, start, rate = read_pc2(path)
    assert np.array_equal(Q, P.astype(np.float32)) and (start, rate) == (12.0, 0.5) and is_pc2(path)


def test_bad_caches_are_named_and_bad_points_or_outputs_write_nothing(tmp_path):
    path = tmp_path / "cloth.pc2"
    write_pc2(path, np.zeros((2, 3, 3)))
    cut = tmp_path / "cut.pc2"
    cut.write_bytes(path.read_bytes()[:-4])
    with pytest.raises(MeshError, match="cut.pc2: .*2 samples of 3 points .* cut off"):
        read_pc2(cut)
    other = tmp_path / "notes.txt"
    other.write_text("POINTCACHE")
    with pytest.raises(MeshError, match="notes.txt: is not a PC2 point cache"):
        read_pc2(other)
    assert not is_pc2(other) and not is_pc2(tmp_path / "missing.pc2")
    for bad in (np.full((1, 2, 3), np.nan), np.zeros((0, 2, 3)), np.zeros((2, 3))):
        with pytest.raises(ValueError):
            write_pc2(tmp_path / "new.pc2", bad)
    with pytest.raises(OutputError, match="refusing to overwrite an input"):
        write_pc2(other, np.zeros((1, 1, 3)), inputs=[other])
    assert not (tmp_path / "new.pc2").exists() and other.read_text() == "POINTCACHE"


def test_an_mdd_cache_is_big_endian_with_its_times_and_reads_back(tmp_path):
    P = np.random.default_rng(1).normal(size=(3, 4, 3))
    times = [0.0, 1 / 24, 2 / 24]
    path = tmp_path / "body.mdd"
    write_mdd(path, P, times)
    data = path.read_bytes()
    assert struct.unpack(">ii", data[:8]) == (3, 4) and len(data) == 8 + 3 * 4 + 3 * 4 * 12
    assert np.array_equal(np.frombuffer(data[8:20], ">f4"), np.float32(times))
    assert np.array_equal(np.frombuffer(data[20:], ">f4"), P.astype(np.float32).ravel())
    Q, t = read_mdd(path)
    assert np.array_equal(Q, P.astype(np.float32)) and np.array_equal(t, np.float32(times))
    cut = tmp_path / "cut.mdd"
    cut.write_bytes(data[:-4])
    (tmp_path / "body.cache").write_bytes(data)
    assert is_mdd(path) and not is_mdd(cut) and not is_mdd(tmp_path / "body.cache") and not is_mdd(tmp_path / "no.mdd")
    with pytest.raises(MeshError, match="cut.mdd: holds 160 bytes, but an MDD file of the 3 frames of 4 points"):
        read_mdd(cut)
    (tmp_path / "tiny.mdd").write_bytes(b"abc")
    with pytest.raises(MeshError, match="tiny.mdd: holds 3 bytes, fewer than an MDD header"):
        read_mdd(tmp_path / "tiny.mdd")
    for bad_P, bad_t in ((np.full((1, 2, 3), np.nan), [0.0]), (np.zeros((2, 2, 3)), [0.0]),
                         (np.zeros((1, 2, 3)), [np.inf])):
        with pytest.raises(ValueError):
            write_mdd(tmp_path / "new.mdd", bad_P, bad_t)
    with pytest.raises(OutputError, match="refusing to overwrite an input"):
        write_mdd(path, P, times, inputs=[path])
    assert not (tmp_path / "new.mdd").exists() and read_mdd(path)[0].shape == (3, 4, 3)
