"""Plant plug-ins: run the pipeline on a catheter simulator (or recording) we did not write.

A plug-in is a factory ``factory(seed: int, vessel: str) -> (plant, tracker)``, named on the
command line as ``MODULE:FACTORY`` (``MODULE`` an importable module, or the path of a
``.py`` file), e.g. ``--plant mylab.sofa_catheter:make`` or ``--plant ./replay.py:make``.
The stable protocol (docs/digital-twin.md, "Plant plug-ins"):

plant
    ``move(q_motor (4,)) -> tip2base (4, 4)``; ``move_along(q_path (n, 4)) -> (n, 4, 4)``
    (the same as n moves); ``reset(q_motor=None)`` (relax at ``q_motor``, default zeros);
    ``state.tip2base`` (4, 4), the pose now. Units mm and rad, ``q = (phi1, phi2, phi3, d4)``
    motor joint states. Optional: ``state.q_motor`` (4,) (the commanded joints; the
    ``field-distortion`` tracker reads the robot's roll from it), ``backbone(n) -> (n, 3)``
    (drawn by the console; without it the console draws no true shape), ``geometry``
    (a :class:`~icenav.geometry.kinematics.CatheterGeometry`: the joint limits the simulated
    robot enforces; without it the default geometry's).
tracker
    ``measure_tip2base(n_average=1) -> (4, 4) | None`` (the tracked tip in the base frame,
    averaged over ``n_average`` fresh samples; None when none was valid); ``get_frame() ->
    TrackerFrame``; ``start()``, ``stop()``; ``registration`` (a
    :class:`~icenav.devices.registration.Registration`: ``tracker2base`` and
    ``sensor2tip``).
factory
    ``factory(seed, vessel)``: ``seed`` an integer >= 0 (the catheter), ``vessel`` one of
    ``straight``, ``moderate``, ``steep``. Optionally a keyword ``clock`` (a callable
    returning seconds): the simulated clock a closed-loop run drives; a factory without it
    is called without it.

Everything else the pipeline needs it asks through the robot and tracker protocols, never a
plant's parameters. :func:`load_factory` imports a spec, :func:`make_plant` calls a factory
and checks what it returns (:func:`check_plant`, :func:`check_tracker`), raising
:class:`~icenav.errors.PluginError` that names the spec and what is missing.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav.errors import PluginError
from icenav.sim.families import family

__all__ = [
    "PlantFactory",
    "PluginPlant",
    "PluginTracker",
    "check_plant",
    "check_tracker",
    "load_factory",
    "make_plant",
    "resolve_factory",
]

PlantFactory = Callable[..., tuple[Any, Any]]
"""``factory(seed, vessel[, clock=...]) -> (plant, tracker)``."""

VESSELS = ("straight", "moderate", "steep")


@runtime_checkable
class PluginPlant(Protocol):
    """The plant side of the protocol (the module docstring says what each returns)."""

    def move(self, q_motor: ArrayLike) -> NDArray[np.float64]: ...

    def move_along(self, q_path: ArrayLike) -> NDArray[np.float64]: ...

    def reset(self, q_motor: ArrayLike | None = None) -> None: ...

    @property
    def state(self) -> Any: ...


@runtime_checkable
class PluginTracker(Protocol):
    """The tracker side of the protocol."""

    def measure_tip2base(self, n_average: int = 1) -> NDArray[np.float64] | None: ...

    def get_frame(self) -> Any: ...

    def start(self) -> None: ...

    def stop(self) -> None: ...

    @property
    def registration(self) -> Any: ...


# --- loading --------------------------------------------------------------------------------


def _split(spec: str) -> tuple[str, str]:
    if not isinstance(spec, str) or not spec.strip():
        raise PluginError(f"a plant plug-in is MODULE:FACTORY, got {spec!r}")
    module, sep, name = spec.strip().rpartition(":")
    if not sep or not module or not name:
        raise PluginError(
            f"a plant plug-in is MODULE:FACTORY (an importable module or a .py file, a colon, "
            f"the factory's name), got {spec!r}"
        )
    if not name.isidentifier():
        raise PluginError(f"{spec!r}: the factory name {name!r} is not a Python identifier")
    return module, name


def _import_file(path: Path, spec: str) -> Any:
    if not path.is_file():
        raise PluginError(f"{spec!r}: no such file {str(path)!r}")
    # a stable module name per file, registered in sys.modules so its classes pickle
    digest = hashlib.sha1(str(path).encode()).hexdigest()[:10]
    name = f"icenav_plugin_{path.stem}_{digest}"
    if name in sys.modules:
        return sys.modules[name]
    module_spec = importlib.util.spec_from_file_location(name, path)
    if module_spec is None or module_spec.loader is None:
        raise PluginError(f"{spec!r}: {str(path)!r} cannot be imported as a Python module")
    module = importlib.util.module_from_spec(module_spec)
    sys.modules[name] = module
    try:
        module_spec.loader.exec_module(module)
    except Exception as exc:
        del sys.modules[name]
        raise PluginError(
            f"{spec!r}: importing {str(path)!r} failed: {type(exc).__name__}: {exc}"
        ) from exc
    return module


def load_factory(spec: str) -> PlantFactory:
    """The factory named by ``spec`` = ``MODULE:FACTORY``.

    ``MODULE`` is a dotted module name on the import path, or the path of a ``.py`` file
    (recognised by the suffix or a path separator). Raises PluginError naming the spec and
    what failed: no colon, no such module or file, an import error inside it, no such
    attribute (listing the callables it has), or an attribute that is not callable.
    """
    module_name, name = _split(spec)
    if module_name.endswith(".py") or "/" in module_name or "\\" in module_name:
        module = _import_file(Path(module_name).expanduser().resolve(), spec)
    else:
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name is not None and module_name.startswith(exc.name):
                raise PluginError(
                    f"{spec!r}: no module named {module_name!r} on the import path "
                    f"(a file needs its path, e.g. ./{module_name.replace('.', '/')}.py)"
                ) from exc
            raise PluginError(f"{spec!r}: importing {module_name!r} failed: {exc}") from exc
        except Exception as exc:
            raise PluginError(
                f"{spec!r}: importing {module_name!r} failed: {type(exc).__name__}: {exc}"
            ) from exc
    factory = getattr(module, name, None)
    if factory is None:
        have = sorted(k for k, v in vars(module).items() if callable(v) and not k.startswith("_"))
        raise PluginError(
            f"{spec!r}: module {module_name!r} has no {name!r}; its public callables: "
            f"{', '.join(have) or 'none'}"
        )
    if not callable(factory):
        raise PluginError(
            f"{spec!r}: {name!r} is a {type(factory).__name__}, not a callable "
            "factory(seed, vessel) -> (plant, tracker)"
        )
    return factory


def resolve_factory(plant: str | None = None, plant_family: str | None = None) -> PlantFactory:
    """The factory the command line asks for: ``--plant MODULE:FACTORY`` or
    ``--plant-family NAME`` (at most one; neither: the default twin)."""
    if plant is not None and plant_family is not None:
        raise PluginError("give --plant MODULE:FACTORY or --plant-family NAME, not both")
    if plant is not None:
        return load_factory(plant)
    return family("default" if plant_family is None else plant_family)


# --- checking -------------------------------------------------------------------------------


def _where(spec: str) -> str:
    return f"{spec}: " if spec else ""


def _callable_with(obj: Any, attr: str, args: tuple[Any, ...], kwargs: dict[str, Any]) -> str:
    """'' if ``obj.attr`` exists and accepts ``args``/``kwargs``; else what is wrong."""
    missing = object()
    fn = getattr(obj, attr, missing)
    if fn is missing:
        return f"has no {attr}()"
    if not callable(fn):
        return f"has {attr}, but it is a {type(fn).__name__}, not a method"
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return ""  # a builtin without a signature: trust it
    try:
        sig.bind(*args, **kwargs)
    except TypeError as exc:
        return f"has {attr}{sig}, which cannot be called as the protocol calls it ({exc})"
    return ""


def _pose(value: Any, what: str, spec: str) -> None:
    arr = np.asarray(value, dtype=np.float64) if value is not None else None
    if arr is None or arr.shape != (4, 4) or not np.all(np.isfinite(arr)):
        shape = None if arr is None else arr.shape
        raise PluginError(
            f"{_where(spec)}{what} must be a finite (4, 4) transform (mm), got "
            f"{type(value).__name__} of shape {shape}"
        )


def check_plant(plant: Any, spec: str = "", probe: bool = False) -> None:
    """Check ``plant`` against the protocol (module docstring); PluginError naming each
    missing or wrong part. Without ``probe`` nothing is called that changes the plant; with
    it the plant is reset, moved to zero and along a two-state path, and reset again."""
    zeros = np.zeros(4)
    problems = [
        f"plant {p}"
        for p in (
            _callable_with(plant, "move", (zeros,), {}),
            _callable_with(plant, "move_along", (np.zeros((2, 4)),), {}),
            _callable_with(plant, "reset", (), {}),
            _callable_with(plant, "reset", (zeros,), {}),
        )
        if p
    ]
    missing: Any = object()
    try:
        state = getattr(plant, "state", missing)
    except Exception as exc:
        problems.append(f"plant.state raised {type(exc).__name__}: {exc}")
        state = missing
    if state is missing:
        problems.append("plant has no state (with state.tip2base, the (4, 4) pose now)")
    elif not hasattr(state, "tip2base"):
        problems.append("plant.state has no tip2base (the (4, 4) pose now, mm)")
    if problems:
        raise PluginError(
            f"{_where(spec)}the plant ({type(plant).__name__}) does not follow the protocol: "
            + "; ".join(dict.fromkeys(problems))
        )
    _pose(getattr(state, "tip2base", None), "plant.state.tip2base", spec)
    if probe:
        plant.reset()
        _pose(plant.move(zeros), "plant.move(q) (the returned tip2base)", spec)
        path = np.asarray(plant.move_along(np.zeros((2, 4))), dtype=np.float64)
        if path.shape != (2, 4, 4) or not np.all(np.isfinite(path)):
            raise PluginError(
                f"{_where(spec)}plant.move_along(q_path (n, 4)) must return (n, 4, 4) poses, "
                f"got shape {path.shape} for n = 2"
            )
        plant.reset()


def check_tracker(tracker: Any, spec: str = "") -> None:
    """Check ``tracker`` against the protocol; PluginError naming each missing part.
    Nothing is called that samples (the tracker's random stream is left untouched)."""
    problems = [
        f"tracker {p}"
        for p in (
            _callable_with(tracker, "measure_tip2base", (), {"n_average": 1}),
            _callable_with(tracker, "get_frame", (), {}),
            _callable_with(tracker, "start", (), {}),
            _callable_with(tracker, "stop", (), {}),
        )
        if p
    ]
    try:
        reg = tracker.registration
    except AttributeError:
        problems.append(
            "tracker has no registration (tracker2base and sensor2tip, "
            "icenav.devices.registration.Registration)"
        )
        reg = None
    if problems:
        raise PluginError(
            f"{_where(spec)}the tracker ({type(tracker).__name__}) does not follow the "
            "protocol: " + "; ".join(problems)
        )
    for attr in ("tracker2base", "sensor2tip"):
        _pose(getattr(reg, attr, None), f"tracker.registration.{attr}", spec)


def _accepts_clock(factory: PlantFactory) -> bool:
    try:
        params = inspect.signature(factory).parameters
    except (TypeError, ValueError):
        return False
    return "clock" in params or any(p.kind is p.VAR_KEYWORD for p in params.values())


def make_plant(
    factory: PlantFactory | str,
    seed: int,
    vessel: str = "straight",
    *,
    clock: Callable[[], float] | None = None,
    probe: bool = False,
) -> tuple[Any, Any]:
    """Call a factory (or a ``MODULE:FACTORY`` spec, or a family name) for catheter
    ``seed`` in ``vessel`` and check the plant and tracker it returns.

    ``clock`` is passed only to a factory that takes it (PluginError if it does not and a
    clock was asked for). Errors of the factory itself are wrapped in PluginError naming the
    spec (the original chained). Returns ``(plant, tracker)``.
    """
    spec = ""
    if isinstance(factory, str):
        spec = factory
        factory = load_factory(factory) if ":" in factory else family(factory)
    else:
        spec = getattr(factory, "name", None) or getattr(factory, "__qualname__", "") or ""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise PluginError(f"{_where(spec)}seed must be an integer >= 0, got {seed!r}")
    if vessel not in VESSELS:
        raise PluginError(f"{_where(spec)}vessel must be one of {VESSELS}, got {vessel!r}")
    kwargs: dict[str, Any] = {}
    if clock is not None:
        if not _accepts_clock(factory):
            raise PluginError(
                f"{_where(spec)}a clock was asked for, but the factory takes no clock= keyword"
            )
        kwargs["clock"] = clock
    try:
        made = factory(int(seed), vessel, **kwargs)
    except PluginError:
        raise
    except Exception as exc:
        raise PluginError(
            f"{_where(spec)}the factory raised {type(exc).__name__} for seed {seed}, "
            f"vessel {vessel!r}: {exc}"
        ) from exc
    if not isinstance(made, tuple) or len(made) != 2:
        raise PluginError(
            f"{_where(spec)}the factory must return a (plant, tracker) pair, got "
            f"{type(made).__name__}"
            + (f" of length {len(made)}" if isinstance(made, tuple | list) else "")
        )
    plant, tracker = made
    check_plant(plant, spec, probe=probe)
    check_tracker(tracker, spec)
    return plant, tracker
