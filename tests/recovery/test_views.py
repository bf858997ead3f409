"""View and ViewLibrary: validation, add / rename / delete / list."""

from __future__ import annotations

import numpy as np
import pytest

from icenav.errors import IcenavError, InvalidValueError, NonFiniteError
from icenav.geometry.kinematics import forward
from icenav.recovery.views import View, ViewExistsError, ViewLibrary, ViewNotFoundError


def make(name: str, d4: float = 0.0, **kw: object) -> View:
    return View(name=name, q=np.array([0.1, -0.2, 0.3, d4]), vertex=3, created_s=1.5, **kw)  # type: ignore[arg-type]


def test_view_is_validated_and_read_only() -> None:
    pose = forward([0.1, -0.2, 0.3, 0.0])
    thumb = np.zeros((8, 12), np.uint8)
    v = make("aortic valve", tip2base=pose, thumbnail=thumb, arrival_direction=(1, -1, 0, 1))
    assert v.q.flags.writeable is False
    with pytest.raises(ValueError, match="read-only"):
        v.q[0] = 1.0
    np.testing.assert_array_equal(v.tip2base, pose)
    with pytest.raises(InvalidValueError, match="non-empty"):
        make("  ")
    with pytest.raises(NonFiniteError, match="finite"):
        View(name="x", q=np.array([0, 0, np.nan, 0]), vertex=0, created_s=0)
    with pytest.raises(InvalidValueError, match="arrival_direction"):
        make("x", arrival_direction=(2, 0, 0, 0))
    with pytest.raises(InvalidValueError, match="thumbnail"):
        make("x", thumbnail=np.zeros((4, 4), np.float32))
    with pytest.raises(IcenavError, match="rigid"):
        make("x", tip2base=2 * np.eye(4))


def test_library_add_rename_delete_list() -> None:
    lib = ViewLibrary()
    a, b, c = make("a", 1.0), make("b", 2.0), make("c", 3.0)
    for v in (a, b, c):
        lib.add(v)
    assert lib.names() == ["a", "b", "c"] and len(lib) == 3 and "b" in lib
    with pytest.raises(ViewExistsError, match="already exists"):
        lib.add(make("a"))
    renamed = lib.rename("b", "mitral")
    assert renamed.name == "mitral" and renamed.q[3] == 2.0
    assert lib.names() == ["a", "mitral", "c"]  # keeps its place
    with pytest.raises(ViewExistsError, match="already exists"):
        lib.rename("a", "c")
    assert lib.delete("a") is a
    assert [v.name for v in lib] == ["mitral", "c"]
    with pytest.raises(ViewNotFoundError, match="no view named 'a'"):
        lib.get("a")
    with pytest.raises(KeyError):
        lib.delete("a")
    assert lib.get("c") is c
