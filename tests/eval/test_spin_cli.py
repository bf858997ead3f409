"""``icenav eval spin --plant`` / ``--plant-family``: the evaluation runs the plant it is given
(a plug-in written here, a family), through the simulated robot, and reports each plant."""

from __future__ import annotations

import json
import math
import textwrap
from pathlib import Path

import numpy as np
import pytest

from icenav.eval import spin_cli
from icenav.geometry.kinematics import forward

# A lab's plug-in: the constant-curvature model whose roll lags the motor by a fixed 5 deg,
# read by a perfect tracker; it counts the moves it was sent.
PLUGIN = """
import math
import numpy as np
from icenav.devices.registration import Registration
from icenav.geometry.kinematics import forward

LAG = math.radians(5.0)
MOVES = []

class State:
    def __init__(self, q):
        self.q_motor = q
        self.tip2base = forward(q - np.array([0.0, 0.0, LAG, 0.0]), check=False)

class LaggingRoll:
    def __init__(self):
        self.reset()
    def reset(self, q_motor=None):
        self.q = np.zeros(4) if q_motor is None else np.asarray(q_motor, float)
    def move(self, q_motor):
        self.q = np.asarray(q_motor, float)
        MOVES.append(self.q)
        return self.state.tip2base
    def move_along(self, q_path):
        return np.array([self.move(q) for q in q_path])
    @property
    def state(self):
        return State(self.q)

class PerfectTracker:
    registration = Registration.given(np.eye(4), np.eye(4))
    def __init__(self, plant):
        self.plant = plant
    def measure_tip2base(self, n_average=1):
        return self.plant.state.tip2base
    def get_frame(self):
        raise NotImplementedError
    def start(self):
        pass
    def stop(self):
        pass

def make(seed, vessel):
    plant = LaggingRoll()
    return plant, PerfectTracker(plant)
"""

SPIN = ["--samples", "12", "--bends", "40", "--conditions", "none"]


@pytest.fixture
def plugin(tmp_path: Path) -> Path:
    path = tmp_path / "lab_catheter.py"
    path.write_text(textwrap.dedent(PLUGIN))
    return path


def test_a_plugin_written_here_is_the_plant_the_spin_measures(plugin: Path, tmp_path: Path) -> None:
    out = tmp_path / "spin.json"
    spec = f"{plugin}:make"
    assert spin_cli.main(["--plant", spec, "--seed", "7", *SPIN, "--json", str(out)]) == 0
    (rec,) = json.loads(out.read_text())
    assert rec["plant"] == spec and rec["seed"] == 7 and rec["condition"] == "none"
    # the model's own catheter with its roll 5 deg behind: the whole tip frame is turned
    # by -5 deg about the base axis at every sample, so the tip sits on the chord of 5 deg
    # of its circle and the image plane lags 5 deg (measured alike by the perfect tracker)
    tip = forward(np.array([math.radians(40.0), 0.0, 0.0, 0.0]))[:3, 3]
    chord = 2.0 * math.hypot(tip[0], tip[1]) * math.sin(math.radians(2.5))
    for kind in ("true_", ""):
        assert rec[f"{kind}position_rmse_mm"] == pytest.approx(chord, rel=1e-6)
        assert rec[f"{kind}rotation_rmse_deg"] == pytest.approx(5.0, rel=1e-6)


def test_the_plugin_is_driven_through_the_simulated_robot(plugin: Path) -> None:
    import sys

    from icenav.eval.spin import make_rig

    rig, _ = make_rig(3, "straight", f"{plugin}:make")
    module = sys.modules[type(rig.robot.plant).__module__]
    n = len(module.MOVES)
    rig.move([0.1, 0.0, 0.2, 0.0])
    assert len(module.MOVES) == n + 1
    assert rig.robot.read_state().q[2] == pytest.approx(0.2)
    from icenav.errors import JointLimitError

    with pytest.raises(JointLimitError):  # the robot's limits hold for any plant
        rig.move([math.radians(120.0), 0.0, 0.0, 0.0])


def test_families_run_the_same_protocol_and_print_the_matrix(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "families.json"
    argv = ["--plant-family", "default,nonlinear-play", "--seed", "210", *SPIN]
    assert spin_cli.main([*argv, "--json", str(out)]) == 0
    records = json.loads(out.read_text())
    assert [r["plant"] for r in records] == ["default", "nonlinear-play"]
    a, b = records
    assert a["true_position_rmse_mm"] != b["true_position_rmse_mm"]  # two different catheters
    text = capsys.readouterr().out
    assert "plant default" in text and "plant nonlinear-play" in text
    assert "plant x condition x bend, vessel straight" in text


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--plant", "no_such_file.py:make"], "no such file"),
        (["--plant", "json:no_factory"], "has no 'no_factory'"),
        (["--plant-family", "bogus"], "unknown plant family 'bogus'"),
        (["--plant-family", " , "], "names no family"),
    ],
)
def test_a_bad_plant_is_refused_before_anything_runs(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert spin_cli.main([*argv, *SPIN]) == 2
    assert message in capsys.readouterr().err


def test_plant_and_plant_family_exclude_each_other() -> None:
    with pytest.raises(SystemExit):
        spin_cli.main(["--plant", "x:y", "--plant-family", "default", *SPIN])
