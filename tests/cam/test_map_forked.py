"""cam.map_forked: the calls' results in order, bit for bit those of one process; errors and cancel reach the caller."""

from __future__ import annotations

import os
import select
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



def _work_reporting(k: int, check_cancel, progress) -> np.ndarray:
    """`_work`, reporting after each of its five rounds."""
    a = np.random.default_rng(k).normal(size=(60, 60))
    for r in range(5):
        a = np.tanh(a @ a / 60)
        progress((r + 1) / 5, f"call {k}: round {r + 1} of 5")
    return a


@pytest.mark.parametrize("processes", [1, 3])
def test_results_stay_identical_with_each_calls_progress(processes):
    plain = map_forked(_work, 7)
    reported = map_forked(_work_reporting, 7, processes=processes, item_progress=True, report_s=0,
                          progress=lambda f, m=None: None)
    assert all(np.array_equal(a, b) for a, b in zip(plain, reported, strict=True))


def test_a_calls_progress_arrives_here_while_it_runs():
    # Each call reports 0.25, 0.5, 0.75 and after each waits until this process has seen that report: it
    # can only return once its reports arrived here while it ran.
    acks = [os.pipe() for _ in range(2)]
    seen = []

    def progress(fraction, message=None):
        seen.append((fraction, message))
        if message and "; call" in message:
            k = int(message.split("; call ")[1].split(" ")[0])
            os.write(acks[k][1], b"x")

    def call(k, cc, report):
        for f in (0.25, 0.5, 0.75):
            report(f, f"call {k} at {f}")
            ready, _, _ = select.select([acks[k][0]], [], [], 60)  # a guard against a hang, not a timing
            if not ready:
                raise TimeoutError(f"call {k}: the report {f} never arrived")
            os.read(acks[k][0], 1)
        return k * 10

    try:
        assert map_forked(call, 2, processes=2, progress=progress, item_progress=True, report_s=0) == [0, 10]
    finally:
        for fds in acks:
            for fd in fds:
                os.close(fd)
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    # Each report came while its call ran (the other one running or done): a share between none and all.
    reported = {m.split("; ")[1]: f for f, m in seen if "; " in m}
    assert set(reported) == {f"call {k} at {f}" for k in (0, 1) for f in (0.25, 0.5, 0.75)}
    assert all(0.0 < f < 1.0 for f in reported.values())


def test_one_process_reports_each_calls_progress_between_its_ends():
    seen = []
    out = map_forked(lambda k, cc, report: report(0.5, f"call {k} half way") or k, 3, item_progress=True,
                     report_s=0, progress=lambda f, m=None: seen.append((f, m)))
    assert out == [0, 1, 2]
    assert seen == [(0.5 / 3, "0 of 3 done; call 0 half way"), (1 / 3, "1 of 3 done"),
                    (1.5 / 3, "1 of 3 done; call 1 half way"), (2 / 3, "2 of 3 done"),
                    (2.5 / 3, "2 of 3 done; call 2 half way"), (1.0, "3 of 3 done")]


def test_the_share_never_goes_back_when_a_call_reports_less():
    seen = []
    map_forked(lambda k, cc, report: [report(f) for f in (0.8, 0.2, 0.5)] and k, 2, item_progress=True, report_s=0,
               progress=lambda f, m=None: seen.append(f))
    assert seen == [0.4, 0.4, 0.4, 0.5, 0.9, 0.9, 0.9, 1.0]


def test_a_flood_of_reports_while_this_process_is_busy_does_not_block():
    # Each call writes far more than a pipe holds (64 kB) while this process sits in its first report.
    calls = []

    def progress(fraction, message=None):
        calls.append(fraction)
        if len(calls) == 1:
            time.sleep(0.5)  # busy: the children fill their pipes and wait

    def flood(k, cc, report):
        for i in range(20000):
            report(i / 20000, f"call {k}: report {i} of 20000, padded to take room in the pipe")
        return _work(k, cc)

    out = map_forked(flood, 4, processes=2, progress=progress, item_progress=True, report_s=0)
    assert all(np.array_equal(a, _work(k, None)) for k, a in enumerate(out))
    assert len(calls) == 4 * 20000 + 4 and calls == sorted(calls) and calls[-1] == 1.0


def test_cancel_bites_while_the_children_report():
    polls = []

    def cancel():
        polls.append(1)
        if len(polls) > 50:
            raise KeyboardInterrupt("canceled")

    def forever(k, cc, report):
        while True:
            report(0.5, "still going")

    with pytest.raises(KeyboardInterrupt):
        map_forked(forever, 4, processes=2, check_cancel=cancel, item_progress=True, report_s=0)


def test_reports_are_throttled_per_call():
    seen = []
    map_forked(lambda k, cc, report: [report(i / 1000, f"report {i}") for i in range(1000)] and k, 2, processes=2,
               item_progress=True, report_s=3600, progress=lambda f, m=None: seen.append(m))
    # Within the hour, only each call's first report passes; then the two ends.
    assert sorted(m.split("; ")[-1] for m in seen if ";" in m) == ["report 0", "report 0"] and len(seen) == 4


def test_an_error_after_reports_is_raised_here():
    def fail(k, cc, report):
        report(0.5, "half way")
        raise ValueError(f"call {k} failed after reporting")

    with pytest.raises(ValueError, match="failed after reporting"):
        map_forked(fail, 3, processes=2, item_progress=True, report_s=0)
