"""The paper's published figures, shipped with icenav as package data.

``icenav/eval/data/paper_results.json`` is a copy of the numbers of the paper's tables and
text (Table I, Table II, the phantom EM result, the tracker's accuracy, the geometry), so
every evaluation prints the paper's row beside ours on any machine.
"""

from __future__ import annotations

import json
from functools import cache
from importlib import resources
from typing import Any

from icenav.errors import FileFormatError

__all__ = ["paper_results"]


@cache
def paper_results() -> dict[str, Any]:
    """The whole ``paper_results.json`` document (read once)."""
    path = resources.files("icenav.eval") / "data" / "paper_results.json"
    try:
        doc: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # a broken install
        raise FileFormatError(f"cannot read the paper's figures from {path}: {exc}") from exc
    return doc
