"""Evaluations that reproduce (and extend) the paper's tables on the digital twin.

``icenav eval <name>`` dispatches to ``icenav.eval.<name>:main(argv)``.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence

__all__ = ["EVALUATIONS", "main"]

EVALUATIONS: dict[str, tuple[str, str]] = {
    "spin": (
        "icenav.eval.spin_cli",
        "image spinning with elasticity/hysteresis compensation (Table I, Figs. 5 and 7)",
    ),
    "recovery": (
        "icenav.eval.recovery",
        "view recovery to the aortic, mitral and tricuspid valve views, open loop and "
        "image-refined (Table II, Figs. 8-10)",
    ),
}
"""name -> (module with main(argv), one-line help)."""


def main(argv: Sequence[str] | None = None) -> int:
    """``icenav eval <name> [options]``."""
    args = list(argv or [])
    if not args or args[0] in ("-h", "--help"):
        print("usage: icenav eval <name> [options]\n\nevaluations:")
        for name, (_, text) in EVALUATIONS.items():
            print(f"  {name}  {text}")
        if not EVALUATIONS:
            print("  (none yet)")
        return 0
    if args[0] not in EVALUATIONS:
        print(f"icenav eval: unknown evaluation {args[0]!r}", file=sys.stderr)
        return 2
    module = importlib.import_module(EVALUATIONS[args[0]][0])
    code: int = module.main(args[1:])
    return code
