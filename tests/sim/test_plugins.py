"""Plant plug-ins: MODULE:FACTORY specs load from modules and files, and every way a spec or
the objects it makes can break the protocol gives a PluginError naming what is wrong."""

from __future__ import annotations

import pickle
import textwrap
from pathlib import Path

import numpy as np
import pytest

from icenav.errors import PluginError
from icenav.sim import CatheterPlant
from icenav.sim.families import FAMILIES, FamilyFactory
from icenav.sim.plugins import (
    check_plant,
    check_tracker,
    load_factory,
    make_plant,
    resolve_factory,
)

# A lab's plug-in: the constant-curvature model as the catheter, the twin's EM tracker.
GOOD = """
import numpy as np
from icenav.geometry.kinematics import forward
from icenav.sim.tracker import EMTracker

class State:
    def __init__(self, q):
        self.tip2base = forward(q)

class ModelCatheter:
    def __init__(self):
        self.reset()
    def reset(self, q_motor=None):
        self.q = np.zeros(4) if q_motor is None else np.asarray(q_motor, float)
    def move(self, q_motor):
        self.q = np.asarray(q_motor, float)
        return forward(self.q)
    def move_along(self, q_path):
        return np.array([self.move(q) for q in q_path])
    @property
    def state(self):
        return State(self.q)

def make(seed, vessel):
    plant = ModelCatheter()
    return plant, EMTracker(plant, seed=seed)

def make_with_clock(seed, vessel, clock=None):
    plant = ModelCatheter()
    return plant, EMTracker(plant, seed=seed, clock=clock)

NOT_CALLABLE = 3
"""


@pytest.fixture
def plugin(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The good plug-in as ``lab_catheter.py`` in a directory on the import path."""
    path = tmp_path / "lab_catheter.py"
    path.write_text(GOOD)
    monkeypatch.syspath_prepend(str(tmp_path))
    return path


def _write(tmp_path: Path, body: str) -> Path:
    """A plug-in file that imports the good one's pieces and changes what it says."""
    path = tmp_path / "variant.py"
    path.write_text(textwrap.dedent(GOOD + body))
    return path


def test_a_factory_loads_from_a_module_and_from_a_file(plugin: Path) -> None:
    by_module = load_factory("lab_catheter:make")
    by_path = load_factory(f"{plugin}:make")
    for factory in (by_module, by_path):
        plant, tracker = make_plant(factory, 3, "straight", probe=True)
        np.testing.assert_allclose(
            plant.move([0.3, 0.2, 0.1, 0.0])[:3, 3], plant.state.tip2base[:3, 3]
        )
        assert tracker.measure_tip2base() is not None
    # a spec string works directly, and loading the same file twice gives the same module
    assert make_plant(f"{plugin}:make", 1)[0].__class__.__name__ == "ModelCatheter"
    assert load_factory(f"{plugin}:make") is by_path


def test_family_names_and_specs_resolve() -> None:
    assert resolve_factory() == FAMILIES["default"]
    assert resolve_factory(plant_family="rate-dependent") == FamilyFactory("rate-dependent")
    factory = resolve_factory(plant="icenav.sim.families:FamilyFactory")
    assert factory is FamilyFactory  # (a class is a callable; calling it is the caller's business)
    with pytest.raises(PluginError, match="not both"):
        resolve_factory(plant="a:b", plant_family="default")
    plant, _ = make_plant("out-of-tolerance", 2)
    assert isinstance(plant, CatheterPlant)


def test_a_clock_goes_only_to_a_factory_that_takes_it(plugin: Path) -> None:
    now = [5.0]
    _, tracker = make_plant(f"{plugin}:make_with_clock", 0, clock=lambda: now[0])
    tracker.start()
    now[0] = 6.0
    assert tracker.get_frame().timestamp > 5.0  # the injected clock drives the sampling
    with pytest.raises(PluginError, match="takes no clock= keyword"):
        make_plant(f"{plugin}:make", 0, clock=lambda: 0.0)
    plant, _ = make_plant("rate-dependent", 0, clock=lambda: now[0])
    assert plant.clock is not None


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("", "MODULE:FACTORY"),
        ("lab_catheter", "MODULE:FACTORY"),
        ("lab_catheter:", "MODULE:FACTORY"),
        ("lab_catheter:make-it", "not a Python identifier"),
        ("no_such_module_xyz:make", "no module named 'no_such_module_xyz'"),
        ("./no/such/file.py:make", "no such file"),
        ("lab_catheter:missing", "has no 'missing'; its public callables: .*make"),
        ("lab_catheter:NOT_CALLABLE", "'NOT_CALLABLE' is a int, not a callable"),
    ],
)
def test_bad_specs_say_what_is_wrong(plugin: Path, spec: str, match: str) -> None:
    with pytest.raises(PluginError, match=match):
        load_factory(spec)


def test_an_import_error_inside_a_plugin_is_reported_with_its_spec(tmp_path: Path) -> None:
    path = tmp_path / "broken.py"
    path.write_text("import numpy as np\nraise RuntimeError('no licence for the solver')\n")
    with pytest.raises(
        PluginError, match="importing .*broken.py.* failed: RuntimeError: no licence"
    ):
        load_factory(f"{path}:make")


@pytest.mark.parametrize(
    ("body", "match"),
    [
        (
            "def bad(seed, vessel):\n    return ModelCatheter()\n",
            "must return a \\(plant, tracker\\) pair, got ModelCatheter",
        ),
        (
            "def bad(seed, vessel):\n    raise OSError('simulator not running')\n",
            "the factory raised OSError for seed 0, vessel 'straight': simulator not running",
        ),
        (
            "class P(ModelCatheter):\n    move_along = None\n"
            "def bad(seed, vessel):\n    p = P()\n    return p, EMTracker(p)\n",
            "plant has move_along, but it is a NoneType",
        ),
        (
            "class P(ModelCatheter):\n    def move(self):\n        return None\n"
            "def bad(seed, vessel):\n    p = P()\n    return p, EMTracker(p)\n",
            "plant has move\\(\\), which cannot be called as the protocol calls it",
        ),
        (
            "class P(ModelCatheter):\n    state = None\n"
            "def bad(seed, vessel):\n    p = P()\n    return p, EMTracker(ModelCatheter())\n",
            "plant.state has no tip2base",
        ),
        (
            "class S:\n    tip2base = np.eye(3)\n"
            "class P(ModelCatheter):\n    state = S()\n"
            "def bad(seed, vessel):\n    p = P()\n    return p, EMTracker(ModelCatheter())\n",
            "plant.state.tip2base must be a finite \\(4, 4\\) transform",
        ),
        (
            "class T:\n    def measure_tip2base(self, n_average=1):\n        return None\n"
            "def bad(seed, vessel):\n    return ModelCatheter(), T()\n",
            "tracker has no get_frame\\(\\); tracker has no start\\(\\); "
            "tracker has no stop\\(\\); tracker has no registration",
        ),
        (
            "class T(EMTracker):\n    def measure_tip2base(self):\n        return None\n"
            "def bad(seed, vessel):\n    p = ModelCatheter()\n    return p, T(p)\n",
            "tracker has measure_tip2base\\(\\), which cannot be called",
        ),
    ],
)
def test_objects_that_break_the_protocol_are_named(tmp_path: Path, body: str, match: str) -> None:
    path = _write(tmp_path, body)
    with pytest.raises(PluginError, match=match) as info:
        make_plant(f"{path}:bad", 0)
    assert str(path) in str(info.value)  # the spec is named


def test_probing_catches_what_a_signature_cannot(tmp_path: Path) -> None:
    body = (
        "class P(ModelCatheter):\n    def move_along(self, q_path):\n"
        "        return np.zeros((len(q_path), 3))\n"
        "def bad(seed, vessel):\n    p = P()\n    return p, EMTracker(p)\n"
    )
    path = _write(tmp_path, body)
    make_plant(f"{path}:bad", 0)  # the signature is right
    with pytest.raises(PluginError, match="move_along.*must return \\(n, 4, 4\\).*\\(2, 3\\)"):
        make_plant(f"{path}:bad", 0, probe=True)


def test_seed_and_vessel_are_checked_before_the_factory_runs(plugin: Path) -> None:
    with pytest.raises(PluginError, match="seed must be an integer >= 0, got -1"):
        make_plant("lab_catheter:make", -1)
    with pytest.raises(PluginError, match="vessel must be one of"):
        make_plant("lab_catheter:make", 0, "tortuous")


def test_checks_read_nothing_that_samples() -> None:
    """Checking a tracker leaves its random stream alone: the same draws follow."""
    a, ta = FAMILIES["default"](9, "straight")
    b, tb = FAMILIES["default"](9, "straight")
    check_plant(a)
    check_tracker(ta)
    np.testing.assert_array_equal(ta.measure_tip2base(), tb.measure_tip2base())
    assert pickle.loads(pickle.dumps(FAMILIES["field-distortion"])) == FAMILIES["field-distortion"]
