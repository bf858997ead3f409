"""Saved views ("bookmarks") and the view library (the paper's set V of Algorithm 1).

A :class:`View` is a recorded *motor* joint state the operator saved, with what is needed to
return to it: the roadmap vertex it sits on, the direction from which each joint arrived
(so a return takes up the transmission's backlash the same way), and the recorded trace
vertices that led to it (the same-direction approach). Optional: the true or estimated tip
pose, a thumbnail of the ultrasound image, notes.
"""

from __future__ import annotations

import builtins
from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from icenav._validation import check_joint_state, check_transform
from icenav.errors import InvalidValueError, ViewExistsError, ViewNotFoundError

__all__ = ["View", "ViewExistsError", "ViewLibrary", "ViewNotFoundError"]


@dataclass(frozen=True)
class View:
    """One saved view."""

    name: str
    """Unique, human-readable name (non-empty)."""
    q: NDArray[np.float64]
    """(4,) motor joint state (phi1 rad, phi2 rad, phi3 rad, d4 mm); read-only."""
    vertex: int
    """Id of the roadmap vertex holding exactly ``q``."""
    created_s: float
    """Time the view was saved (s, the controller's clock)."""
    arrival_direction: tuple[int, int, int, int] = (0, 0, 0, 0)
    """Sign (-1, 0, +1) of the last significant motion of each joint before saving
    (0: that joint has not moved significantly)."""
    approach: tuple[int, ...] = ()
    """Roadmap vertex ids of the recorded trace that led to the view, oldest first, ending
    at ``vertex``; replayed at the end of a return (empty: no approach recorded)."""
    tip2base: NDArray[np.float64] | None = None
    """(4, 4) pose of the image centre frame in the base frame (mm), if known."""
    thumbnail: NDArray[np.uint8] | None = None
    """(H, W) or (H, W, 3) uint8 thumbnail of the ultrasound image, if any."""
    notes: str = ""
    """Free text."""
    em_tip2base: NDArray[np.float64] | None = None
    """(4, 4) tracked tip pose in the base frame (mm) averaged over complete breaths / beats
    of the still catheter when the view was saved: the target of the EM refinement (None:
    no tracker, or the catheter was not held still long enough)."""

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise InvalidValueError(f"view name must be a non-empty string, got {self.name!r}")
        q = np.array(check_joint_state(self.q, name="view q"), dtype=np.float64)
        if q.shape != (4,):
            raise InvalidValueError(f"view q must have shape (4,), got {q.shape}")
        q.setflags(write=False)
        object.__setattr__(self, "q", q)
        if int(self.vertex) < 0:
            raise InvalidValueError(f"view vertex must be >= 0, got {self.vertex}")
        object.__setattr__(self, "vertex", int(self.vertex))
        direction = tuple(int(d) for d in self.arrival_direction)
        if len(direction) != 4 or any(d not in (-1, 0, 1) for d in direction):
            raise InvalidValueError(
                f"arrival_direction must be 4 values in (-1, 0, 1), got {self.arrival_direction!r}"
            )
        object.__setattr__(self, "arrival_direction", direction)
        object.__setattr__(self, "approach", tuple(int(v) for v in self.approach))
        if self.tip2base is not None:
            t = np.array(check_transform(self.tip2base, "view tip2base"), dtype=np.float64)
            if t.shape != (4, 4):
                raise InvalidValueError(f"view tip2base must have shape (4, 4), got {t.shape}")
            t.setflags(write=False)
            object.__setattr__(self, "tip2base", t)
        if self.em_tip2base is not None:
            e = np.array(check_transform(self.em_tip2base, "view em_tip2base"), np.float64)
            if e.shape != (4, 4):
                raise InvalidValueError(f"view em_tip2base must have shape (4, 4), got {e.shape}")
            e.setflags(write=False)
            object.__setattr__(self, "em_tip2base", e)
        if self.thumbnail is not None:
            img = np.array(self.thumbnail)
            if (
                img.dtype != np.uint8
                or img.ndim not in (2, 3)
                or (img.ndim == 3 and img.shape[2] != 3)
            ):
                raise InvalidValueError(
                    "view thumbnail must be a uint8 array of shape (H, W) or (H, W, 3), "
                    f"got dtype {img.dtype} shape {img.shape}"
                )
            img.setflags(write=False)
            object.__setattr__(self, "thumbnail", img)

    def renamed(self, name: str) -> View:
        """A copy of this view under another name."""
        return replace(self, name=name)


class ViewLibrary:
    """Named views in insertion order: add / rename / delete / get / list."""

    def __init__(self, views: list[View] | None = None) -> None:
        self._views: dict[str, View] = {}
        for v in views or []:
            self.add(v)

    def add(self, view: View) -> View:
        """Add ``view``; raises ViewExistsError if its name is taken."""
        if view.name in self._views:
            raise ViewExistsError(f"a view named {view.name!r} already exists")
        self._views[view.name] = view
        return view

    def get(self, name: str) -> View:
        """The view called ``name``; raises ViewNotFoundError."""
        try:
            return self._views[name]
        except KeyError:
            raise ViewNotFoundError(
                f"no view named {name!r}; views: {sorted(self._views)}"
            ) from None

    def rename(self, old: str, new: str) -> View:
        """Rename a view, keeping its place in the list."""
        view = self.get(old)
        if new == old:
            return view
        if new in self._views:
            raise ViewExistsError(f"a view named {new!r} already exists")
        renamed = view.renamed(new)
        self._views = {
            (new if k == old else k): (renamed if k == old else v) for k, v in self._views.items()
        }
        return renamed

    def delete(self, name: str) -> View:
        """Remove and return the view called ``name``."""
        view = self.get(name)
        del self._views[name]
        return view

    def list(self) -> builtins.list[View]:
        """All views in the order they were added."""
        return [*self._views.values()]

    def names(self) -> builtins.list[str]:
        """All view names in the order they were added."""
        return [*self._views]

    def __len__(self) -> int:
        return len(self._views)

    def __iter__(self) -> Iterator[View]:
        return iter(list(self._views.values()))

    def __contains__(self, name: object) -> bool:
        return name in self._views
