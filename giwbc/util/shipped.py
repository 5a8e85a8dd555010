"""Where the data shipped with giwbc lies: the robot descriptions (``robots/``) and the trained
policies (``policies/``).

A wheel carries both as package data in ``giwbc/_data/`` (``setup.py`` maps the project's two
top-level folders there), so an installed giwbc finds them without its sources. In a source
checkout (``make install``: an editable install) they are the project's ``robots/`` and
``policies/`` folders themselves, edited in place.
"""

from __future__ import annotations

from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parents[1]  # the giwbc package
DATA_KINDS = ("robots", "policies")
POLICY_SUFFIX = ".onnx"


def shipped_folder(kind: str) -> Path | None:
    """The folder of shipped ``kind`` ("robots" or "policies"): the wheel's package data, else the
    source tree's (beside the package: a checkout, or a copy of one such as the mutation runs');
    ``None`` when neither exists."""
    if kind not in DATA_KINDS:
        raise ValueError(f"unknown kind of shipped data {kind!r}; expected one of {DATA_KINDS}")
    for folder in (PACKAGE_DIR / "_data" / kind, PACKAGE_DIR.parent / kind):
        if folder.is_dir():
            return folder
    return None


def shipped_policies() -> dict[str, Path]:
    """The shipped policy files by name (the file's stem), sorted by name."""
    folder = shipped_folder("policies")
    if folder is None:
        return {}
    return {path.stem: path for path in sorted(folder.glob(f"*{POLICY_SUFFIX}")) if path.is_file()}


def shipped_policy(name: str) -> Path | None:
    """The shipped policy called ``name`` (``"g1_balance_residual"``, with or without ``.onnx``), else ``None``."""
    stem = name[: -len(POLICY_SUFFIX)] if name.lower().endswith(POLICY_SUFFIX) else name
    return shipped_policies().get(stem)


def policy_by_name(text: str) -> Path | None:
    """The shipped policy ``text`` names when no such file exists: a bare name (``g1_walk_residual``,
    with or without ``.onnx``) or ``policies/<name>.onnx`` as the docs write it (an installed giwbc
    run outside the source tree); ``None`` otherwise (an existing file is always taken as given)."""
    path = Path(text)
    if path.exists() or not (len(path.parts) == 1 or (len(path.parts) == 2 and path.parts[0] == "policies")):
        return None
    return shipped_policy(path.name)


__all__ = ["DATA_KINDS", "policy_by_name", "shipped_folder", "shipped_policies", "shipped_policy"]
