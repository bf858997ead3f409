"""icenav/Spin-v0: with zero corrections an episode is eval spin's ``none`` condition."""

from __future__ import annotations

import math
from typing import Any

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import icenav.gym  # noqa: F401  (registers the environments)
from icenav.errors import ConfigurationError
from icenav.eval.spin import run_vessel
from icenav.gym import SpinEnv

ZERO = np.zeros(4, dtype=np.float32)


def test_registered_and_passes_the_env_checker() -> None:
    env = gymnasium.make("icenav/Spin-v0", n_samples=30)
    check_env(env.unwrapped)
    env.close()


def _episode(env: SpinEnv, options: dict[str, Any]) -> list[dict[str, Any]]:
    obs, _ = env.reset(seed=0, options=options)
    assert obs[6] == 0.0  # no tracker sample before the first step
    infos = []
    truncated = False
    while not truncated:
        obs, reward, terminated, truncated, info = env.step(ZERO)
        assert not terminated
        info["reward"] = reward
        infos.append(info)
    return infos


@pytest.mark.parametrize("vessel", ["straight", "steep"])
def test_zero_corrections_reproduce_eval_spin_none(vessel: str) -> None:
    n = 90
    env = SpinEnv(n_samples=n)
    infos = _episode(env, {"catheter_seed": 100, "vessel": vessel, "bend_deg": 40})
    assert len(infos) == n
    (rec,) = run_vessel(100, vessel, None, bends_deg=(40,), n_samples=n, conditions=("none",))

    def rms(key: str) -> float:
        v = np.array([i[key] for i in infos])
        v = v[np.isfinite(v)]
        return float(np.sqrt(np.mean(v**2)))

    assert rms("true_position_error_mm") == pytest.approx(rec.true_position_rmse_mm, rel=1e-12)
    assert rms("true_rotation_error_deg") == pytest.approx(rec.true_rotation_rmse_deg, rel=1e-9)
    assert rms("em_position_error_mm") == pytest.approx(rec.position_rmse_mm, rel=1e-12)
    assert rms("em_rotation_error_deg") == pytest.approx(rec.rotation_rmse_deg, rel=1e-9)
    n_missing = sum(math.isnan(i["em_position_error_mm"]) for i in infos)
    assert n_missing == rec.em_missing
    for i in infos:  # the reward is the scaled true error
        want = -(i["true_position_error_mm"] / 5.0 + i["true_rotation_error_deg"] / 10.0)
        assert i["reward"] == pytest.approx(want)


def test_corrections_move_the_tip_and_em_rewards_use_the_tracker() -> None:
    env = SpinEnv(n_samples=20, reward_from="em")
    opts = {"catheter_seed": 101, "bend_deg": 20}
    env.reset(seed=0, options=opts)
    obs, reward, _, _, info = env.step(np.array([1.0, 0.0, 0.0, 0.0], dtype=np.float32))
    assert obs[6] == 1.0 and np.all(np.isfinite(obs))
    want = -(info["em_position_error_mm"] / 5.0 + info["em_rotation_error_deg"] / 10.0)
    assert reward == pytest.approx(want)
    np.testing.assert_allclose(obs[11:15], [1.0, 0.0, 0.0, 0.0])
    env.reset(seed=0, options=opts)
    _, _, _, _, plain = env.step(ZERO)
    # a 15 deg knob correction moves the tip by millimetres
    assert abs(info["true_position_error_mm"] - plain["true_position_error_mm"]) > 1.0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n_samples": 1}, r"n_samples must be in \[2, 10000\]"),
        ({"bends_deg": (95.0,)}, r"bends_deg must be in \(0, 90\] deg"),
        ({"reward_from": "oracle"}, "reward_from must be 'true' or 'em'"),
        ({"max_correction": (0.1, 0.1, 0.1, -1.0)}, "max_correction must be 4 positive"),
        ({"position_scale_mm": 0.0}, "position_scale_mm must be > 0"),
    ],
)
def test_bad_settings_are_rejected(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(ConfigurationError, match=match):
        SpinEnv(**kwargs)


def test_step_after_the_end_is_rejected() -> None:
    env = SpinEnv(n_samples=2)
    env.reset(seed=0)
    env.step(ZERO)
    env.step(ZERO)
    with pytest.raises(ConfigurationError, match="the spin is over"):
        env.step(ZERO)
    env.reset(seed=0)
    with pytest.raises(ConfigurationError, match="action must be 4 finite corrections"):
        env.step(np.zeros(5, dtype=np.float32))
