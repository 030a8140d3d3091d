"""Does progress move? The longest time between two progress updates of each stage of `cloud2cnc run`.

The job is the README example (`examples/dome_block.xyz` with its documented parameters) unless a part is
given. It runs once, in this process, as `cloud2cnc run` does with its output going to a file (plain lines,
no bar). Two gaps per stage, the stage's start and end counting as updates:
- calls: between two calls of the stage's progress callback (what a terminal's bar shows);
- lines: between two lines the run writes (what a log shows).
The message around each stage's longest gap says where the slow code is.

    python bench/progress.py [input] [--set key=value ...]
        prints a table on stdout; the run's own output goes to stderr, each line prefixed with its time.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
EXAMPLE = ROOT / "examples" / "dome_block.xyz"
EXAMPLE_SETS = ("tool.radius_mm=2", "reconstruct.max_faces=20000", "fit.max_refinements=0")


class Clock:
    """Per stage: the times (s since the run started) and messages of its progress calls and written lines."""

    def __init__(self) -> None:
        self.t0 = time.perf_counter()
        self.calls: dict[str, list[tuple[float, str]]] = {}
        self.lines: dict[str, list[tuple[float, str]]] = {}
        self.stage = ""

    def now(self) -> float:
        return time.perf_counter() - self.t0


class StampedStream:
    """A text stream (not a terminal) that notes when each line is written and echoes it, stamped, to stderr."""

    def __init__(self, clock: Clock) -> None:
        self.clock, self.pending = clock, ""

    def isatty(self) -> bool:
        return False

    def write(self, text: str) -> int:
        self.pending += text
        while "\n" in self.pending:
            line, self.pending = self.pending.split("\n", 1)
            t = self.clock.now()
            self.clock.lines.setdefault(self.clock.stage, []).append((t, line))
            print(f"[{t:8.2f} s] {line}", file=sys.stderr, flush=True)
        return len(text)

    def flush(self) -> None:
        pass


def instrument(clock: Clock) -> None:
    """Wrap `worker.local._Bar` so that its start, every update and its end are noted on `clock`."""
    from worker import local

    bar, update, end = local._Bar.__init__, local._Bar.update, local._Bar.end

    def start_bar(self, stream, name):
        clock.stage = name
        clock.calls[name] = [(clock.now(), "stage start")]
        clock.lines.setdefault(name, []).append((clock.now(), "stage start"))
        bar(self, stream, name)

    def note(self, fraction, message=None):
        clock.calls[self.name].append((clock.now(), f"{fraction:.0%} {message or ''}"))
        update(self, fraction, message)

    def finish(self, text):
        clock.calls[self.name].append((clock.now(), "stage end"))
        end(self, text)

    local._Bar.__init__, local._Bar.update, local._Bar.end = start_bar, note, finish


def longest_gap(events: list[tuple[float, str]]) -> tuple[float, str, str]:
    """The longest time between two consecutive events, and the events on either side of it."""
    if len(events) < 2:
        return 0.0, "", ""
    k = max(range(1, len(events)), key=lambda i: events[i][0] - events[i - 1][0])
    return events[k][0] - events[k - 1][0], events[k - 1][1], events[k][1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input", nargs="?", default=str(EXAMPLE))
    parser.add_argument("--set", action="append", default=None, help="key=value (default: the README's)")
    parser.add_argument("--calls", help="also write every progress call (stage, s, fraction and message) here")
    args = parser.parse_args()

    from core.config import Settings, set_thread_limits

    settings = Settings()
    set_thread_limits(settings)  # as `cloud2cnc run` does, before numpy loads
    from core.params import merge_params, parse_assignment
    from worker.local import run_local

    params: dict = {}
    for item in args.set if args.set is not None else EXAMPLE_SETS:
        params = merge_params(params, parse_assignment(item))
    clock = Clock()
    instrument(clock)
    with tempfile.TemporaryDirectory() as out:
        reports = run_local(Path(args.input), Path(out), params=params, settings=settings,
                            stream=StampedStream(clock))
    print("| stage | seconds | progress calls | longest gap between calls, s (between) | "
          "longest gap between lines, s |")
    print("|---|---|---|---|---|")
    for report in reports:
        calls = clock.calls.get(report.name, [])
        lines = clock.lines.get(report.name, []) + [(calls[-1][0], "stage end")] if calls else []
        gap, before, after = longest_gap(calls)
        line_gap, _, _ = longest_gap(sorted(lines))
        print(f"| {report.name} | {report.seconds:.1f} | {len(calls) - 2} | {gap:.1f} ({before!r} → {after!r}) | "
              f"{line_gap:.1f} |")
    if args.calls:
        Path(args.calls).write_text("".join(f"{stage}\t{t:.3f}\t{text}\n" for stage, calls in clock.calls.items()
                                            for t, text in calls))
    return 0 if all(r.status in ("succeeded", "skipped") for r in reports) else 1


if __name__ == "__main__":
    raise SystemExit(main())
