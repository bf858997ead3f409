"""Robot configuration: the sample file, validation, and the counts <-> rad / mm conversion."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from icenav.devices.canopen.config import (
    ControlMode,
    MotorConfig,
    RobotConfig,
    bundled_eds_path,
    load_robot_config,
)
from icenav.errors import ConfigurationError, FileFormatError

EXAMPLE = Path(__file__).parents[3] / "examples" / "robot.toml"


def test_sample_config_loads() -> None:
    cfg = load_robot_config(EXAMPLE)
    assert cfg.mode is ControlMode.PROFILE_POSITION
    assert [m.node_id for m in cfg.motors] == [1, 2, 3, 4, 5]
    assert [m.name for m in cfg.motors_of("phi3")] == ["roll_front", "roll_back"]
    assert cfg.heartbeat.producer_ms == 50
    assert cfg.limits.shape == (4, 2)
    assert cfg.limits[2, 0] == -math.inf and cfg.limits[2, 1] == math.inf
    assert cfg.limits[3, 1] == 50.0
    assert cfg.motors[1].direction == -1
    assert bundled_eds_path().is_file()


def _raw() -> str:
    return EXAMPLE.read_text()


def _load_text(tmp_path: Path, text: str) -> RobotConfig:
    p = tmp_path / "robot.toml"
    p.write_text(text)
    return load_robot_config(p)


def test_unknown_key_is_rejected(tmp_path: Path) -> None:
    text = _raw().replace("bitrate = 1000000", "bitrate = 1000000\nbitrat = 5")
    with pytest.raises(ConfigurationError, match="unknown key.*bitrat"):
        _load_text(tmp_path, text)


def test_bad_mode_is_rejected(tmp_path: Path) -> None:
    text = _raw().replace('mode = "profile_position"', 'mode = "velocity"')
    with pytest.raises(ConfigurationError, match="mode must be one of"):
        _load_text(tmp_path, text)


def test_not_toml_is_a_file_format_error(tmp_path: Path) -> None:
    with pytest.raises(FileFormatError, match="not a valid TOML"):
        _load_text(tmp_path, "[bus\n")


def test_duplicate_node_id_is_rejected(tmp_path: Path) -> None:
    text = _raw().replace("node_id = 2", "node_id = 1")
    with pytest.raises(ConfigurationError, match="node ids must be unique"):
        _load_text(tmp_path, text)


def test_missing_roll_role_is_rejected(tmp_path: Path) -> None:
    text = _raw().replace('role = "back"', 'role = "front"')
    with pytest.raises(ConfigurationError, match='role = "front" and role = "back"'):
        _load_text(tmp_path, text)


def test_missing_eds_file_is_rejected(tmp_path: Path) -> None:
    text = _raw().replace('eds = ""', 'eds = "maxon_epos4.eds"')
    with pytest.raises(ConfigurationError, match="EDS file .*maxon_epos4.eds does not exist"):
        _load_text(tmp_path, text)


def test_relative_eds_resolves_against_the_file(tmp_path: Path) -> None:
    (tmp_path / "drive.eds").write_text(bundled_eds_path().read_text())
    text = _raw().replace('eds = ""', 'eds = "drive.eds"')
    cfg = _load_text(tmp_path, text)
    assert cfg.motors[0].eds == tmp_path / "drive.eds"


def test_heartbeat_consumer_must_exceed_producer(tmp_path: Path) -> None:
    text = _raw().replace("consumer_s = 0.15", "consumer_s = 0.04")
    with pytest.raises(ConfigurationError, match="must exceed the producer period"):
        _load_text(tmp_path, text)


def test_bad_limits_and_ratios_are_rejected() -> None:
    cfg = load_robot_config(EXAMPLE)
    with pytest.raises(ConfigurationError, match=r"low .* must be < high"):
        replace(cfg, joints=(replace(cfg.joints[0], low=1.0, high=0.5), *cfg.joints[1:]))
    with pytest.raises(ConfigurationError, match="gear_ratio must be finite and > 0"):
        replace(cfg, motors=(replace(cfg.motors[0], gear_ratio=0.0), *cfg.motors[1:]))
    with pytest.raises(ConfigurationError, match="mm_per_rev"):
        replace(cfg, motors=(*cfg.motors[:4], replace(cfg.motors[4], mm_per_rev=0.0)))
    with pytest.raises(ConfigurationError, match="five motors"):
        replace(cfg, motors=cfg.motors[:4])


# ------------------------------------------------------------------ unit conversions
def test_counts_per_rad_analytic() -> None:
    m = MotorConfig("k", "phi1", 1, counts_per_rev=4096, gear_ratio=10.0)
    # One output revolution (2 pi rad) is 10 motor revolutions of 4096 counts.
    assert m.to_counts(2 * math.pi) == 40960
    assert m.to_counts(math.pi / 2) == 10240
    assert m.from_counts(40960) == pytest.approx(2 * math.pi)


def test_counts_per_mm_analytic() -> None:
    m = MotorConfig("t", "d4", 5, counts_per_rev=2048, gear_ratio=4.8, mm_per_rev=2.0)
    # 1 mm = half an output revolution = 2.4 motor revolutions = 4915.2 counts.
    assert m.counts_per_unit == pytest.approx(4915.2)
    assert m.to_counts(10.0) == 49152
    assert m.from_counts(49152) == pytest.approx(10.0)


def test_direction_flips_the_sign() -> None:
    m = MotorConfig("k", "phi2", 2, 2048, 26.0, direction=-1)
    assert m.to_counts(0.5) == -MotorConfig("k", "phi2", 2, 2048, 26.0).to_counts(0.5)
    assert m.from_counts(m.to_counts(0.5)) == pytest.approx(0.5, abs=1 / m.counts_per_unit)


def test_round_trip_within_one_count_over_random_motors() -> None:
    rng = np.random.default_rng(7)
    for _ in range(500):
        joint = str(rng.choice(["phi1", "phi2", "phi3", "d4"]))
        m = MotorConfig(
            "m",
            joint,
            1,
            counts_per_rev=int(rng.integers(16, 65536)),
            gear_ratio=float(rng.uniform(1.0, 200.0)),
            mm_per_rev=float(rng.uniform(0.5, 10.0)),
            direction=int(rng.choice([-1, 1])),
        )
        x = float(rng.uniform(-3.0, 3.0))
        c = m.to_counts(x)
        assert abs(m.from_counts(c) - x) <= 0.5 / m.counts_per_unit + 1e-12
        assert m.to_counts(m.from_counts(c)) == c


def test_counts_beyond_int32_are_rejected() -> None:
    m = MotorConfig("roll_front", "phi3", 3, counts_per_rev=1 << 20, gear_ratio=100.0)
    with pytest.raises(ConfigurationError, match=r"roll_front: phi3 = .* rad .* int32"):
        m.to_counts(1000.0)
