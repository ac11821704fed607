"""The command line: ``python -m garment_transfer <command>`` (``main``). ``commands`` holds one function per
command, each a thin layer that reads files, calls the pipeline and writes files, and the parser; ``batch`` is
the catalogue command; ``options`` is what every command shares (option types, progress, the JSON output).
The top of the house: nothing else in the core imports it."""

from .commands import build_parser, main

__all__ = ["build_parser", "main"]
