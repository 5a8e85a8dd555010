"""Argument types and help formatting shared by every ``giwbc`` command.

Every numeric option is validated by its argparse ``type`` before anything starts: argparse then
prints one usage line and exits 2, so a bad number can never reach a controller or a motor.
Each type says what it accepts (``finite number in [0, 60] s``) in its error message, and the
help formatter shows every default.
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from giwbc.util.shipped import policy_by_name, shipped_policies


class HelpFormatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """Descriptions kept as written, defaults shown (``(default: 10.0)``) after every option's help."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        help_text = action.help or ""
        if action.default is None or action.default is False or action.default is argparse.SUPPRESS or "%(default)" in help_text:
            return help_text
        if action.option_strings or action.nargs in (argparse.OPTIONAL, argparse.ZERO_OR_MORE):
            return f"{help_text} (default: %(default)s)" if help_text else "(default: %(default)s)"
        return help_text


def add_command(commands: Any, name: str, help: str, description: str | None = None) -> argparse.ArgumentParser:
    """A subcommand with giwbc's help formatter (subparsers do not inherit ``formatter_class``)."""
    return commands.add_parser(name, help=help, description=description or help, formatter_class=HelpFormatter)


def _bound(value: float) -> str:
    """A bound as a person writes it: integers in full (4294967295, not 4.29497e+09)."""
    return str(int(value)) if float(value).is_integer() and abs(value) < 1e15 else f"{value:g}"


def _interval(low: float | None, high: float | None, low_open: bool, high_open: bool) -> str:
    if low is not None and high is not None:
        return f"in {'(' if low_open else '['}{_bound(low)}, {_bound(high)}{')' if high_open else ']'}"
    if low is not None:
        return f"{'>' if low_open else '>='} {_bound(low)}"
    if high is not None:
        return f"{'<' if high_open else '<='} {_bound(high)}"
    return ""


def number(
    low: float | None = None,
    high: float | None = None,
    *,
    unit: str = "",
    low_open: bool = False,
    high_open: bool = False,
    integer: bool = False,
) -> Callable[[str], float]:
    """An argparse ``type``: a finite number (an integer with ``integer``) within [low, high]
    (``low_open`` / ``high_open``: the bound itself excluded). NaN and ±inf are always refused."""
    kind = "an integer" if integer else "a finite number"
    what = " ".join(part for part in (kind, _interval(low, high, low_open, high_open), unit) if part)

    def parse(text: str) -> float:
        try:
            value: Any = int(text, 0) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if not integer and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        too_low = low is not None and (value <= low if low_open else value < low)
        too_high = high is not None and (value >= high if high_open else value > high)
        if too_low or too_high:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return value

    parse.__name__ = "integer" if integer else "number"  # argparse names the type in its messages
    return parse


def integer(low: int | None = None, high: int | None = None, *, unit: str = "") -> Callable[[str], int]:
    """An argparse ``type``: an integer within [low, high]."""
    return number(low, high, unit=unit, integer=True)  # type: ignore[return-value]


def seconds(high: float, *, low: float = 0.0, allow_zero: bool = False) -> Callable[[str], float]:
    """A duration in seconds: finite, > 0 (>= 0 with ``allow_zero``) and at most ``high``."""
    return number(low, high, unit="s", low_open=not allow_zero)


def existing_file(*suffixes: str) -> Callable[[str], str]:
    """An argparse ``type``: a path to a readable, non-empty file (with one of ``suffixes`` when given)."""

    def parse(text: str) -> str:
        path = Path(text)
        if suffixes and path.suffix.lower() not in suffixes:
            raise argparse.ArgumentTypeError(f"{text}: expected a {' or '.join(suffixes)} file")
        if not path.is_file():
            raise argparse.ArgumentTypeError(f"{text}: no such file")
        if not os.access(path, os.R_OK):
            raise argparse.ArgumentTypeError(f"{text}: not readable")
        if path.stat().st_size == 0:
            raise argparse.ArgumentTypeError(f"{text}: empty file")
        return text

    parse.__name__ = "file"
    return parse


def policy_file() -> Callable[[str], str]:
    """An argparse ``type``: a policy .onnx file, or a shipped policy by name (``g1_balance_residual``,
    with or without ``.onnx``). ``policies/<name>.onnx``, as the docs write it, is the shipped one
    when no such file exists here (an installed giwbc run outside the source tree)."""
    check = existing_file(".onnx")

    def parse(text: str) -> str:
        shipped = policy_by_name(text)
        if shipped is not None:
            return str(shipped)
        try:
            return check(text)
        except argparse.ArgumentTypeError as error:
            names = ", ".join(shipped_policies()) or "none"
            raise argparse.ArgumentTypeError(f"{error}, and not a shipped policy (shipped: {names})") from None

    parse.__name__ = "policy"
    return parse


POLICY_HELP = "policy: a .onnx file written by `giwbc train`, or a shipped policy's name (e.g. g1_balance_residual)"
ROBOT_HELP = "robot: a name listed by `giwbc robots`, or a robot folder / robot.toml path"
SEED_MAX = 2**32 - 1  # numpy's SeedSequence takes any non-negative integer; this keeps seeds printable and portable


def seed() -> Callable[[str], int]:
    """An episode / run seed: an integer in [0, 2**32 - 1]."""
    return integer(0, SEED_MAX)


def port() -> Callable[[str], int]:
    """A loopback TCP port a user process may listen on: an integer in [1024, 65535]."""
    return integer(1024, 65535)


__all__ = ["POLICY_HELP", "ROBOT_HELP", "SEED_MAX", "HelpFormatter", "add_command", "existing_file", "integer", "number", "policy_file", "port", "seconds", "seed"]
