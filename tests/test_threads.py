"""``geometry.threads.together``: the calls' results in order, every call ended before an error is raised, and
the work done in the caller's thread when no helper is free; ``ahead``: a call started early, its result (or its
error) when asked for, in the caller's thread when no helper is free; ``in_threads``: a map in threads of its own."""

import threading
import time

import numpy as np
import pytest

from garment_transfer.geometry.threads import HELPERS, ahead, in_threads, together


def test_results_in_order_as_one_after_the_other():
    rng = np.random.default_rng(0)
    A = [rng.random((300, 300)) for _ in range(3)]
    got = together(*(lambda a=a: a @ a.T for a in A))
    for a, g in zip(A, got):
        np.testing.assert_array_equal(g, a @ a.T)
    assert together(lambda: 1) == [1]


def test_an_error_is_raised_after_every_call_has_ended():
    ended = []

    def slow():
        time.sleep(0.2)
        ended.append("slow")
        return 1

    def broken():
        raise ValueError("the second call")

    with pytest.raises(ValueError, match="the second call"):
        together(slow, broken)
    assert ended == ["slow"]
    with pytest.raises(ValueError, match="the second call"):
        together(broken, slow)
    assert ended == ["slow", "slow"]
    # The helpers are free again: a later call still gets one (where the machine has more than one core).
    names = together(lambda: threading.current_thread().name, lambda: threading.current_thread().name)
    assert names[1] == threading.current_thread().name
    assert (names[0] != names[1]) == (HELPERS > 0)


def test_no_free_helper_runs_the_work_in_the_callers_thread():
    here = threading.current_thread().name
    if HELPERS == 0:
        assert together(lambda: threading.current_thread().name, lambda: 0)[0] == here
        return
    # Every helper busy (inside calls of their own): a nested call runs everything where it is.
    release = threading.Event()
    started = threading.Semaphore(0)

    def busy():
        started.release()
        release.wait(5)
        return together(lambda: threading.current_thread().name, lambda: threading.current_thread().name)

    outer = threading.Thread(target=lambda: results.append(together(*([busy] * HELPERS), lambda: None)))
    results = []
    outer.start()
    for _ in range(HELPERS):
        assert started.acquire(timeout=5)
    assert together(lambda: threading.current_thread().name, lambda: 0)[0] == here
    release.set()
    outer.join(5)
    for nested in results[0][:HELPERS]:
        assert nested[0] == nested[1]          # each helper ran its nested calls itself


def test_ahead_runs_on_a_helper_meanwhile_and_gives_its_result_or_error():
    here = threading.current_thread().name
    gate = threading.Event()
    calls = []

    def work():
        calls.append(threading.current_thread().name)
        gate.wait(5)
        return 42

    early = ahead(work)
    if HELPERS:
        # Started before the caller asks: on a helper, while the caller goes on.
        for _ in range(500):
            if calls:
                break
            time.sleep(0.01)
        assert calls and calls[0] != here
    gate.set()
    assert early.result() == 42 and early.result() == 42
    assert len(calls) == 1                      # run once, however often asked
    assert (calls[0] == here) == (HELPERS == 0)
    # The helper is free again afterwards: together still gets it.
    names = together(lambda: threading.current_thread().name, lambda: 0)
    assert (names[0] != here) == (HELPERS > 0)

    def broken():
        raise ValueError("the early call")

    failed = ahead(broken)
    with pytest.raises(ValueError, match="the early call"):
        failed.result()


def test_ahead_without_a_free_helper_runs_when_asked_in_the_callers_thread():
    # Every helper busy with an early call of its own (none on one core).
    here = threading.current_thread().name
    release = threading.Event()
    busy = [ahead(lambda: release.wait(5)) for _ in range(HELPERS)]
    ran = []
    late = ahead(lambda: ran.append(threading.current_thread().name) or "done")
    assert ran == []                            # nothing started: it waits to be asked
    assert late.result() == "done" and ran == [here]
    release.set()
    assert all(b.result() for b in busy)


def test_in_threads_maps_in_order_and_one_worker_stays_in_the_callers_thread():
    rng = np.random.default_rng(1)
    A = [rng.random((200, 200)) for _ in range(5)]
    got = in_threads(lambda a: a @ a.T, A, workers=2)
    for a, g in zip(A, got):
        np.testing.assert_array_equal(g, a @ a.T)
    here = threading.current_thread().name
    assert in_threads(lambda _: threading.current_thread().name, [0, 1], workers=1) == [here, here]
    assert set(in_threads(lambda _: threading.current_thread().name, [0, 1, 2], workers=2)) != {here}
    assert in_threads(len, []) == []
