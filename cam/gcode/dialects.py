"""G-code dialects as small tables of rules: what each controller needs around the same moves.

LinuxCNC (default) and Fanuc take a tool change with M6 and a length offset with G43 H; Grbl has no
tool changer (no M6, no G43 H) and reads lines of at most 80 characters. Fanuc wraps the program in
'%' with an O number, wants upper-case comments and ends with M30; LinuxCNC and Grbl end with M2.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["DIALECTS", "Dialect", "get_dialect"]


@dataclass(frozen=True)
class Dialect:
    """The rules of one controller's G-code dialect.

    Attributes
    ----------
    name : str
        Key in `DIALECTS`.
    modal_reset : str
        The line that sets the modal state at the start (plane, mm, no compensation, absolute, ...).
    tool_change : str or None
        Tool change line, formatted with t = tool number; None without a tool changer.
    length_offset : str or None
        Tool length offset line, formatted with t = tool number and z = clearance height (mm); None
        where the controller takes none.
    spindle_on : str
        Formatted with s = spindle speed (rev/min).
    spindle_off : str
        Spindle stop line.
    end : str
        Program end line.
    percent : bool
        Whether '%' is the first and last line.
    program_number : str or None
        Program number line, formatted with n; None for none.
    upper_comments : bool
        Whether comments are written in upper case.
    max_line : int or None
        Longest line the controller reads, in characters; None for no limit.
    decimals : int
        Decimals of coordinates (mm).
    """
    name: str
    modal_reset: str
    tool_change: str | None  # format with t=tool number
    length_offset: str | None  # format with t=tool number and z=clearance
    spindle_on: str  # format with s=rpm
    spindle_off: str
    end: str
    percent: bool = False  # '%' first and last line
    program_number: str | None = None
    upper_comments: bool = False
    max_line: int | None = None
    decimals: int = 4


DIALECTS = {
    "linuxcnc": Dialect(name="linuxcnc", modal_reset="G17 G21 G40 G49 G80 G90 G94", tool_change="T{t} M6",
                        length_offset="G43 H{t}", spindle_on="S{s} M3", spindle_off="M5", end="M2"),
    "grbl": Dialect(name="grbl", modal_reset="G17 G21 G40 G49 G80 G90 G94", tool_change=None, length_offset=None,
                    spindle_on="S{s} M3", spindle_off="M5", end="M2", max_line=79),
    "fanuc": Dialect(name="fanuc", modal_reset="G17 G21 G40 G49 G80 G90 G94", tool_change="T{t} M6",
                     length_offset="G0 G43 H{t} Z{z}", spindle_on="S{s} M3", spindle_off="M5", end="M30",
                     percent=True, program_number="O{n:04d}", upper_comments=True),
}


def get_dialect(name: str) -> Dialect:
    """The dialect table by name.

    Parameters
    ----------
    name : str
        A key of `DIALECTS`: "linuxcnc", "grbl" or "fanuc".

    Returns
    -------
    dialect : Dialect
        Its rules.

    Raises
    ------
    ValueError
        For an unknown name, naming the known ones.
    """
    try:
        return DIALECTS[name]
    except KeyError:
        raise ValueError(f"unknown G-code dialect {name!r}; known: {', '.join(DIALECTS)}") from None
