"""G-code, shared by `plan` (which writes it) and `verify` (which reads it back): the move list
(`moves`), dialect tables (`dialects`), the writer and our own strict reader (`parser`), the setup a
program's coordinates are in (`setup`), and the volume a ball sweeps along moves (`sweep`)."""

from cam.gcode.dialects import DIALECTS, Dialect, get_dialect
from cam.gcode.moves import FEED, PLUNGE, RAPID, MoveList
from cam.gcode.parser import GCodeError, ParsedProgram, parse_program
from cam.gcode.writer import GENERATOR, write_program

__all__ = [
    "DIALECTS",
    "FEED",
    "GENERATOR",
    "PLUNGE",
    "RAPID",
    "Dialect",
    "GCodeError",
    "MoveList",
    "ParsedProgram",
    "get_dialect",
    "parse_program",
    "write_program",
]
