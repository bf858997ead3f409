"""Tests of icenav.calibration.transmission: identification of the per-tendon transmission
from two-knob motions (on a synthetic catheter of known model, and on a plant of another form:
distributed play), its recording through the calibration runner, and the end-to-end
compensation through the controller's knob map."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from icenav._typing import Array
from icenav.calibration.plans import MotionPlan, calibration_set_from, raster_grid
from icenav.calibration.procedure import run_visits
from icenav.calibration.procedures import plan_visits
from icenav.calibration.transmission import (
    FORM_MARGIN,
    KNOB_CIRCLES,
    CalibrationMotion,
    build_transmission,
    circle_blocks,
    circle_path,
    circle_plan,
    identify_transmission,
    identify_transmission_form,
    motion_from,
    reidentify_in_situ,
)
from icenav.compensation.tendon_map import TendonKnobMap
from icenav.compensation.transmission import PairTransmission, TendonTransmission
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import forward
from tests.support.transmission import (
    TRUTH,
    SyntheticCatheter,
    spin_like,
    spin_path_motion,
    synthetic_catheter,
)

DEG = math.pi / 180


def test_identification_recovers_a_known_synthetic_model() -> None:
    rng = np.random.default_rng(5)
    circles = circle_path((25 * DEG, 50 * DEG), step=4 * DEG)
    sweep = np.zeros((120, 4))
    sweep[:, 0] = 60 * DEG * np.sin(np.linspace(0, 4 * math.pi, 120))
    sweep[:, 1] = 40 * DEG * np.sin(np.linspace(0, 3 * math.pi, 120))
    motions = [
        synthetic_catheter(TRUTH, rng, circles, 0.05 * DEG),
        synthetic_catheter(TRUTH, rng, sweep, 0.05 * DEG),
    ]
    fit = identify_transmission(motions, degree=3, max_nfev=40)
    assert fit.rms < 0.15 * DEG < fit.rms_without_play
    assert fit.model.ap.slack == pytest.approx(TRUTH.ap.slack, abs=0.3 * DEG)
    assert fit.model.rl.slack == pytest.approx(TRUTH.rl.slack, abs=0.3 * DEG)
    # held-out two-knob motion: the identified model predicts the truth's effective knobs
    test = spin_like(40 * DEG)
    err = fit.model.simulate(test, x_start=[0.0, 0.0]) - TRUTH.simulate(test, x_start=[0.0, 0.0])
    assert float(np.sqrt(np.mean(err**2))) < 0.2 * DEG

    # in situ: the same catheter in a curved vessel, re-identified from circles alone with
    # the static map kept; it must predict the wider plays there
    curved = TRUTH.with_vessel(1.0)
    in_situ = identify_transmission(
        [synthetic_catheter(curved, rng, circles, 0.05 * DEG)],
        initial=fit.model,
        degree=3,
        static_coefficients=fit.static_coefficients,
        max_nfev=30,
    )
    truth_z = curved.simulate(test, x_start=[0.0, 0.0])
    err_situ = in_situ.model.simulate(test, x_start=[0.0, 0.0]) - truth_z
    err_straight = fit.model.simulate(test, x_start=[0.0, 0.0]) - truth_z
    assert np.sqrt(np.mean(err_situ**2)) < 0.3 * np.sqrt(np.mean(err_straight**2))
    with pytest.raises(ShapeError, match="static_coefficients"):
        identify_transmission(motions, degree=3, static_coefficients=np.zeros((3, 2)))


def test_motion_from_a_recording_reads_the_tracker_and_marks_missing() -> None:
    moves: list[np.ndarray] = []

    class Tracker:
        n = 0

        def measure_tip2base(self, n_average: int = 1) -> np.ndarray | None:
            self.n += 1
            return None if self.n == 2 else forward(moves[-1])

    plan = circle_plan((20 * DEG,), step=5 * DEG)
    rec = run_visits(plan_visits(plan), lambda q: moves.append(np.array(q)), Tracker())
    motion = motion_from(rec, KNOB_CIRCLES)
    assert np.isnan(motion.observed[1]).all()
    ok = np.isfinite(motion.observed[:, 0])
    path = plan.q_motor[plan.segment(KNOB_CIRCLES)]
    np.testing.assert_allclose(motion.observed[ok], path[ok, :2], atol=1e-7)


def _record(cat: SyntheticCatheter, plan: MotionPlan) -> object:
    cat.reset()
    return run_visits(plan_visits(plan), cat.move, cat)


def test_calibration_and_compensation_end_to_end_on_a_synthetic_catheter() -> None:
    """Raster and circles recorded through the runner, the transmission identified, and a
    spin commanded through the controller's knob map (model_to_motor + observe per command):
    the tip follows the model within 1 mm where the uncompensated one misses by > 4 mm."""
    cat = SyntheticCatheter(TRUTH)
    raster = raster_grid(step=30 * DEG)
    rec = _record(cat, MotionPlan.make(raster, "dense raster", n_average=1, retries=0))
    dense = calibration_set_from(rec, "dense raster").calibration
    circles = motion_from(_record(cat, circle_plan((30 * DEG, 60 * DEG), step=8 * DEG)))
    tcal = build_transmission(dense, raster, circles, degree=3, max_nfev=25, circles_in_map=False)
    assert tcal.fit.rms < 0.3 * tcal.fit.rms_without_play
    q_model = spin_like(40 * DEG)
    target = forward(q_model[20:])
    errors = []
    kmap = TendonKnobMap(tcal)
    compensated = []
    for q in q_model:
        cmd = kmap.model_to_motor(q)
        kmap.observe(cmd)
        compensated.append(cmd)
    for cmd in (q_model, np.array(compensated)):
        cat.reset()
        tips = np.array([cat.move(q)[:3, 3] for q in cmd])[20:]
        errors.append(float(np.sqrt(np.mean(np.sum((tips - target[:, :3, 3]) ** 2, -1)))))
    assert errors[1] < 1.0 < 4.0 < errors[0]  # mm
    # in situ with the same (straight) plays: the re-identified model predicts as well
    again = motion_from(_record(cat, circle_plan((30 * DEG, 60 * DEG), step=8 * DEG)))
    situ = reidentify_in_situ(tcal, again, max_nfev=15)
    assert situ.effective_map is tcal.effective_map
    assert situ.fit.rms < 2.0 * tcal.fit.rms + 0.1 * DEG
    with pytest.raises(ConfigurationError, match="not on the raster"):
        build_transmission(dense, raster + 0.1)
    with pytest.raises(ConfigurationError, match="TransmissionCalibration"):
        reidentify_in_situ("calibration", again)  # type: ignore[arg-type]


def test_identification_on_a_plant_with_distributed_play() -> None:
    """A plant of another form than the model's: each tendon pair's play is a weighted sum of
    play operators of graded widths (Prandtl-Ishlinskii), not slack plus one capstan band.
    The identified model cannot be exact, but it must explain most of what the play-free
    model leaves and predict a held-out spin's effective knobs far better than no model."""
    widths = np.linspace(0.5, 5.0, 8) * DEG

    def plant(path: np.ndarray) -> np.ndarray:
        z = np.zeros((path.shape[0], 2))
        for j in range(2):
            for r in widths:
                p, out = 0.0, []
                for x in path[:, j]:
                    p = min(max(p, x - r), x + r)
                    out.append(p)
                z[:, j] += np.array(out) / widths.size
        return z

    rng = np.random.default_rng(7)
    circles = circle_path((25 * DEG, 50 * DEG), step=4 * DEG)
    sweep = np.zeros((120, 4))
    sweep[:, 0] = 60 * DEG * np.sin(np.linspace(0, 4 * math.pi, 120))
    sweep[:, 1] = 40 * DEG * np.sin(np.linspace(0, 3 * math.pi, 120))
    motions = []
    for path in (circles, sweep):
        y = plant(path) + rng.normal(0.0, 0.05 * DEG, (path.shape[0], 2))
        motions.append(CalibrationMotion(q_motor=path, observed=y))
    fit = identify_transmission(motions, degree=3, max_nfev=40)
    assert fit.rms < 0.5 * fit.rms_without_play
    test = spin_like(40 * DEG)
    truth = plant(test)
    err_model = fit.model.simulate(test, x_start=[0.0, 0.0]) - truth
    err_none = test[:, :2] - truth
    assert np.sqrt(np.mean(err_model**2)) < 0.5 * np.sqrt(np.mean(err_none**2))
    with pytest.raises(ShapeError, match="static_coefficients"):
        identify_transmission(motions, degree=3, static_coefficients=np.zeros((3, 2)))


def test_circle_blocks_count_the_departures_from_rest() -> None:
    path = circle_path((20 * DEG, 40 * DEG, 60 * DEG), step=10 * DEG)
    labels = circle_blocks(np.vstack([np.zeros((1, 4)), path]))
    assert labels[0] == 0 and labels.max() == 3
    assert np.all(np.diff(labels) >= 0)
    for k, r in zip((1, 2, 3), (20, 40, 60), strict=True):
        assert np.max(np.hypot(*path[labels[1:] == k, :2].T)) == pytest.approx(r * DEG)


def _stretch_catheter_on_circles(
    rng: np.random.Generator,
) -> tuple[TendonTransmission, Array, CalibrationMotion, Array]:
    """A catheter whose tendons are routed so that the other pair's bend relieves them (the
    stretch form, TR3s) on knob circles at 25 / 45 / 65 deg: (truth, the circles' path (n,
    4), its motion, the middle circle's samples (n,) bool)."""
    circles = circle_path((25 * DEG, 45 * DEG, 65 * DEG), step=10 * DEG)
    pair = PairTransmission(slack=1.0 * DEG, seal_play=0.5 * DEG, tension_play=0.5, coupling=0.8)
    truth = TendonTransmission(ap=pair, rl=pair, wrap=0.5, friction=0.3, coupling_form="stretch")
    motion = synthetic_catheter(truth, rng, circles, 0.05 * DEG)
    return truth, circles, motion, circle_blocks(circles) == 2


def test_the_tension_form_is_chosen_by_held_out_residual() -> None:
    """Data of a catheter whose tendons are routed so that the other pair's bend relieves
    them (the stretch form, TR3s): the stretch form predicts the held-out middle circle
    better than the added one (TR3) fitted to the same data, and is kept."""
    rng = np.random.default_rng(11)
    truth, circles, motion, middle = _stretch_catheter_on_circles(rng)
    fit = identify_transmission_form(
        [motion], [middle], degree=3, train_nfev=12, refit_nfev=4, extensions=()
    )
    scores = dict(fit.held_out_rms)
    assert fit.model.coupling_form == "stretch"
    assert scores["stretch"] < 0.5 * scores["added"]
    with pytest.raises(ConfigurationError, match="held_out"):
        identify_transmission_form([motion], [np.zeros(circles.shape[0], dtype=bool)])


def test_with_the_spin_circle_a_form_must_win_on_both_held_out_paths() -> None:
    """The stretch form's data on the knob circles (it wins the middle circle, as above) but
    a spin circle of the added form's catheter: scored on both held-out paths, the stretch
    form does not win on the spin and the simpler added form is kept; the spin's scores are
    listed (``"spin circle: " + form``). Spin data of the stretch catheter itself keep it."""
    rng = np.random.default_rng(11)
    truth, circles, motion, middle = _stretch_catheter_on_circles(rng)
    kw = {"degree": 3, "train_nfev": 12, "refit_nfev": 2, "extensions": ()}
    lag = (4 * DEG, -6 * DEG)
    other = spin_path_motion(replace(truth, coupling_form="added"), rng, lag, 0.05 * DEG)
    fit = identify_transmission_form([motion], [middle], spin=other, **kw)
    scores = dict(fit.held_out_rms)
    assert scores["stretch"] < 0.5 * scores["added"]  # the knob circle alone would keep it
    assert scores["spin circle: stretch"] > scores["spin circle: added"] * (1 - FORM_MARGIN)
    assert fit.model.coupling_form == "added"
    own = spin_path_motion(truth, rng, lag, 0.05 * DEG)
    assert identify_transmission_form([motion], [middle], spin=own, **kw).model.coupling_form == (
        "stretch"
    )


def test_an_extension_is_kept_where_it_predicts_held_out_data_better() -> None:
    """Data of a catheter whose tendons have two play elements of very different widths
    (half the pull play-free): a model with a second element predicts the held-out middle
    circle better than the one-element forms and is kept; the bend-tension extension,
    tried too, is scored and not kept."""
    rng = np.random.default_rng(12)
    circles = circle_path((25 * DEG, 45 * DEG, 65 * DEG), step=10 * DEG)
    pair = PairTransmission(slack=0.5 * DEG, seal_play=3.0 * DEG, tension_play=0.1, coupling=0.0)
    truth = TendonTransmission(ap=pair, rl=pair, wrap=0.3, friction=0.2).with_extension(
        "two-play", [0.5, 0.0]
    )
    motion = synthetic_catheter(truth, rng, circles, 0.05 * DEG)
    middle = circle_blocks(circles) == 2
    fit = identify_transmission_form(
        [motion], [middle], forms=("added",), degree=3, train_nfev=8, extension_nfev=8, refit_nfev=3
    )
    scores = dict(fit.held_out_rms)
    assert fit.model.form == "added+two-play"
    assert scores["added+two-play"] < 0.7 * scores["added"]
    assert scores["added+two-play"] < scores["added+bend-tension"]
    with pytest.raises(ConfigurationError, match="extensions"):
        identify_transmission_form([motion], [middle], extensions=("none",))


def test_a_held_wrap_stays_held_and_the_held_out_circle_decides_whether_it_is_kept() -> None:
    """``wrap_range`` with equal bounds holds the capstan exponent through the fit; each wrap
    tried by the form's choice is scored on the held-out circle (``form@wrap``): on data of
    a catheter of wrap 0.9, a wrap of 0 predicts it worse and is not kept, 0.9 better, kept
    and held through the refit."""
    rng = np.random.default_rng(13)
    circles = circle_path((25 * DEG, 45 * DEG, 65 * DEG), step=10 * DEG)
    pair = PairTransmission(slack=0.5 * DEG, seal_play=1.0 * DEG, tension_play=0.3, coupling=0.0)
    truth = TendonTransmission(ap=pair, rl=pair, wrap=0.9, friction=0.2)
    motion = synthetic_catheter(truth, rng, circles, 0.05 * DEG)
    held = identify_transmission([motion], degree=3, max_nfev=6, wrap_range=(0.45, 0.45))
    assert held.model.wrap == pytest.approx(0.45, abs=1e-6)
    with pytest.raises(ConfigurationError, match="wrap_range"):
        identify_transmission([motion], degree=3, wrap_range=(0.6, 0.3))
    middle = circle_blocks(circles) == 2
    fit = identify_transmission_form(
        [motion],
        [middle],
        forms=("added",),
        extensions=(),
        wraps=(0.0, 0.9),
        degree=3,
        train_nfev=8,
        refit_nfev=3,
    )
    scores = dict(fit.held_out_rms)
    assert set(scores) == {"added", "added@0", "added@0.9"}
    # a wrong wrap predicts the held-out circle worse and is not kept; the catheter's own is
    assert scores["added@0"] > scores["added"]
    assert scores["added@0.9"] < scores["added"] * (1.0 - FORM_MARGIN)
    assert fit.model.wrap == pytest.approx(0.9, abs=1e-6)
