"""The layout's arrows point one way: a test walks every import of ``src/icenav``.

Layers (docs/architecture.md): a package may import only the packages listed for it (and
itself). The core (geometry, compensation, calibration, recovery, refinement, control) imports
no I/O, no twin, no evaluation and no console; the twin (``sim``) imports no method of ours
(compensation, calibration, refinement, control), so it cannot copy what it is used to test.
"""

from __future__ import annotations

import ast
from pathlib import Path

import icenav

SRC = Path(icenav.__file__).parent

BASE = {"icenav", "icenav.errors", "icenav._typing", "icenav._validation"}
PROTOCOLS = {"icenav.devices.robot", "icenav.devices.tracker", "icenav.devices.registration"}
"""Device protocols and values (no I/O) that the core may use."""

ALLOWED: dict[str, set[str]] = {
    "geometry": BASE,
    "compensation": BASE | {"geometry"},
    "calibration": BASE | PROTOCOLS | {"geometry", "compensation"},
    "recovery": BASE | {"geometry"},
    "refinement": BASE | PROTOCOLS | {"geometry", "compensation", "recovery"},
    "control": BASE
    | PROTOCOLS
    | {"geometry", "compensation", "calibration", "recovery", "refinement"},
    "devices": BASE | {"geometry"},
    "persistence": BASE | PROTOCOLS | {"geometry", "compensation", "recovery", "control"},
    "io": BASE | {"geometry", "control"},
    "sim": BASE | PROTOCOLS | {"geometry", "recovery"},
    "console": BASE
    | PROTOCOLS
    | {"geometry", "compensation", "recovery", "control", "persistence", "devices"},
    "eval": BASE
    | {
        "geometry",
        "compensation",
        "calibration",
        "recovery",
        "refinement",
        "control",
        "devices",
        "persistence",
        "sim",
    },
    "apps": {"*"},
    "gym": BASE | {"geometry", "compensation", "calibration", "recovery", "refinement", "control",
                   "devices", "sim"},
}  # fmt: skip
"""package -> what it may import ("geometry" means icenav.geometry and its modules)."""


def _package(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _imports(path: Path) -> list[tuple[str, int]]:
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names if a.name.startswith("icenav")]
        elif (
            isinstance(node, ast.ImportFrom)
            and node.level == 0
            and (node.module or "").startswith("icenav")
        ):
            out.append((str(node.module), node.lineno))
    return out


def _allowed(target: str, rules: set[str]) -> bool:
    if "*" in rules or target in rules:
        return True
    return any(
        target == f"icenav.{p}" or target.startswith(f"icenav.{p}.")
        for p in rules
        if not p.startswith("icenav")
    ) or any(target.startswith(r + ".") for r in rules if r.startswith("icenav."))


def wrong_way_arrows() -> list[str]:
    bad = []
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC.parent).with_suffix("")
        module = ".".join(p for p in rel.parts if p != "__init__")
        pkg = _package(module)
        if pkg not in ALLOWED:
            continue  # top-level modules (errors, _typing, _validation, app)
        rules = ALLOWED[pkg] | {pkg}
        for target, line in _imports(path):
            if _package(target) == pkg or _allowed(target, rules):
                continue
            bad.append(f"{rel}.py:{line}: {module} imports {target}")
    return bad


def test_every_package_is_in_the_layer_table() -> None:
    packages = {p.name for p in SRC.iterdir() if (p / "__init__.py").exists()}
    assert packages <= set(ALLOWED), f"add {packages - set(ALLOWED)} to ALLOWED"


KNOWN: set[str] = set()
"""Wrong-way arrows left by the layout move (all gone): a new one fails at once."""


def test_no_import_points_the_wrong_way() -> None:
    bad = [b for b in wrong_way_arrows() if b.split(": ", 1)[1] not in KNOWN]
    assert not bad, "imports against the layering:\n" + "\n".join(bad)
    fixed = KNOWN - {b.split(": ", 1)[1] for b in wrong_way_arrows()}
    assert not fixed, f"fixed: remove from KNOWN: {sorted(fixed)}"


def test_the_checker_sees_a_wrong_way_arrow() -> None:
    assert not _allowed("icenav.sim.plant", ALLOWED["compensation"] | {"compensation"})
    assert not _allowed("icenav.eval.metrics", ALLOWED["refinement"] | {"refinement"})
    assert _allowed("icenav.geometry.kinematics", ALLOWED["compensation"])
    assert _allowed("icenav.devices.robot", ALLOWED["calibration"])
    assert not _allowed("icenav.devices.canopen.robot", ALLOWED["calibration"])
