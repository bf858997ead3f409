"""Where ours' spin error comes from (session 9's diagnosis, docs/results.md "Plant families").

Reads the plant's *true* state (the method never does): for each catheter it runs the console's
``dense+hysteresis`` calibration, then the spins of ``icenav eval spin`` through the
controller's map, and splits the true position error into what each part of the plant's state
alone would give on the intended state: the bend's size, its direction in the base frame (knob
direction plus roll), the section's length, the translation. It also counts the reversals of
the knob commands (a chattering map) and gives the EM and true RMSE as the eval does.

    python docs/figures/diagnose_family_spins.py --families default,rate-dependent \
        --seeds 210-212 [--bends 20,40,60] [--map-from bcf73ae] [--cache /tmp/cal] [--json F]

``--both-ways`` also spins the other way and splits the bend's size and direction errors
into the part that does not depend on the sense of turning (static) and the part that flips
with it (a lag). ``--map-from REV`` spins through ``TendonKnobMap`` as it was at git
revision REV (the same calibration), for a before / after of the map alone. ``--release
limit:DEG`` spreads every knob step of the transmission's inverse larger than DEG over the next
samples (at most DEG a sample; the model's state follows the command sent), ``--release
scale:F`` makes every step larger than 8 deg (a band crossing) F times as large: plants8's
(session 11) test of whether the inverse's single-sample band crossings make the
`out-of-tolerance` error.
Development seeds only.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from icenav.calibration.model_files import decode_model, encode_model
from icenav.eval.spin import (
    APPROACH_STEPS,
    _approach_path,
    _rmse,
    knob_map_commands,
    make_rig,
    run_calibration,
)
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, forward
from icenav.geometry.trajectories import spin_trajectory

G = DEFAULT_GEOMETRY
MAP_PATH = "src/icenav/compensation/tendon_map.py"


def calibrated(family: str, seed: int, cache: Path | None) -> Any:
    """Ours' CatheterCalibration of the catheter (cached as a model file in ``cache``)."""
    f = None if cache is None else cache / f"cal_{family}_{seed}.json"
    if f is not None and f.exists():
        return decode_model("dense+hysteresis", json.loads(f.read_text()), str(f))
    rig, tracker = make_rig(seed, "straight", family)
    cat = run_calibration("dense+hysteresis", rig, tracker).details
    if f is not None:
        f.write_text(json.dumps(encode_model("dense+hysteresis", cat)))
    return cat


def map_class(rev: str | None) -> Any:
    """TendonKnobMap now, or as it was at git revision ``rev``."""
    if rev is None:
        from icenav.compensation.tendon_map import TendonKnobMap

        return TendonKnobMap
    text = subprocess.run(
        ["git", "show", f"{rev}:{MAP_PATH}"], check=True, capture_output=True, text=True
    ).stdout
    path = Path(tempfile.mkdtemp()) / "tendon_map_at_rev.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location("tendon_map_at_rev", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.TendonKnobMap


def release_variant(cls: Any, spec: str | None) -> Any:
    """``cls`` with its knob inverse's large steps spread (``limit:DEG``) or scaled
    (``scale:F``, steps over 8 deg), or ``cls`` itself for None (see the module's doc)."""
    if spec is None:
        return cls
    kind, value = spec.split(":")
    v = float(value)
    if kind not in ("limit", "scale"):
        raise SystemExit(f"--release must be limit:DEG or scale:F, got {spec!r}")

    class Released(cls):  # type: ignore[misc, valid-type]
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            knobs = self._knobs
            solve = knobs.knob_command

            def knob_command(z1: float, z2: float) -> tuple[float, float]:
                x = solve(z1, z2)
                out = []
                for j in (0, 1):
                    step = x[j] - knobs._x[j]
                    if kind == "limit":
                        m = math.radians(v)
                        step = min(max(step, -m), m)
                    elif abs(step) > math.radians(8.0):
                        step *= v
                    out.append(knobs._x[j] + step)
                return out[0], out[1]

            knobs.knob_command = knob_command

    return Released


def pose_of(knobs: Any, roll: float, scale: float, trans: float) -> Any:
    """Eq. (T10) of the twin (twist left out: it does not move the tip)."""
    pose = forward(np.array([knobs[0], knobs[1], roll, 0.0]), G, check=False)
    z = pose[:3, 2]
    arc = pose[:3, 3] - G.us_offset * z
    pose[:3, 3] = scale * arc + G.us_offset * z
    pose[2, 3] += trans
    return pose


def reversals(cmd: Any) -> int:
    """Sign changes of the knob commands' steps (both knobs)."""
    n = 0
    for j in (0, 1):
        d = np.diff(cmd[:, j])
        s = np.sign(d[np.abs(d) > 1e-9])
        n += int(np.sum(s[1:] != s[:-1]))
    return n


def spin(
    cat: Any, cls: Any, family: str, seed: int, bend: int, direction: int = -1
) -> dict[str, Any]:
    """One spin: EM / true RMSE, reversals and the decomposition of the true position error
    (the per-sample bend size and direction errors, deg, and the intended azimuth, rad, under
    the keys starting with ``_``)."""
    sp = spin_trajectory(
        [math.radians(bend), 0.0, 0.0, 0.0], 360, include_end=True, direction=direction
    )
    q = sp.q_model
    km = cls(cat.transmission)
    model_twist: list[float] = []

    class Recording:  # the map as the controller drives it, noting the model's twist
        def model_to_motor(self, q_model: Any, *, check: bool = True) -> Any:
            return km.model_to_motor(q_model, check=check)

        def observe(self, q_motor: Any) -> None:
            km.observe(q_motor)
            model_twist.append(getattr(km, "_i", 0.0) - getattr(km, "_p3", 0.0))

    cmd = knob_map_commands(Recording(), _approach_path(q))
    rig, tracker = make_rig(seed, "straight", family)
    plant = rig.robot.plant
    rig.reset()
    eff, roll, trans, true, em, twist = [], [], [], [], [], []
    for i, c in enumerate(cmd):
        rig.move(c)
        if i < APPROACH_STEPS:
            continue
        s = plant.state
        eff.append(s.effective_knobs)
        roll.append(s.roll)
        trans.append(s.translation_mm)
        twist.append(s.twist)
        true.append(s.tip2base)
        m = tracker.measure_tip2base()
        em.append(np.full((4, 4), np.nan) if m is None else m)
    eff_a, roll_a, trans_a = np.array(eff), np.array(roll), np.array(trans)
    true_a, em_a = np.array(true), np.array(em)
    scale = plant._length / G.bending_length  # the plant's own (the diagnosis reads it)
    intended = forward(q, G, check=False)
    p0 = intended[0, :3, 3]
    ok = np.all(np.isfinite(em_a.reshape(len(em_a), -1)), axis=1)
    ep, er = _rmse(em_a[ok], intended[ok])
    tp, tr = _rmse(true_a, intended)

    def err(knobs: Any, rl: Any, sc: float, tz: Any) -> float:
        p = np.array([pose_of(knobs[i], rl[i], sc, tz[i])[:3, 3] for i in range(len(rl))])
        return float(np.sqrt(np.mean(np.sum((p - p0) ** 2, axis=1))))

    size = np.hypot(q[:, 0], q[:, 1])
    size_eff = np.hypot(eff_a[:, 0], eff_a[:, 1])
    az = np.arctan2(eff_a[:, 1], eff_a[:, 0]) + roll_a - q[:, 2]  # base-frame direction
    d_size = np.degrees(size_eff - size)
    d_az = np.degrees((az - np.arctan2(q[:, 1], q[:, 0]) + np.pi) % (2 * np.pi) - np.pi)
    qk = q[:, :2]
    # the distal twist (image about its own axis): the plant's against the map's model of it
    d_twist = np.degrees(np.array(twist) - np.array(model_twist[APPROACH_STEPS:]))
    return {
        "family": family,
        "seed": seed,
        "bend_deg": bend,
        "em_mm": ep,
        "em_deg": er,
        "true_mm": tp,
        "true_deg": tr,
        "reversals": reversals(cmd[APPROACH_STEPS:]),
        "max_knob_step_deg": float(np.degrees(np.abs(np.diff(cmd[:, :2], axis=0)).max())),
        # each part of the plant's state alone on the intended state (true position RMSE, mm)
        "alone_bend_size_mm": err(qk * (size_eff / size)[:, None], q[:, 2], 1.0, q[:, 3]),
        "alone_bend_direction_mm": err(
            np.column_stack([size * np.cos(az), size * np.sin(az)]), q[:, 2], 1.0, q[:, 3]
        ),
        "alone_length_mm": err(qk, q[:, 2], scale, q[:, 3]),
        "alone_translation_mm": err(qk, q[:, 2], 1.0, trans_a),
        "bend_size_err_rms_deg": float(np.sqrt(np.mean(d_size**2))),
        "bend_size_err_mean_deg": float(np.mean(d_size)),
        "bend_direction_err_rms_deg": float(np.sqrt(np.mean(d_az**2))),
        "translation_err_mean_mm": float(np.mean(trans_a - q[:, 3])),
        "twist_err_rms_deg": float(np.sqrt(np.mean(d_twist**2))),
        "twist_err_mean_deg": float(np.mean(d_twist)),
        "_d_size": d_size,
        "_d_az": d_az,
        "_azimuth": np.arctan2(q[:, 1], q[:, 0]),
    }


def split_both_ways(one: dict[str, Any], other: dict[str, Any]) -> dict[str, float]:
    """The bend's size and direction errors of two spins turned opposite ways, on a common
    grid of intended azimuths (knob plane, 1 deg): their mean is the part that does not
    depend on the sense of turning (static: F, G, the section's length, a static share of
    the transmission), half their difference the part that flips with it (the
    transmission's lag). RMS of each (deg); the static size error's mean and its first and
    second harmonics' amplitudes over the azimuth (deg)."""
    grid = np.radians(np.arange(-180.0, 180.0, 1.0))

    def on_grid(r: dict[str, Any], key: str) -> Any:
        az = np.asarray(r["_azimuth"])
        order = np.argsort(az)
        return np.interp(grid, az[order], np.asarray(r[key])[order], period=2 * np.pi)

    out: dict[str, float] = {}
    for key, name in (("_d_size", "size"), ("_d_az", "direction")):
        a, b = on_grid(one, key), on_grid(other, key)
        static, flip = 0.5 * (a + b), 0.5 * (a - b)
        out[f"{name}_static_rms_deg"] = float(np.sqrt(np.mean(static**2)))
        out[f"{name}_reversing_rms_deg"] = float(np.sqrt(np.mean(flip**2)))
        if name == "size":
            out["size_static_mean_deg"] = float(np.mean(static))
            for k in (1, 2):
                c = 2.0 * np.mean(static * np.exp(-1j * k * grid))
                out[f"size_static_h{k}_deg"] = float(abs(c))
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--families", required=True)
    ap.add_argument("--seeds", required=True, help="e.g. 210-212 or 210,212")
    ap.add_argument("--bends", default="20,40,60")
    ap.add_argument("--map-from", default=None, help="git revision of TendonKnobMap")
    ap.add_argument("--cache", type=Path, default=None)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument(
        "--both-ways",
        action="store_true",
        help="also spin the other way and split the bend's errors into the part that does "
        "not depend on the sense of turning and the part that flips with it",
    )
    ap.add_argument("--release", default=None, help="limit:DEG or scale:F (see above)")
    a = ap.parse_args(argv)
    if "-" in a.seeds:
        lo, hi = (int(x) for x in a.seeds.split("-"))
        seeds = list(range(lo, hi + 1))
    else:
        seeds = [int(x) for x in a.seeds.split(",")]
    if a.cache is not None:
        a.cache.mkdir(parents=True, exist_ok=True)
    cls = release_variant(map_class(a.map_from), a.release)
    rows = []
    for family in a.families.split(","):
        for seed in seeds:
            cat = calibrated(family, seed, a.cache)
            for bend in (int(b) for b in a.bends.split(",")):
                r = spin(cat, cls, family, seed, bend)
                if a.both_ways:
                    r.update(split_both_ways(r, spin(cat, cls, family, seed, bend, direction=1)))
                r = {k: v for k, v in r.items() if not k.startswith("_")}
                r["release"] = a.release
                rows.append(r)
                print(
                    json.dumps(
                        {k: round(v, 3) if isinstance(v, float) else v for k, v in r.items()}
                    )
                )
                sys.stdout.flush()
    if a.json is not None:
        a.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
