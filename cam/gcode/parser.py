"""Our own reader of the G-code we write (and of plain 3-axis linear programs like it), for verify.

It follows the modal state a controller keeps — motion G0/G1, G90/G91, G20/G21, feed — and returns
every straight move with its start and end tool tip. Anything that would move the tool in a way it
does not model (arcs, canned cycles, probing, machine coordinates, offsets) is refused with the line
number, so verify never measures a program it did not understand.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

__all__ = ["GCodeError", "ParsedProgram", "parse_program"]

_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")
_UNSUPPORTED_G = {2, 3, 5, 28, 30, 33, 38, 53, 73, 76, 81, 82, 83, 84, 85, 86, 87, 88, 89, 92}


class GCodeError(ValueError):
    """A program verify cannot follow; the message names the line."""


@dataclass(frozen=True)
class ParsedProgram:
    """The straight moves of a program, in order, and its comments.

    Attributes
    ----------
    start, end : (m, 3) float64
        Tool tips (mm, machine frame) at the start and end of each straight move.
    rapid : (m,) bool
        True for G0 moves.
    feed : (m,) float64
        Feed rate in mm/min; NaN for rapids.
    line : (m,) int64
        1-based source line of each move.
    comments : list of str
        The text of every comment, in order.
    """

    start: np.ndarray
    end: np.ndarray
    rapid: np.ndarray
    feed: np.ndarray
    line: np.ndarray
    comments: list[str]

    def header_value(self, key: str) -> str | None:
        """The value of a 'key: value' header comment (case-insensitive), or None.

        Parameters
        ----------
        key : str
            The key, such as ``certified scallop bound``.

        Returns
        -------
        value : str or None
            The stripped text after the first ':' of the first matching comment.
        """
        for c in self.comments:
            k, sep, v = c.partition(":")
            if sep and k.strip().lower() == key.lower():
                return v.strip()
        return None


def _strip(line: str, comments: list[str]) -> str:
    out, depth, buf = [], 0, []
    for ch in line:
        if ch == ";" and depth == 0:
            comments.append(line[line.index(";") + 1:].strip())
            break
        if ch == "(":
            depth += 1
            continue
        if ch == ")" and depth:
            depth -= 1
            if depth == 0:
                comments.append("".join(buf).strip())
                buf = []
            continue
        (buf if depth else out).append(ch)
    return "".join(out)


def parse_program(text: str) -> ParsedProgram:
    """The straight moves of a program text.

    Follows G0/G1, G90/G91, G20/G21 (inches become mm, feeds too) and F; moves made before all three
    axes are known only set the position.

    Parameters
    ----------
    text : str
        The program.

    Returns
    -------
    program : ParsedProgram
        Its moves and comments.

    Raises
    ------
    GCodeError
        For what it does not model, naming the line: block delete, unreadable words, arcs, canned cycles,
        probing, machine coordinates or offsets, rotary or extra axes, a coordinate without a motion
        mode, or G1 without a feed rate.
    """
    comments: list[str] = []
    pos = np.full(3, np.nan)
    motion, absolute, scale, feed = None, True, 1.0, np.nan
    starts, ends, rapid, feeds, lines = [], [], [], [], []
    for number, raw in enumerate(text.splitlines(), start=1):
        body = _strip(raw, comments).strip()
        if not body or body == "%":
            continue
        if body.startswith("/"):
            raise GCodeError(f"line {number}: block delete '/' is not supported")
        words = _WORD.findall(body)
        rest = _WORD.sub("", body).strip()
        if rest:
            raise GCodeError(f"line {number}: cannot read {rest!r} in {raw.strip()!r}")
        target = {}
        for letter, value in words:
            letter = letter.upper()
            val = float(value)
            if letter == "G":
                code = round(val, 1)
                if code in (0, 1):
                    motion = int(code)
                elif code == 20:
                    scale = 25.4
                elif code == 21:
                    scale = 1.0
                elif code == 90:
                    absolute = True
                elif code == 91:
                    absolute = False
                elif int(code) in _UNSUPPORTED_G or code in (43.1, 92.1):
                    raise GCodeError(f"line {number}: G{value} moves the tool in a way verify does not model")
            elif letter in "XYZ":
                target["XYZ".index(letter)] = val
            elif letter == "F":
                feed = val
            elif letter in "ABCUVW":
                raise GCodeError(f"line {number}: axis {letter} is not a 3-axis move")
        if target:
            if motion is None:
                raise GCodeError(f"line {number}: a coordinate without a motion mode (G0/G1)")
            new = pos.copy()
            for axis, val in target.items():
                new[axis] = val * scale if absolute else pos[axis] + val * scale
            if np.all(np.isfinite(pos)) and np.all(np.isfinite(new)):
                if motion == 1 and not np.isfinite(feed):
                    raise GCodeError(f"line {number}: G1 without a feed rate")
                starts.append(pos.copy())
                ends.append(new)
                rapid.append(motion == 0)
                feeds.append(np.nan if motion == 0 else feed * scale)
                lines.append(number)
            pos = new
    as_array = lambda x: np.array(x, dtype=np.float64).reshape(-1, 3)
    return ParsedProgram(start=as_array(starts), end=as_array(ends), rapid=np.array(rapid, dtype=bool),
                         feed=np.array(feeds, dtype=np.float64), line=np.array(lines, dtype=np.int64),
                         comments=comments)
