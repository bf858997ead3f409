"""icenav/ViewFinding-v0: spaces, seeds, reward, termination, bounds."""

from __future__ import annotations

import math
from typing import Any

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import icenav.gym
from icenav.errors import ConfigurationError
from icenav.gym import ViewFindingEnv
from icenav.sim.anatomy import EXAMPLE_VIEWS
from tests.support.gym import kinematic_factory, walled_factory

ZERO = np.zeros(4, dtype=np.float32)


def test_registered_and_passes_the_env_checker() -> None:
    env = gymnasium.make("icenav/ViewFinding-v0", image_size=32)
    check_env(env.unwrapped)
    obs, _ = env.reset(seed=0)
    assert obs["image"].shape == (32, 32, 1) and obs["image"].dtype == np.uint8
    assert env.observation_space.contains(obs)
    env.close()
    assert set(icenav.gym.ENV_IDS) <= set(gymnasium.registry)


def test_same_seed_same_episode_other_seed_other_catheter_and_patient() -> None:
    env = ViewFindingEnv()
    obs_a, info_a = env.reset(seed=7)
    step_a = env.step(np.full(4, 0.01, dtype=np.float32))
    obs_b, info_b = env.reset(seed=7)
    step_b = env.step(np.full(4, 0.01, dtype=np.float32))
    np.testing.assert_array_equal(obs_a["image"], obs_b["image"])
    np.testing.assert_array_equal(step_a[0]["image"], step_b[0]["image"])
    assert step_a[1] == step_b[1]
    assert info_a["catheter_seed"] == info_b["catheter_seed"]
    _, info_c = env.reset(seed=8)
    assert (info_c["catheter_seed"], info_c["patient_seed"]) != (
        info_a["catheter_seed"],
        info_a["patient_seed"],
    )
    lo, hi = icenav.gym.TRAINING_CATHETERS
    assert lo <= info_a["catheter_seed"] < hi


@pytest.mark.parametrize("view", sorted(EXAMPLE_VIEWS))
def test_the_view_is_found_at_its_pose_and_not_from_a_random_start(view: str) -> None:
    # the model itself as the plant: q_view puts the tip exactly at the target pose
    env = ViewFindingEnv(plant_factory=kinematic_factory, success_bonus=2.0)
    _, info = env.reset(seed=1, options={"view": view, "q_start": EXAMPLE_VIEWS[view]})
    _, reward, terminated, truncated, info = env.step(ZERO)
    assert terminated and not truncated
    assert info["similarity"] >= env.config.similarity_threshold
    assert reward == pytest.approx(info["similarity"] - 1.0 + 2.0)
    # the twin's catheter from its random start near the home view: far from the view
    real = ViewFindingEnv()
    _, info = real.reset(seed=1, options={"view": view})
    assert info["similarity"] < env.config.similarity_threshold - 0.2
    _, reward, terminated, _, info = real.step(ZERO)
    assert not terminated and reward == pytest.approx(info["similarity"] - 1.0)


def test_contact_force_is_penalised() -> None:
    env = ViewFindingEnv(plant_factory=walled_factory, contact_penalty_per_n=0.5)
    q = np.array([0.0, 0.0, 0.0, 4.5])
    env.reset(seed=2, options={"q_start": q})
    _, r_free, _, _, free = env.step(ZERO)
    assert free["contact_force_n"] == 0.0
    assert r_free == pytest.approx(free["similarity"] - 1.0)
    _, r_push, _, _, push = env.step(np.array([0, 0, 0, 1.0], dtype=np.float32))
    assert push["contact_force_n"] == pytest.approx(0.2 * 0.5)  # 0.5 mm past the wall
    assert r_push == pytest.approx(push["similarity"] - 1.0 - 0.5 * 0.1)


def test_actions_and_joints_stay_in_their_bounds_and_episodes_truncate() -> None:
    env = ViewFindingEnv(max_steps=4, roll_limit_rad=0.2)
    obs, _ = env.reset(seed=3, options={"q_start": [0.0, 0.0, 0.15, 0.0]})
    big = np.array([1.0, -1.0, 1.0, 5.0], dtype=np.float32)  # beyond max_increment
    obs, _, terminated, truncated, info = env.step(big)
    inc = np.asarray(env.config.max_increment)
    np.testing.assert_allclose(obs["q"], [inc[0], -inc[1], 0.2, inc[3]], atol=1e-6)
    assert info["clipped"]  # the roll stopped at the box
    for _ in range(3):
        obs, _, terminated, truncated, info = env.step(ZERO)
    assert truncated and not terminated
    assert env.observation_space.contains(obs)


def test_render_shows_the_picture_beside_the_target() -> None:
    env = ViewFindingEnv(render_mode="rgb_array", image_size=32)
    obs, _ = env.reset(seed=0)
    img = env.render()
    assert img is not None and img.shape == (32, 64, 3) and img.dtype == np.uint8
    np.testing.assert_array_equal(img[:, :32, 0], obs["image"][..., 0])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"image_size": 8}, r"image_size must be an int in \[16, 512\] pixels, got 8"),
        ({"max_increment": (0.1, 0.1, 0.1)}, "max_increment must be 4 positive"),
        ({"views": ("septum",)}, "unknown view"),
        ({"vessels": ("tortuous",)}, "tortuous"),
        ({"catheter_seeds": (5, 5)}, "catheter_seeds must satisfy"),
        ({"similarity_threshold": 1.5}, r"similarity_threshold must be in \[-1.0, 1.0\]"),
        ({"frame_time_s": 0.0}, "frame_time_s must be in"),
        ({"render_mode": "human"}, "render_mode"),
    ],
)
def test_bad_settings_are_rejected(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(ConfigurationError, match=match):
        ViewFindingEnv(**kwargs)


def test_bad_reset_options_and_step_before_reset_are_rejected() -> None:
    env = ViewFindingEnv(image_size=32)
    with pytest.raises(ConfigurationError, match="call reset"):
        env.step(ZERO)
    with pytest.raises(ConfigurationError, match=r"unknown reset option\(s\) \['colour'\]"):
        env.reset(seed=0, options={"colour": 1})
    with pytest.raises(ConfigurationError, match="q_start must be 4 values within"):
        env.reset(seed=0, options={"q_start": [0.0, 0.0, 0.0, math.inf]})
    env.reset(seed=0)
    with pytest.raises(ConfigurationError, match="action must be 4 finite increments"):
        env.step(np.zeros(3, dtype=np.float32))
    with pytest.raises(ConfigurationError, match="action must be 4 finite increments"):
        env.step(np.array([0.0, math.nan, 0.0, 0.0], dtype=np.float32))
