"""Reading TOML configuration files with clear errors: one set of helpers for every config file
(``robot.toml``, ``hardware.toml``).

A :class:`TomlPlace` is a place in a file (``where``: the file and the table, the prefix of every
message) and the error class its problems raise (a :class:`~giwbc.errors.ConfigError`); its
methods read one key of a table and say exactly what is wrong with it.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from giwbc.errors import ConfigError


def parse_toml(text: str, source: str, error: type[ConfigError]) -> dict[str, Any]:
    """The tables of TOML ``text``; ``error`` naming ``source`` when it is not valid TOML."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{source}: invalid TOML: {e}") from e


def load_toml(path: Path, error: type[ConfigError]) -> dict[str, Any]:
    """:func:`parse_toml` of the file at ``path`` (``error`` when it cannot be read or is not UTF-8 text)."""
    try:
        with Path(path).open("rb") as stream:
            data = stream.read()
        text = data.decode()
    except (OSError, UnicodeDecodeError) as e:
        raise error(f"{path}: cannot read it as text: {e}") from e
    return parse_toml(text, str(path), error)


@dataclass(frozen=True)
class TomlPlace:
    """A table's place in a config file, for reading its keys (see the module docstring)."""

    where: str
    error: type[ConfigError]

    def fail(self, message: str) -> ConfigError:
        """The error for ``message`` here (to raise)."""
        return self.error(f"{self.where}: {message}")

    def check_keys(self, table: Any, allowed: set[str], required: Iterable[str] = ()) -> None:
        """``table`` is a table of ``allowed`` keys holding every ``required`` one."""
        if not isinstance(table, Mapping):
            raise self.fail(f"expected a table, got {type(table).__name__}")
        unknown = sorted(set(table) - allowed)
        if unknown:
            raise self.fail(f"unknown key(s) {unknown}; allowed: {sorted(allowed)}")
        absent = [k for k in required if k not in table]
        if absent:
            raise self.fail(f"missing key(s) {absent}")

    def require(self, table: Mapping[str, Any], key: str, kind: type | tuple[type, ...]) -> Any:
        """``table[key]``, which must exist and be a ``kind`` (a bool is no number)."""
        if key not in table:
            raise self.fail(f"missing required key {key!r}")
        value = table[key]
        if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
            raise self.fail(f"key {key!r} should be {getattr(kind, '__name__', kind)}, got {value!r}")
        return value

    def number(self, table: Mapping[str, Any], key: str, default: float) -> float:
        """``table[key]`` (``default`` when absent) as a finite float."""
        value = table.get(key, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(f"{key!r} should be a finite number, got {value!r}")
        return float(value)

    def string(self, table: Mapping[str, Any], key: str) -> str:
        """``table[key]`` as a non-empty string."""
        value = table[key]
        if not isinstance(value, str) or not value:
            raise self.fail(f"{key!r} should be a non-empty string, got {value!r}")
        return value

    def integer(self, table: Mapping[str, Any], key: str) -> int:
        """``table[key]`` as an integer (not a bool)."""
        value = table[key]
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(f"{key!r} should be an integer, got {value!r}")
        return value


__all__ = ["TomlPlace", "load_toml", "parse_toml"]
