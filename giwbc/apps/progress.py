"""Progress bars for the long commands (episodes done, rate, time left), with tqdm on stderr.

A bar is drawn only when the stream it writes to is a terminal and ``--no-progress`` was not given:
piped output and CI logs stay clean, and stdout keeps only the command's results (tables, JSON).
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import IO, Any

from tqdm import tqdm


def add_progress_argument(parser: argparse.ArgumentParser) -> None:
    """``--no-progress``: no bar even on a terminal."""
    parser.add_argument("--no-progress", action="store_true",
                        help="no progress bar (there is none anyway when stderr is not a terminal)")


def wants_progress(args: argparse.Namespace | None = None, stream: IO[str] | None = None) -> bool:
    """Whether a bar should be drawn: ``stream`` (stderr by default) is a terminal and ``--no-progress`` is not set."""
    stream = sys.stderr if stream is None else stream
    if args is not None and getattr(args, "no_progress", False):
        return False
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # a closed or exotic stream
        return False


DEFAULT_COLUMNS, DEFAULT_ROWS = 100, 24  # for a terminal that reports no size (tqdm would hide its bar)


def _smallest_side(stream: IO[str]) -> int:
    try:
        size = os.get_terminal_size(stream.fileno())
        return min(size.columns, size.lines)
    except (AttributeError, OSError, ValueError):
        return 0


class Progress:
    """A bar of ``total`` units; calling it with ``n`` advances it. Disabled, every call does nothing."""

    def __init__(self, total: float, description: str, *, unit: str = "episode", enabled: bool = True,
                 stream: IO[str] | None = None) -> None:  # fmt: skip
        self._bar: Any = None
        if enabled:
            stream = sys.stderr if stream is None else stream
            sized = _smallest_side(stream) > 0  # a pseudo-terminal nobody sized reports 0 columns
            self._bar = tqdm(total=total, desc=description, unit=unit, file=stream, dynamic_ncols=sized,
                             ncols=None if sized else DEFAULT_COLUMNS, nrows=None if sized else DEFAULT_ROWS, smoothing=0.1, leave=True)

    @property
    def enabled(self) -> bool:
        return self._bar is not None

    def __call__(self, n: float = 1) -> None:
        if self._bar is not None:
            self._bar.update(n)

    def describe(self, text: str) -> None:
        """Change what the bar says it is doing (e.g. which push force or condition)."""
        if self._bar is not None:
            self._bar.set_description(text, refresh=False)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
