"""`cloud2cnc run`'s progress: plain lines in a log, every 5 % or, while a stage crawls, every 10 s with
what it is doing; a bar that keeps to one line on a terminal."""

from __future__ import annotations

import io

from worker.local import _Bar


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_a_log_gets_a_line_per_five_percent_or_per_ten_seconds():
    clock, log = _Clock(), io.StringIO()
    bar = _Bar(log, "fit", clock=clock)
    for dt, fraction, message in [(0, 0.0, "start"), (1, 0.01, "a"), (1, 0.049, "b"), (1, 0.05, "c"),
                                  (9.5, 0.06, "d"), (0.5, 0.061, "patch 3: step 4"), (1, 0.07, "e"),
                                  (1, 1.0, "fitted")]:
        clock.t += dt
        bar.update(fraction, message)
    # 0.05 moved 5 % from the start; 0.061 came 10 s after it with little moved; 1.0 ends it.
    assert log.getvalue().splitlines() == ["fit: 0% start", "fit: 5% c", "fit: 6% patch 3: step 4", "fit: 100% fitted"]


def test_no_report_no_line():
    clock, log = _Clock(), io.StringIO()
    bar = _Bar(log, "plan", clock=clock)
    bar.update(0.5, "half")
    clock.t += 60
    assert log.getvalue() == "plan: 50% half\n"  # a line comes with a report, never on its own


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_terminal_gets_one_line_overwritten_and_the_message_cut_to_fit():
    term = _Terminal()
    bar = _Bar(term, "fit")
    bar.update(0.3, "x" * 500)
    bar.update(0.5, "short")
    bar.end("done in 3 s")
    frames = term.getvalue().split("\r")[1:]
    assert len(frames) == 3 and all("\n" not in f for f in frames[:2]) and frames[2].endswith("\n")
    assert len(frames[0]) == len(frames[1]) <= len(frames[2].rstrip("\n"))  # each overwrites the one before
    assert frames[0].rstrip().endswith("…") and "50% short" in frames[1]
