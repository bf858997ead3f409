"""The one error tree: every exception icenav raises derives from IcenavError."""

from __future__ import annotations

import ast
import builtins
import importlib
import inspect
from pathlib import Path

import icenav
from icenav import errors
from icenav.errors import IcenavError

SRC = Path(icenav.__file__).parent
# raised on purpose, as a protocol asks: Python's (a module's __getattr__ raises
# AttributeError) and canopen's (an SDO callback of a LocalNode aborts with SdoAbortedError)
ALLOWED = {"AttributeError", "StopIteration", "NotImplementedError", "SdoAbortedError"}


def _modules() -> list[str]:
    out = []
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out.append(".".join(parts))
    return out


def _raised_names(tree: ast.AST) -> list[tuple[str, int]]:
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Raise) and node.exc is not None:
            exc = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
            if isinstance(exc, ast.Name):
                names.append((exc.id, node.lineno))
            elif isinstance(exc, ast.Attribute):
                names.append((exc.attr, node.lineno))
    return names


def test_every_exception_class_raised_in_src_derives_from_icenav_error() -> None:
    bad = []
    for name in _modules():
        module = importlib.import_module(name)
        path = Path(module.__file__ or "")
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for exc_name, line in _raised_names(tree):
            obj = getattr(module, exc_name, None)
            if obj is None:
                obj = getattr(builtins, exc_name, None)
            if not inspect.isclass(obj):
                continue  # a re-raise of a caught instance (``raise exc``)
            if issubclass(obj, IcenavError) or obj.__name__ in ALLOWED:
                continue
            bad.append(f"{path.relative_to(SRC.parent)}:{line}: raises {obj.__name__}")
    assert not bad, "exceptions outside the IcenavError tree:\n" + "\n".join(bad)


def test_every_exception_class_defined_in_src_is_in_the_tree_and_drawn() -> None:
    drawn = errors.__doc__ or ""
    bad = []
    for name in _modules():
        module = importlib.import_module(name)
        for cls_name, cls in vars(module).items():
            if not (inspect.isclass(cls) and issubclass(cls, BaseException)):
                continue
            if cls.__module__ != module.__name__:
                continue
            if not issubclass(cls, IcenavError):
                bad.append(f"{name}.{cls_name} does not derive from IcenavError")
            elif module is not errors and cls_name not in drawn:
                bad.append(f"{name}.{cls_name} is not drawn in the errors.py tree")
    assert not bad, "\n".join(bad)
