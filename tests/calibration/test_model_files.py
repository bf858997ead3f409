"""Calibration files of versions 3 and 4: the fitted model is kept, and loading gives the
compensation the fit gave (a reduced dense+hysteresis fit on the twin, conftest's
``twin_catheter_calibration``)."""

from __future__ import annotations

import copy
import dataclasses
import inspect
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from icenav.calibration.catheter import CatheterCalibration
from icenav.calibration.files import CalibrationFile
from icenav.calibration.hysteresis import HysteresisFit, HysteresisIdentification
from icenav.calibration.model_files import (
    HYSTERESIS_COMPENSATOR_KEYS,
    TENDON_COMPENSATOR_KEYS,
    decode_model,
    encode_model,
)
from icenav.compensation.bend_play import BendPlay, KnobPlanePlay
from icenav.compensation.elasticity import BuildReport, ElasticityMap
from icenav.compensation.hysteresis import HysteresisCompensator, JointHysteresis
from icenav.compensation.knob_residual import KnobResidual
from icenav.compensation.tendon_map import TendonKnobMap
from icenav.compensation.tracker_bias import TrackerBias
from icenav.compensation.transmission import (
    PairTransmission,
    TendonCompensator,
    TendonTransmission,
    TransmissionCalibration,
    TransmissionFit,
)
from icenav.errors import ConfigurationError, FileFormatError, UnsupportedVersionError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry
from tests.support.transmission import wave_residual

ROUNDING = 1e-12
"""rad, mm: how far the loaded compensation may differ from the fitted one. The tables of F
are rebuilt from their node values (the same spline through the same 91 x 91 values up to
the last bit of the node values read back): differences of a few 1e-16 rad are measured;
1e-12 is four orders below the 1e-8 rad the tendon compensator's own root search resolves."""


@pytest.fixture(scope="module")
def saved(twin_catheter_calibration: CatheterCalibration, tmp_path_factory: Any) -> Path:
    cat = twin_catheter_calibration
    path = tmp_path_factory.mktemp("cal") / "cal.json"
    CalibrationFile(cat.dense, kind="dense+hysteresis", model=cat).save(path)
    return path


def _random_states(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lim = 0.95 * DEFAULT_GEOMETRY.knob_limit
    return np.column_stack(
        [
            rng.uniform(-lim, lim, (n, 2)),
            rng.uniform(-math.pi, math.pi, n),
            rng.uniform(-40.0, 40.0, n),
        ]
    )


def test_a_twin_fit_loads_as_the_same_knob_map(
    twin_catheter_calibration: CatheterCalibration, saved: Path
) -> None:
    loaded = CalibrationFile.load(saved)
    assert loaded.kind == "dense+hysteresis"
    fitted = twin_catheter_calibration.knob_map()
    again = loaded.compensation()
    assert isinstance(again, TendonKnobMap)
    states = _random_states(20)
    worst = 0.0
    for q in states:  # one command after the other: the maps' states follow them alike
        a = fitted.model_to_motor(q)
        b = again.model_to_motor(q)
        worst = max(worst, float(np.max(np.abs(a - b))))
        fitted.observe(a)
        again.observe(a)
        a, b = fitted.motor_to_model(a), again.motor_to_model(a)
        worst = max(worst, float(np.max(np.abs(a - b))))
    # a path from the present state, executed in order
    worst = max(
        worst,
        float(
            np.max(np.abs(fitted.model_to_motor(states[:30]) - again.model_to_motor(states[:30])))
        ),
    )
    assert worst <= ROUNDING
    # and the commands do move: a map that ignored the model would not match the fit
    assert float(np.max(np.abs(fitted.model_to_motor(states[0]) - states[0]))) > 1e-3


def test_the_parts_of_the_fit_come_back_equal(
    twin_catheter_calibration: CatheterCalibration, saved: Path
) -> None:
    cat = twin_catheter_calibration
    back = CalibrationFile.load(saved).model
    assert isinstance(back, CatheterCalibration)
    assert back.hysteresis.fits == cat.hysteresis.fits
    assert back.hysteresis.n_moves == cat.hysteresis.n_moves
    for new, old in ((back.hysteresis.compensator, cat.hysteresis.compensator),):
        assert new.joints == old.joints and new.roll_play == old.roll_play
        assert new.twist_play == old.twist_play
        assert new.reversal_threshold == old.reversal_threshold
    np.testing.assert_array_equal(back.tracker_bias.gradient, cat.tracker_bias.gradient)
    np.testing.assert_array_equal(back.tracker_bias.offset_mm, cat.tracker_bias.offset_mm)
    t, t0 = back.transmission, cat.transmission
    assert t.fit.model == t0.fit.model and t.compensator.model == t0.compensator.model
    np.testing.assert_array_equal(t.fit.static_coefficients, t0.fit.static_coefficients)
    assert t.effective_map.report == t0.effective_map.report
    np.testing.assert_array_equal(
        t.effective_map.calibration.q_motor, t0.effective_map.calibration.q_motor
    )
    # F of the raster (the paper's, kept beside): the same to rounding, its real-tip
    # interpolant rebuilt on first use
    nodes = np.linspace(-1.5, 1.5, 7)
    a, b = np.meshgrid(nodes, nodes)
    for new_map, old_map in ((back.elasticity_map, cat.elasticity_map),):
        np.testing.assert_allclose(
            new_map.model_to_motor_knobs(a, b), old_map.model_to_motor_knobs(a, b), atol=ROUNDING
        )
        np.testing.assert_allclose(
            new_map.real_position(a, b), old_map.real_position(a, b), atol=1e-9
        )


def _objects(doc: Any) -> list[dict[str, Any]]:
    out = []
    if isinstance(doc, dict):
        out.append(doc)
        for v in doc.values():
            out += _objects(v)
    elif isinstance(doc, list) and doc and isinstance(doc[0], dict | type(None)):
        for v in doc:
            out += _objects(v)
    return out


def _init_fields(cls: type) -> set[str]:
    return {f.name for f in dataclasses.fields(cls) if f.init}


def test_every_field_of_every_serialised_class_is_in_the_document(
    twin_catheter_calibration: CatheterCalibration,
) -> None:
    """Fails when a field is added to one of the classes a file keeps and the encoder does not
    write it (or a constructor parameter to one of the stateful compensators)."""
    cat = twin_catheter_calibration
    model = encode_model("dense+hysteresis", cat)
    assert set(model) == _init_fields(CatheterCalibration)
    t = model["transmission"]
    assert set(t) == _init_fields(TransmissionCalibration)
    assert set(t["fit"]) == _init_fields(TransmissionFit)
    assert set(t["fit"]["model"]) == _init_fields(TendonTransmission)
    assert set(t["fit"]["model"]["ap"]) == _init_fields(PairTransmission)
    h = model["hysteresis"]
    assert set(h) == _init_fields(HysteresisIdentification)
    assert set(h["fits"][0]) == _init_fields(HysteresisFit)
    assert set(h["fits"][0]["model"]) == _init_fields(JointHysteresis)
    assert set(model["tracker_bias"]) == _init_fields(TrackerBias)
    assert set(model["elasticity_map"]["report"]) == _init_fields(BuildReport)
    assert set(model["elasticity_map"]["geometry"]) == _init_fields(CatheterGeometry)
    assert cat.hysteresis.compensator.roll_play is not None  # the fit has a bend play
    assert set(h["compensator"]["roll_play"]) == _init_fields(KnobPlanePlay)
    assert set(h["compensator"]["roll_play"]["laws"][0]) == _init_fields(BendPlay)
    # the stateful compensators: by their constructors' parameters
    params = set(inspect.signature(HysteresisCompensator.__init__).parameters) - {"self"}
    assert params == set(HYSTERESIS_COMPENSATOR_KEYS) == set(h["compensator"])
    params = set(inspect.signature(TendonCompensator.__init__).parameters) - {"self"}
    assert params == set(TENDON_COMPENSATOR_KEYS) == set(t["compensator"])
    # F: its constructor's parameters, each kept (the real-tip interpolant as the samples)
    params = set(inspect.signature(ElasticityMap.__init__).parameters) - {"self"}
    kept_as = {
        "geometry": "geometry",
        "real_position": "calibration",
        "forward_table": "model_to_motor",
        "inverse_table": "motor_to_model",
        "report": "report",
        "calibration": "calibration",
        "dead_zone_det": "dead_zone_det",
    }
    assert params == set(kept_as)
    assert set(kept_as.values()) <= set(model["elasticity_map"])


def _same(a: Any, b: Any, path: str = "model") -> None:
    """The same JSON structure, numbers equal to ROUNDING (the tables of F are read back from
    a rebuilt table)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), f"{path}: keys {set(a) ^ set(b)}"
        for k in a:
            _same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), path
        if a and isinstance(a[0], int | float | list) and not isinstance(a[0], bool):
            x, y = np.asarray(a, float), np.asarray(b, float)  # numbers, or arrays of them
            assert x.shape == y.shape, path
            np.testing.assert_allclose(x, y, atol=ROUNDING, err_msg=path)
        else:
            for i, (x, y) in enumerate(zip(a, b, strict=True)):
                _same(x, y, f"{path}[{i}]")
    elif isinstance(a, float) and isinstance(b, float):
        assert a == pytest.approx(b, abs=ROUNDING, nan_ok=True), path
    else:
        assert a == b, f"{path}: {a!r} != {b!r}"


def test_what_is_read_is_what_was_written(
    twin_catheter_calibration: CatheterCalibration,
) -> None:
    """Decoding then encoding gives the document back: a field the encoder writes and the
    decoder drops (left at its default) fails here."""
    doc = json.loads(json.dumps(encode_model("dense+hysteresis", twin_catheter_calibration)))
    back = decode_model("dense+hysteresis", doc, "doc")
    _same(doc, json.loads(json.dumps(encode_model("dense+hysteresis", back))))


@pytest.fixture(scope="module")
def document(saved: Path) -> dict[str, Any]:
    doc: dict[str, Any] = json.loads(saved.read_text(encoding="utf-8"))
    return doc


@pytest.mark.parametrize(
    ("change", "match", "error"),
    [
        (
            lambda d: d.update(version=5),
            r"x\.json: calibration file version 5 .* 1\.\.4",
            UnsupportedVersionError,
        ),
        (lambda d: d.update(kind="dense+magic"), r"x\.json: kind must be one of", FileFormatError),
        (lambda d: d.pop("model"), r"x\.json: model is missing", FileFormatError),
        (
            lambda d: d["model"]["transmission"]["fit"].update(static_coefficients=[1.0, 2.0]),
            r"x\.json: model\.transmission\.fit\.static_coefficients must have shape "
            r"\(36, 2\), got \(2,\)",
            FileFormatError,
        ),
        (
            lambda d: d["model"]["tracker_bias"].pop("gradient"),
            r"x\.json: model\.tracker_bias\.gradient is missing",
            FileFormatError,
        ),
        (
            lambda d: d["model"]["elasticity_map"].update(model_to_motor=[[0.0, 0.0]]),
            r"model\.elasticity_map\.model_to_motor must have shape \(8281, 2\)",
            FileFormatError,
        ),
        (
            lambda d: d["model"]["hysteresis"]["fits"][0]["model"].update(backlash=-1.0),
            r"model\.hysteresis\.fits\[0\]\.model: backlash must be in",
            FileFormatError,
        ),
    ],
)
def test_a_damaged_file_is_refused_naming_the_file_and_the_field(
    document: dict[str, Any], tmp_path: Path, change: Any, match: str, error: type
) -> None:
    doc = copy.deepcopy(document)
    change(doc)
    path = tmp_path / "x.json"
    path.write_text(json.dumps(doc), encoding="utf-8")
    with pytest.raises(error, match=match):
        CalibrationFile.load(path)


def test_plays_over_the_knob_plane_are_version_4_and_a_version_3_file_still_loads(
    twin_catheter_calibration: CatheterCalibration, document: dict[str, Any], tmp_path: Path
) -> None:
    """The twin fit's plays are laws over the knob plane: the file is version 4. A version 3
    file (written before: one law of the bend) loads, its law the same in every direction."""
    assert document["version"] == 4
    comp = document["model"]["hysteresis"]["compensator"]
    assert len(comp["roll_play"]["directions"]) == 4 and len(comp["twist_play"]["laws"]) == 4
    old = copy.deepcopy(document)
    old["version"] = 3

    def strip(c: dict[str, Any] | None) -> None:  # as icenav wrote it: the AP knob's law only
        if c is not None:
            for key in ("roll_play", "twist_play"):
                c[key] = c[key]["laws"][0]

    strip(old["model"]["hysteresis"]["compensator"])
    strip(old["model"]["transmission"]["compensator"]["roll"])
    path = tmp_path / "v3.json"
    path.write_text(json.dumps(old), encoding="utf-8")
    back = CalibrationFile.load(path)
    assert isinstance(back.model, CatheterCalibration)
    loaded = back.model.hysteresis.compensator
    plane = twin_catheter_calibration.hysteresis.compensator.roll_play
    assert isinstance(plane, KnobPlanePlay) and isinstance(loaded.roll_play, BendPlay)
    b = np.radians(np.linspace(0.0, 120.0, 13))
    for psi in np.radians([0.0, 45.0, 90.0, 160.0]):
        np.testing.assert_array_equal(loaded.roll_extra(b, psi), plane.laws[0](b))
        np.testing.assert_array_equal(loaded.twist_extra(b, psi), loaded.twist_extra(b))
    # it saves again as version 3 (nothing in it needs 4); the knob map runs on it
    assert back.to_dict()["version"] == 3
    knob_map = back.compensation()
    assert isinstance(knob_map, TendonKnobMap)
    assert np.all(np.isfinite(knob_map.model_to_motor(_random_states(5))))


def test_a_twist_law_over_the_whole_knob_plane_keeps_its_period_and_a_file_without_it_is_pi(
    document: dict[str, Any], tmp_path: Path
) -> None:
    """The spin circle's twist law (period 360 deg) is saved with its period and loads with
    it; a version 4 file written before the period was stored (no key) loads with 180 deg."""
    doc = copy.deepcopy(document)
    comp = doc["model"]["hysteresis"]["compensator"]
    assert comp["twist_play"]["period"] == math.pi
    laws = comp["twist_play"]["laws"]
    comp["twist_play"] = {
        "directions": [k * math.pi / 4 for k in range(8)],
        "laws": [*laws, *laws[::-1]],
        "period": 2 * math.pi,
    }
    path = tmp_path / "p.json"
    path.write_text(json.dumps(doc), encoding="utf-8")
    back = CalibrationFile.load(path)
    twist = back.model.hysteresis.compensator.twist_play
    assert isinstance(twist, KnobPlanePlay) and twist.period == 2 * math.pi
    assert back.to_dict()["model"]["hysteresis"]["compensator"]["twist_play"] == comp["twist_play"]
    del comp["twist_play"]["period"]
    comp["twist_play"]["directions"] = [k * math.pi / 8 for k in range(8)]
    path.write_text(json.dumps(doc), encoding="utf-8")
    twist = CalibrationFile.load(path).model.hysteresis.compensator.twist_play
    assert isinstance(twist, KnobPlanePlay) and twist.period == math.pi


def test_dense_files_keep_f_and_version_2_files_still_load(
    twin_catheter_calibration: CatheterCalibration, tmp_path: Path
) -> None:
    cat = twin_catheter_calibration
    v3 = tmp_path / "dense.json"
    CalibrationFile(cat.dense, kind="dense", model=cat.elasticity_map).save(v3)
    f = CalibrationFile.load(v3).compensation()
    assert isinstance(f, ElasticityMap) and json.loads(v3.read_text())["version"] == 3
    q = _random_states(50, seed=1)
    np.testing.assert_allclose(
        f.model_to_motor(q), cat.elasticity_map.model_to_motor(q), atol=ROUNDING
    )
    # a version 2 file (samples only, as icenav wrote before): F built on the samples
    v2 = tmp_path / "v2.json"
    CalibrationFile(cat.dense).save(v2)
    old = CalibrationFile.load(v2)
    assert json.loads(v2.read_text())["version"] == 2 and old.kind == "" and old.model is None
    np.testing.assert_allclose(
        old.compensation().model_to_motor(q), cat.elasticity_map.model_to_motor(q), atol=ROUNDING
    )
    assert "F built on the samples" in old.describe()


def test_a_model_fitted_for_another_geometry_is_refused(
    twin_catheter_calibration: CatheterCalibration,
) -> None:
    cat = twin_catheter_calibration
    f = CalibrationFile(cat.dense, kind="dense", model=cat.elasticity_map)
    with pytest.raises(ConfigurationError, match="fitted for catheter geometry"):
        f.compensation(CatheterGeometry(bending_length=70.0))
    with pytest.raises(FileFormatError, match="must be a CatheterCalibration"):
        CalibrationFile(cat.dense, kind="dense+hysteresis", model=cat.elasticity_map)


def test_the_tension_form_and_its_scores_come_back_and_old_files_keep_the_added_form(
    twin_catheter_calibration: CatheterCalibration,
) -> None:
    cat = twin_catheter_calibration
    t0 = cat.transmission
    model = dataclasses.replace(t0.fit.model, coupling_form="stretch")
    fit = dataclasses.replace(
        t0.fit, model=model, held_out_rms=(("added", 0.09), ("stretch", 0.08))
    )
    stretched = dataclasses.replace(cat, transmission=dataclasses.replace(t0, fit=fit))
    doc = json.loads(json.dumps(encode_model("dense+hysteresis", stretched)))
    back = decode_model("dense+hysteresis", doc, "x.json").transmission.fit
    assert back.model == model and back.held_out_rms == fit.held_out_rms
    # a file written before the choice: no form, no scores
    del doc["transmission"]["fit"]["model"]["coupling_form"]
    del doc["transmission"]["fit"]["held_out_rms"]
    old = decode_model("dense+hysteresis", doc, "x.json").transmission.fit
    assert old.model.coupling_form == "added" and old.held_out_rms == ()
    doc["transmission"]["fit"]["held_out_rms"] = [["added", "small"]]
    with pytest.raises(FileFormatError, match="held_out_rms"):
        decode_model("dense+hysteresis", doc, "x.json")


def test_a_models_extension_comes_back_and_old_files_have_none(
    twin_catheter_calibration: CatheterCalibration,
) -> None:
    cat = twin_catheter_calibration
    t0 = cat.transmission
    model = t0.fit.model.with_extension("two-play", [0.3, 0.2])
    fit = dataclasses.replace(t0.fit, model=model)
    two = dataclasses.replace(cat, transmission=dataclasses.replace(t0, fit=fit))
    doc = json.loads(json.dumps(encode_model("dense+hysteresis", two)))
    back = decode_model("dense+hysteresis", doc, "x.json").transmission.fit
    assert back.model == model and back.model.state_size == 8
    for key in ("extension", "bend_tension", "second_weight", "second_width"):
        del doc["transmission"]["fit"]["model"][key]
    old = decode_model("dense+hysteresis", doc, "x.json").transmission.fit
    assert old.model.extension == "none" and old.model.second_weight == 0.0


def test_a_models_circle_residual_comes_back_and_old_files_have_none(
    twin_catheter_calibration: CatheterCalibration,
) -> None:
    cat = twin_catheter_calibration
    t0 = cat.transmission
    model = dataclasses.replace(t0.fit.model, residual=wave_residual())
    fit = dataclasses.replace(t0.fit, model=model)
    res = dataclasses.replace(cat, transmission=dataclasses.replace(t0, fit=fit))
    doc = json.loads(json.dumps(encode_model("dense+hysteresis", res)))
    assert set(doc["transmission"]["fit"]["model"]["residual"]) == _init_fields(KnobResidual)
    back = decode_model("dense+hysteresis", doc, "x.json").transmission.fit
    assert back.model == model and back.model.form.endswith("+residual")
    del doc["transmission"]["fit"]["model"]["residual"]
    old = decode_model("dense+hysteresis", doc, "x.json").transmission.fit
    assert old.model.residual is None
    doc["transmission"]["fit"]["model"]["residual"] = {"radii": [0.5], "harmonics": 0}
    with pytest.raises(FileFormatError, match="coefficients"):
        decode_model("dense+hysteresis", doc, "x.json")


def test_the_tracker_bias_quadratic_term_comes_back_and_older_files_load_affine(
    document: dict[str, Any], tmp_path: Path
) -> None:
    doc = copy.deepcopy(document)
    quad = np.arange(18.0).reshape(3, 6) * 1e-5
    doc["model"]["tracker_bias"].update(quadratic=quad.tolist(), centre_mm=[1.0, -2.0, 60.0])
    path = tmp_path / "q.json"
    path.write_text(json.dumps(doc), encoding="utf-8")
    back = CalibrationFile.load(path).model.tracker_bias
    np.testing.assert_array_equal(back.quadratic, quad)
    np.testing.assert_array_equal(back.centre_mm, [1.0, -2.0, 60.0])
    # written before the quadratic field: neither key, the affine field
    for key in ("quadratic", "centre_mm"):
        doc["model"]["tracker_bias"].pop(key)
    path.write_text(json.dumps(doc), encoding="utf-8")
    old = CalibrationFile.load(path).model.tracker_bias
    assert old.quadratic is None and old.centre_mm is None
    np.testing.assert_array_equal(old.gradient, back.gradient)
