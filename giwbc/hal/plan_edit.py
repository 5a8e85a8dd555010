"""Writing calibration results into a hardware plan file: ``sign`` and ``zero_offset`` of named
joints' ``[[motors]]`` tables set in place (comments and layout kept), the new text validated as a
plan before it replaces the old one, the old one kept as ``<name>.bak-<UTC time>``."""

from __future__ import annotations

import os
import re
import shutil
from collections.abc import Callable, Mapping
from datetime import datetime, timezone
from pathlib import Path

from giwbc.errors import HardwareConfigError
from giwbc.hal.hardware import parse_hardware

_MOTORS_HEADER = re.compile(r"^\s*\[\[motors\]\]")
_TABLE_HEADER = re.compile(r"^\s*\[")


def update_plan_text(text: str, updates: Mapping[str, Mapping[str, float | int]], note: str = "") -> str:
    """``text`` with ``sign`` / ``zero_offset`` of the named joints' ``[[motors]]`` tables set
    (lines replaced in place, or added after the ``joint`` line), comments kept; ``note`` goes
    in a comment line above the changed values."""
    lines = text.splitlines(keepends=True)
    if lines and not lines[-1].endswith("\n"):
        lines[-1] += "\n"
    starts = [k for k, line in enumerate(lines) if _MOTORS_HEADER.match(line)]
    todo = dict(updates)
    for s in reversed(starts):  # from the end: earlier indexes stay valid
        e = next((k for k in range(s + 1, len(lines)) if _TABLE_HEADER.match(lines[k])), len(lines))
        block = lines[s:e]
        joint = next((m.group(1) for ln in block if (m := re.match(r'^\s*joint\s*=\s*"([^"]+)"', ln))), None)
        if joint not in todo:
            continue
        for key, value in todo.pop(joint).items():
            if key not in ("sign", "zero_offset"):
                raise ValueError(f"only sign and zero_offset are written, got {key!r}")
            rendered = f"{key} = {int(value)}\n" if key == "sign" else f"{key} = {float(value)!r}\n"
            at = next((k for k, ln in enumerate(block) if re.match(rf"^\s*{key}\s*=", ln)), None)
            if at is not None:
                block[at] = rendered
            else:
                at = next(k for k, ln in enumerate(block) if re.match(r"^\s*joint\s*=", ln))
                block.insert(at + 1, rendered)
        if note:
            first = min(k for k, ln in enumerate(block) if re.match(r"^\s*(sign|zero_offset)\s*=", ln))
            block.insert(first, f"# {note}\n")
        lines[s:e] = block
    if todo:
        raise HardwareConfigError(f"no [[motors]] table for joint(s) {sorted(todo)}")
    return "".join(lines)


def update_plan(
    path: str | Path,
    updates: Mapping[str, Mapping[str, float | int]],
    note: str,
    *,
    now: Callable[[], datetime] = lambda: datetime.now(timezone.utc),
) -> Path:
    """Write ``updates`` into the plan file after copying it to ``<name>.bak-<UTC time>``; the new
    text is validated (parsed as a plan) before it replaces the old one. Returns the backup."""
    p = Path(path)
    text = p.read_text(encoding="utf-8")
    stamp = now().strftime("%Y%m%dT%H%M%SZ")
    new = update_plan_text(text, updates, f"{note} ({stamp})")
    parse_hardware(new, source=str(p))  # never write a plan that does not load
    backup = p.with_name(f"{p.name}.bak-{stamp}")
    shutil.copy2(p, backup)
    tmp = p.with_name(f".{p.name}.tmp")
    tmp.write_text(new, encoding="utf-8")
    os.replace(tmp, p)
    return backup



__all__ = ["update_plan", "update_plan_text"]
