"""cam.map_forked: the calls' results in order, bit for bit those of one process; errors and cancel reach the caller."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from cam import map_forked


def _work(k: int, check_cancel) -> np.ndarray:
    a = np.random.default_rng(k).normal(size=(60, 60))
    for _ in range(5):
        a = np.tanh(a @ a / 60)
    return a


@pytest.mark.parametrize("processes", [2, 3, 8])
def test_results_in_order_and_identical_to_one_process(processes):
    one = map_forked(_work, 7)
    many = map_forked(_work, 7, processes=processes)
    assert len(many) == 7 and all(np.array_equal(a, b) for a, b in zip(one, many, strict=True))


def test_the_children_are_other_processes_and_see_the_callers_state():
    seen = {"parent": os.getpid(), "table": list(range(10))}  # inherited by the fork, never pickled
    out = map_forked(lambda k, cc: (os.getpid(), seen["table"][k]), 4, processes=2)
    assert [v for _, v in out] == [0, 1, 2, 3] and all(pid != seen["parent"] for pid, _ in out)


def test_progress_reaches_one():
    shares = []
    map_forked(_work, 5, processes=2, progress=lambda f, m=None: shares.append(f))
    assert shares == sorted(shares) and shares[-1] == 1.0 and len(shares) == 5


def test_an_error_in_a_call_is_raised_here():
    def fail_on_three(k, cc):
        if k == 3:
            raise ValueError("call 3 failed")
        return k

    with pytest.raises(ValueError, match="call 3 failed"):
        map_forked(fail_on_three, 6, processes=2)


def test_cancel_stops_the_children_while_they_work():
    calls = []

    def cancel():
        calls.append(time.monotonic())
        if len(calls) > 3:
            raise KeyboardInterrupt("canceled")

    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        map_forked(lambda k, cc: time.sleep(30), 4, processes=2, check_cancel=cancel, poll_s=0.05)
    # Four 30 s calls; cancel came at the fourth poll, so the children were killed, not waited for.
    assert time.monotonic() - start < 10


def test_one_process_runs_here_with_the_callers_cancel():
    def cancel():
        raise KeyboardInterrupt("canceled")

    with pytest.raises(KeyboardInterrupt):
        map_forked(_work, 3, processes=1, check_cancel=cancel)


class _Unpicklable(Exception):
    def __init__(self, message):
        super().__init__(message)
        self.handle = lambda: None  # a lambda does not pickle


def test_an_error_that_does_not_pickle_still_says_what_it_was():
    def fail(k, cc):
        raise _Unpicklable(f"call {k} broke")

    with pytest.raises(RuntimeError, match="call 1 broke"):
        map_forked(lambda k, cc: fail(k, cc) if k == 1 else k, 3, processes=2)

