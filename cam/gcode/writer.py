"""Write one setup's move list as a G-code program in a dialect (text; the caller stores it).

Coordinates are tool tips in the machine frame, millimetres, absolute, 4 decimals; only the axes that
change are written. The header comments carry what a machinist and the verify stage need: job, tool,
target scallop, the certified bound, the budget split between scallop and chord error, units, dialect
and the generator version — `certified scallop bound` is read back by verify.
"""

from __future__ import annotations

import textwrap

import numpy as np

from cam.gcode.dialects import Dialect, get_dialect
from cam.gcode.moves import FEED, PLUNGE, RAPID, MoveList

__all__ = ["GENERATOR", "write_program"]

GENERATOR = "cloud2cnc plan 1"


def _num(x: float, decimals: int) -> str:
    text = f"{x:.{decimals}f}"
    return "0." + "0" * decimals if text.strip("-0.") == "" else text  # never '-0.0000'


def _comments(text: str, dialect: Dialect) -> list[str]:
    # No bracket may end the comment early, and no ';': Fanuc ends the block there, and readers such as
    # pygcode take it for an end-of-line comment even inside parentheses.
    text = text.replace("(", "[").replace(")", "]").replace(";", ",")
    if dialect.upper_comments:
        text = text.upper()
    width = (dialect.max_line or 200) - 2
    return [f"({part})" for part in textwrap.wrap(text, width)] or ["()"]


def write_program(moves: MoveList, *, dialect: str | Dialect = "linuxcnc", header: dict[str, str],
                  tool_number: int = 1, spindle_rpm: float = 12000.0, feed_mm_min: float = 1200.0,
                  plunge_mm_min: float = 300.0, program_number: int = 1) -> str:
    """The program text (lines joined with '\\n', ending in a newline).

    Parameters
    ----------
    moves : MoveList
        The moves (tool tips, mm, machine frame).
    dialect : str or Dialect, optional
        The dialect or its name (default "linuxcnc").
    header : dict of str to str
        Ordered key → value pairs written as comments ("key: value").
    tool_number : int, optional
        1..99999 (default 1).
    spindle_rpm : float, optional
        Spindle speed in rev/min, > 0 (default 12000).
    feed_mm_min : float, optional
        Feed rate of FEED moves in mm/min, > 0 (default 1200).
    plunge_mm_min : float, optional
        Feed rate of PLUNGE moves in mm/min, > 0 (default 300).
    program_number : int, optional
        The O number, for dialects that write one (default 1).

    Returns
    -------
    text : str
        The G-code program.

    Raises
    ------
    ValueError
        For an unknown dialect name, a tool number outside 1..99999, or a rate that is not a positive
        number.
    RuntimeError
        When a line is longer than the dialect allows.
    """
    d = dialect if isinstance(dialect, Dialect) else get_dialect(dialect)
    if not 1 <= int(tool_number) <= 99999:
        raise ValueError(f"tool_number must be 1..99999, got {tool_number}")
    for name, value in (("spindle_rpm", spindle_rpm), ("feed_mm_min", feed_mm_min), ("plunge_mm_min", plunge_mm_min)):
        if not np.isfinite(value) or value <= 0:
            raise ValueError(f"{name} must be a positive number, got {value}")
    lines: list[str] = []
    if d.percent:
        lines.append("%")
    if d.program_number:
        lines.append(d.program_number.format(n=program_number))
    for key, value in header.items():
        lines.extend(_comments(f"{key}: {value}", d))
    lines.append(d.modal_reset)
    clear = moves.clearance_z
    fmt = lambda x: _num(x, d.decimals)
    if d.tool_change:
        lines.append(d.tool_change.format(t=int(tool_number)))
    else:
        lines.extend(_comments(f"load tool {int(tool_number)} before starting", d))
    if d.length_offset:
        lines.append(d.length_offset.format(t=int(tool_number), z=fmt(clear)))
    lines.append(d.spindle_on.format(s=int(round(spindle_rpm))))
    lines.append(f"G0 Z{fmt(clear)}")
    pos = np.array([np.nan, np.nan, clear])
    motion, feed = None, None
    for p, kind in zip(moves.points, moves.kind):
        axes = [axis + fmt(value) for axis, value, old in zip("XYZ", p, pos)
                if not np.isfinite(old) or fmt(value) != fmt(old)]
        pos = np.asarray(p, dtype=np.float64)
        if not axes:  # no motion at this precision
            continue
        code = "G0" if kind == RAPID else "G1"
        words = [code] if code != motion else []
        motion = code
        words += axes
        if kind in (PLUNGE, FEED):
            f = plunge_mm_min if kind == PLUNGE else feed_mm_min
            if f != feed:
                words.append(f"F{f:.1f}")
                feed = f
        lines.append(" ".join(words))
    lines.append(d.spindle_off)
    lines.append(d.end)
    if d.percent:
        lines.append("%")
    if d.max_line and max(len(x) for x in lines) > d.max_line:
        raise RuntimeError(f"a line exceeds {d.max_line} characters in the {d.name} program")
    return "\n".join(lines) + "\n"
