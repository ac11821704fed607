"""What every command shares: option types with their ranges, progress on stderr, and the output (lines, or
one JSON object)."""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys

from ..files import json_default


class WarningLog(logging.Handler):
    """The warnings the core logs during one command (they go to stderr too): ``emit`` adds them to the JSON's
    ``warnings``, so that the JSON says every warning the run printed."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.messages = []

    def emit(self, record):
        self.messages.append(record.getMessage())


def emit(args, result: dict, lines):
    """Print ``result`` as one JSON object with ``--json``, else the ``lines``. The warnings logged during the
    command (``args.warning_log``, a ``WarningLog``) join ``result["warnings"]`` first."""
    log = getattr(args, "warning_log", None)
    if log is not None and log.messages:
        said = list(result.get("warnings", []))
        result["warnings"] = said + [m for m in log.messages if m not in said]
    if getattr(args, "json", False):
        print(json.dumps(finite(result), indent=2, default=json_default, allow_nan=False))
    else:
        for line in lines:
            print(line)


def finite(x):
    """NaN and infinities as null: JSON has no such numbers."""
    if isinstance(x, dict):
        return {k: finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [finite(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if hasattr(x, "dtype") and getattr(x, "shape", None) == () and x.dtype.kind == "f":
        return finite(float(x))
    return x


def number_option(kind, low, low_inclusive=True, what="a number"):
    """An argparse type: a finite ``kind`` (int or float) above ``low``; argparse makes the error a
    one-line usage error (exit 2) naming the option."""
    def parse(text):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        if kind is float and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} must be a finite number")
        if value < low or (value == low and not low_inclusive):
            bound = f">= {low}" if low_inclusive else f"> {low}"
            raise argparse.ArgumentTypeError(f"{text!r} must be {bound}")
        return value

    parse.__name__ = what
    return parse


def stderr_progress(label, every=0.05):
    """A progress callback printing ``label: 42.0% ...`` to stderr every ``every`` of the way."""
    state = {"last": -1.0}

    def progress(fraction, *info):
        if fraction - state["last"] >= every or fraction >= 1.0:
            state["last"] = fraction
            extra = " ".join(f"{v:.5g}" if isinstance(v, float) else str(v) for v in info if v is not None)
            print(f"{label}: {100 * fraction:5.1f}% {extra}", file=sys.stderr, flush=True)
        return False

    return progress


def share_option(text):
    """An argparse type: a number in [0, 1]."""
    value = number_option(float, 0.0, what="a share")(text)
    if value > 1.0:
        raise argparse.ArgumentTypeError(f"{text!r} must be <= 1")
    return value
