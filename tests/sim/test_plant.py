"""The catheter plant: dead-zone, hysteresis, path dependence, seeds, API contracts."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from icenav._validation import check_transform
from icenav.errors import ConfigurationError, JointLimitError, ShapeError
from icenav.geometry.kinematics import CatheterGeometry, forward
from icenav.sim import CatheterPlant, PlantParams, Vessel

DEG = math.pi / 180.0

# Loop widths documented in docs/digital-twin.md ("Hysteresis and dead-zone"), nominal
# catheter, AP knob swept 0 -> +60 -> -60 -> +60 deg: widest horizontal gap between the
# rising and falling branches of bend angle vs knob angle (deg of knob).
DOCUMENTED_LOOP_WIDTH_DEG = {"straight": 6.1, "moderate": 7.0, "steep": 7.4}


def sweep(vessel: str, amplitude: float = 60 * DEG, n: int = 241) -> tuple[np.ndarray, ...]:
    """Knob phi1 swept up from -amp to +amp (rising) and back (falling), after one cycle."""
    plant = CatheterPlant(params=PlantParams.nominal(), vessel=vessel)
    up = np.linspace(-amplitude, amplitude, n)
    down = up[::-1]
    q = np.zeros((n, 4))
    plant.move_along(np.column_stack([np.linspace(0, -amplitude, 60), np.zeros((60, 3))]))
    q[:, 0] = up
    plant.move_along(q)  # settle onto the loop
    bends_up = []
    for row in q:
        plant.move(row)
        bends_up.append(plant.state.effective_knobs[0])
    q[:, 0] = down
    bends_down = []
    for row in q:
        plant.move(row)
        bends_down.append(plant.state.effective_knobs[0])
    return up, np.array(bends_up), down, np.array(bends_down)


def loop_width_deg(vessel: str) -> float:
    """Widest horizontal gap (knob deg) between rising and falling branches at equal bend."""
    up, b_up, down, b_down = sweep(vessel)
    levels = np.linspace(-0.6, 0.6, 61) * max(b_up.max(), 1e-9)
    k_up = np.interp(levels, b_up, up)
    k_down = np.interp(levels, b_down[::-1], down[::-1])
    return float(np.degrees(np.max(np.abs(k_up - k_down))))


def test_dead_zone_around_the_cross_over() -> None:
    p = PlantParams.nominal()
    plant = CatheterPlant(params=p)
    dead_zone = p.slack_ap_mm / p.handle_radius_ap_mm  # rad of knob, Eq. (T1)
    plant.move([0.6 * dead_zone, 0, 0, 0])
    inside = plant.state.bend_angle
    plant.reset()
    plant.move([dead_zone + 10 * DEG, 0, 0, 0])
    outside = plant.state.bend_angle
    assert abs(inside) < 0.2 * DEG
    assert outside > 5 * DEG
    # the slope of bend vs knob is far lower inside the dead-zone than outside it
    plant.reset()
    small = plant.move([0.5 * dead_zone, 0, 0, 0])[:3, 3]
    plant.reset()
    big = plant.move([0.5 * dead_zone + 5 * DEG, 0, 0, 0])[:3, 3]
    plant.reset()
    big2 = plant.move([0.5 * dead_zone + 10 * DEG, 0, 0, 0])[:3, 3]
    assert np.linalg.norm(small[:2]) < 0.1 * np.linalg.norm(big2[:2] - big[:2])


def test_no_slack_means_no_dead_zone() -> None:
    p = replace(PlantParams.nominal(), slack_ap_mm=0.0)
    plant = CatheterPlant(params=p)
    plant.move([2 * DEG, 0, 0, 0])
    assert plant.state.bend_angle > 1.0 * DEG


@pytest.mark.parametrize("vessel", ["straight", "moderate", "steep"])
def test_hysteresis_loop_has_the_documented_width(vessel: str) -> None:
    width = loop_width_deg(vessel)
    assert width == pytest.approx(DOCUMENTED_LOOP_WIDTH_DEG[vessel], rel=0.15)


def test_steep_vessel_loop_is_wider_than_straight() -> None:
    assert loop_width_deg("steep") > 1.2 * loop_width_deg("straight")


def test_vessel_acts_only_through_the_tendons_lumen_friction() -> None:
    """The vessel lies between the robot's front and back units (the paper's phantom set-up):
    it adds capstan wrap to the tendons at the lumen's coefficient, and nothing else. With
    that coefficient at 0 a curved vessel is the straight one exactly; the roll and the
    translation, driven by the front unit beside the section, keep their straight play."""
    rng = np.random.default_rng(3)
    path = np.cumsum(rng.normal(scale=[0.08, 0.08, 0.3, 1.0], size=(120, 4)), axis=0)
    path[:, :2] = np.clip(path[:, :2], -1.4, 1.4)
    path[:, 3] = np.clip(path[:, 3], -40.0, 40.0)
    p = PlantParams.sample(104)
    no_lumen = replace(p, lumen_friction_coefficient=0.0)
    straight = CatheterPlant(params=no_lumen).move_along(path)
    steep = CatheterPlant(params=no_lumen, vessel="steep").move_along(path)
    np.testing.assert_array_equal(straight, steep)
    # with the lumen's friction the steep vessel widens the tendons' play, not the roll's
    a, b = CatheterPlant(params=p), CatheterPlant(params=p, vessel="steep")
    for plant in (a, b):
        plant.move([60 * DEG, 0, 0.0, 0])
        plant.move([60 * DEG, 0, 1.0, 5.0])
    for plant in (a, b):  # the roll lags by its straight-vessel play at the plant's own bend
        lag = p.roll_play_rad + p.roll_play_per_bend * plant.state.bend_angle
        assert plant.state.roll == pytest.approx(1.0 - lag, abs=1e-12)
        assert plant.state.translation_mm == pytest.approx(5.0 - p.translation_play_mm, abs=1e-12)
    assert b.state.bend_angle < a.state.bend_angle - 0.5 * DEG  # more friction, less bend


def test_no_friction_no_hysteresis() -> None:
    p = replace(PlantParams.nominal(), friction_coefficient=0.0, seal_play_mm=0.0)
    plant = CatheterPlant(params=p)
    plant.move([50 * DEG, 0, 0, 0])
    a = plant.move([20 * DEG, 0, 0, 0])
    plant.reset()
    b = plant.move([20 * DEG, 0, 0, 0])
    np.testing.assert_allclose(a, b, atol=1e-6)


def test_result_depends_on_the_path() -> None:
    plant = CatheterPlant(seed=0)
    plant.move([60 * DEG, 0, 0, 0])
    from_above = plant.move([30 * DEG, 0, 0, 0])
    plant.reset()
    from_below = plant.move([30 * DEG, 0, 0, 0])
    assert np.linalg.norm(from_above[:3, 3] - from_below[:3, 3]) > 0.5


def test_roll_has_play() -> None:
    plant = CatheterPlant(params=PlantParams.nominal())
    plant.move([0, 0, 0.5, 0])
    forward_roll = plant.state.roll
    plant.move([0, 0, 1.0, 0])
    plant.move([0, 0, 0.5, 0])
    assert forward_roll < 0.5 < plant.state.roll


def test_bent_tip_twists_about_its_own_axis_when_rolled() -> None:
    plant = CatheterPlant(params=PlantParams.nominal())
    plant.move([60 * DEG, 0, 0, 0])
    before = plant.move([60 * DEG, 0, 1.0, 0])
    twist = plant.state.twist
    bend = plant.state.bend_angle
    assert twist == pytest.approx(-plant.params.twist_play_per_bend * bend, rel=1e-6)
    after_up = plant.move([60 * DEG, 0, 0.0, 0])  # back down: the play flips sign
    assert plant.state.twist > 0
    # against the same catheter without the distal play: same centre and axis, turned frame
    stiff = CatheterPlant(params=replace(plant.params, twist_play_per_bend=0.0))
    stiff.move([60 * DEG, 0, 0, 0])
    ref = stiff.move([60 * DEG, 0, 1.0, 0])
    np.testing.assert_allclose(before[:3, 2:], ref[:3, 2:], atol=1e-12)
    assert math.acos(np.clip(before[:3, 0] @ ref[:3, 0], -1, 1)) == pytest.approx(abs(twist))
    assert after_up.shape == (4, 4)


def test_ideal_catheter_matches_the_kinematics() -> None:
    # rigid tendons at the knob radius, no slack, no friction, no offsets: the model is exact
    ideal = replace(
        PlantParams.nominal(),
        handle_radius_ap_mm=1.3,
        handle_radius_rl_mm=1.3,
        tendon_offset_ap_mm=1.3,
        tendon_offset_rl_mm=1.3,
        neutral_axis_x_mm=0.0,
        neutral_axis_y_mm=0.0,
        routing_error_ap_rad=0.0,
        routing_error_rl_rad=0.0,
        slack_ap_mm=0.0,
        slack_rl_mm=0.0,
        tendon_compliance_mm_per_n=1e-4,
        ei_coupling_nmm2=0.0,
        friction_coefficient=0.0,
        lumen_friction_coefficient=0.0,
        seal_play_mm=0.0,
        roll_play_rad=0.0,
        roll_play_per_bend=0.0,
        twist_play_per_bend=0.0,
        translation_play_mm=0.0,
    )
    plant = CatheterPlant(params=ideal)
    rng = np.random.default_rng(5)
    for _ in range(20):
        q = np.array([*rng.uniform(-80, 80, 2) * DEG, rng.uniform(-3, 3), rng.uniform(-40, 40)])
        np.testing.assert_allclose(plant.move(q), forward(q), atol=0.15)


def test_move_along_equals_repeated_move() -> None:
    rng = np.random.default_rng(1)
    path = np.cumsum(rng.normal(scale=[0.05, 0.05, 0.1, 0.5], size=(200, 4)), axis=0)
    path[:, :2] = np.clip(path[:, :2], -1.5, 1.5)
    a = CatheterPlant(seed=7, vessel="moderate")
    b = CatheterPlant(seed=7, vessel="moderate")
    along = a.move_along(path)
    one_by_one = np.stack([b.move(q) for q in path])
    np.testing.assert_array_equal(along, one_by_one)
    np.testing.assert_array_equal(a.state.tendon_pulls_mm, b.state.tendon_pulls_mm)


def test_same_seed_same_catheter_different_seeds_differ() -> None:
    q = [40 * DEG, -30 * DEG, 0.3, 2.0]
    p1 = CatheterPlant(seed=11).move(q)
    p2 = CatheterPlant(seed=11).move(q)
    p3 = CatheterPlant(seed=12).move(q)
    np.testing.assert_array_equal(p1, p2)
    assert np.linalg.norm(p1[:3, 3] - p3[:3, 3]) > 0.1


def test_reset_clears_history() -> None:
    plant = CatheterPlant(seed=2)
    first = plant.move([30 * DEG, 10 * DEG, 0, 0])
    plant.move([-80 * DEG, 60 * DEG, 1, 3])
    plant.reset()
    np.testing.assert_array_equal(plant.move([30 * DEG, 10 * DEG, 0, 0]), first)


def test_state_and_backbone_are_consistent() -> None:
    plant = CatheterPlant(seed=3)
    pose = plant.move([50 * DEG, 20 * DEG, 0.7, 5.0])
    s = plant.state
    check_transform(s.tip2base)
    np.testing.assert_array_equal(s.tip2base, pose)
    with pytest.raises(ValueError, match="read-only"):
        s.tip2base[0, 0] = 2.0
    pts = plant.backbone(30)
    assert pts.shape == (30, 3)
    end = pose[:3, 3] - plant.geometry.us_offset * pose[:3, 2]
    np.testing.assert_allclose(pts[-1], end, atol=1e-9)
    np.testing.assert_allclose(pts[0], [0, 0, s.translation_mm], atol=1e-12)
    length = np.sum(np.linalg.norm(np.diff(plant.backbone(400), axis=0), axis=1))
    assert length == pytest.approx(60.0 * plant.params.bending_length_scale, rel=1e-4)


def test_tendons_of_a_pair_are_never_both_pulling_hard() -> None:
    plant = CatheterPlant(seed=0)
    for a in np.linspace(-85, 85, 35) * DEG:
        plant.move([a, 0, 0, 0])
        t = plant.state.tendon_tensions_n
        assert min(t[0], t[1]) < 0.5


def test_bad_inputs_are_rejected() -> None:
    plant = CatheterPlant(seed=0)
    with pytest.raises(JointLimitError, match=r"phi1 = 2 rad .* outside the allowed range"):
        plant.move([2.0, 0, 0, 0])
    with pytest.raises(ShapeError, match=r"move takes one joint state of shape \(4,\)"):
        plant.move(np.zeros((2, 4)))
    with pytest.raises(ShapeError, match=r"q_path must have shape \(n, 4\)"):
        plant.move_along(np.zeros(4))
    with pytest.raises(ConfigurationError, match="vessel must be one of"):
        CatheterPlant(vessel="wiggly")
    with pytest.raises(ConfigurationError, match="params must be a PlantParams"):
        CatheterPlant(params={"slack_ap_mm": 0.1})  # type: ignore[arg-type]
    with pytest.raises(ConfigurationError, match="n must be an integer >= 2"):
        plant.backbone(1)


def test_custom_vessel_and_geometry() -> None:
    plant = CatheterPlant(
        seed=0, vessel=Vessel("s-bend", (1.0, 1.0, 1.0)), geometry=CatheterGeometry(us_offset=0)
    )
    pose = plant.move([0, 0, 0, 0])
    np.testing.assert_allclose(
        pose[:3, 3], [0, 0, 60.0 * plant.params.bending_length_scale], atol=1e-3
    )


@pytest.mark.parametrize("seed", [100, 105, 111])
def test_both_planes_reach_a_full_deflection_at_the_knob_limit(seed: int) -> None:
    """An AcuNav-like catheter is steered in four directions with comparable reach
    (docs/digital-twin.md, section 2.1): from rest, each 90 deg knob bends the section past
    75 deg in its own plane, and AP does not out-reach RL by more than half."""
    bends = {}
    for name, q in (
        ("ap+", [math.pi / 2, 0.0, 0.0, 0.0]),
        ("ap-", [-math.pi / 2, 0.0, 0.0, 0.0]),
        ("rl+", [0.0, math.pi / 2, 0.0, 0.0]),
        ("rl-", [0.0, -math.pi / 2, 0.0, 0.0]),
    ):
        plant = CatheterPlant(seed=seed)
        plant.move(q)
        bends[name] = plant.state.bend_angle
        plane = plant.state.bend_plane
        want = {"ap+": 0.0, "ap-": math.pi, "rl+": math.pi / 2, "rl-": -math.pi / 2}[name]
        assert abs(math.remainder(plane - want, 2 * math.pi)) < 15 * DEG, name
    assert min(bends.values()) > 75 * DEG
    ratio = max(bends["ap+"], bends["ap-"]) / min(bends["rl+"], bends["rl-"])
    assert 1.0 < ratio < 1.5
