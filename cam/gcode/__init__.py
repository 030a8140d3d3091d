"""G-code: dialect tables, the writer, and our own parser (used by verify)."""

from cam.gcode.dialects import DIALECTS, Dialect, get_dialect
from cam.gcode.parser import GCodeError, ParsedProgram, parse_program
from cam.gcode.writer import GENERATOR, write_program

__all__ = [
           "DIALECTS",
           "GENERATOR",
           "Dialect",
           "GCodeError",
           "ParsedProgram",
           "get_dialect",
           "parse_program",
           "write_program",
]
