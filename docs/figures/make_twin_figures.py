"""Figures and numbers of docs/digital-twin.md (run: python docs/figures/make_twin_figures.py).

- twin_hysteresis.png: AP knob swept up and down, true bend vs knob, per vessel condition.
- twin_grid.png: model vs true tip positions over the +-90 deg knob grid (the paper's Fig. 4a).
- twin_spin.png: spin errors without compensation and after a perfect elastic compensation,
  tuning seeds 0-9 and seeds 100-109 (100 leaked into tuning; results use 110+), beside
  the paper's Table I.
- twin_reference.png: plant vs Cosserat-rod reference backbones for a few tendon tensions.
- twin_contact.png, twin_breathing.png, twin_stick_slip.png: the disturbances of section 9
  (contact force along a bend into the wall, the breathing level and the heart's motion, the
  shaft's lost motion at each of 16 returns); ``--disturbances`` makes only these.
Prints the numbers quoted in the document.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from icenav.geometry.kinematics import forward  # noqa: E402
from icenav.sim import CatheterPlant, EMTracker, PlantParams  # noqa: E402
from icenav.sim.bending import Tendons  # noqa: E402
from icenav.sim.plant import elastic_tip2base_from_tensions  # noqa: E402
from icenav.sim.reference import solve_tendon_rod  # noqa: E402
from icenav.sim.tuning import elastic_oracle, run_spin, spin_errors, spin_trajectory  # noqa: E402

HERE = Path(__file__).parent
DEG = math.pi / 180.0
TABLE_NONE = {20: (5.5, 10.0), 40: (11.0, 20.5), 60: (14.8, 31.0)}
TABLE_DENSE = {20: (2.5, 3.0), 40: (4.2, 8.6), 60: (5.0, 10.3)}


def hysteresis() -> None:
    fig, ax = plt.subplots(figsize=(6, 4.5))
    amp = 60 * DEG
    for vessel, style in (("straight", "-"), ("moderate", ":"), ("steep", "--")):
        plant = CatheterPlant(params=PlantParams.nominal(), vessel=vessel)
        plant.move_along(np.column_stack([np.linspace(0, -amp, 60), np.zeros((60, 3))]))
        knob = np.concatenate([np.linspace(-amp, amp, 241), np.linspace(amp, -amp, 241)])
        bends = []
        for k in knob:
            plant.move([k, 0, 0, 0])
            bends.append(plant.state.effective_knobs[0])
        ax.plot(np.degrees(knob), np.degrees(bends), style, label=vessel)
    ax.plot([-60, 60], [-60, 60], color="0.7", lw=0.8, label="model (bend = knob)")
    ax.set_xlabel("AP motor knob phi1 (deg)")
    ax.set_ylabel("true AP bend as model knob angle (deg)")
    ax.set_title("Knob swept -60 -> +60 -> -60 deg (nominal catheter)")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(HERE / "twin_hysteresis.png", dpi=110)
    plt.close(fig)


def grid() -> None:
    ang = np.arange(-90, 91, 10) * DEG
    plant = CatheterPlant(seed=0)
    model, true = [], []
    for a in ang:
        for b in ang:
            q = np.array([a, b, 0.0, 0.0])
            model.append(forward(q)[:3, 3])
            plant.reset()
            true.append(plant.move(q)[:3, 3])
    m = np.array(model)
    t = np.array(true)
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(m[:, 0], m[:, 1], ".", color="k", ms=4, label="model P_hat (kinematics)")
    ax.plot(t[:, 0], t[:, 1], ".", color="purple", ms=4, label="true P (twin, seed 0)")
    for i in range(len(m)):
        ax.plot([m[i, 0], t[i, 0]], [m[i, 1], t[i, 1]], color="0.8", lw=0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x_tip (mm), AP")
    ax.set_ylabel("y_tip (mm), RL")
    ax.set_title("Tip positions over the +-90 deg knob grid (cf. paper Fig. 4a)")
    ax.legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(HERE / "twin_grid.png", dpi=110)
    plt.close(fig)


def spin_table(seeds: range) -> dict[str, np.ndarray]:
    """Mean over seeds of [pos, rot] per bend: none/oracle x tracked/true."""
    out: dict[str, list[list[float]]] = {
        k: [] for k in ("none", "none_true", "oracle", "oracle_true")
    }
    for seed in seeds:
        plant = CatheterPlant(seed=seed)
        tracker = EMTracker(plant, seed=seed)
        rows: dict[str, list[float]] = {k: [] for k in out}
        for bend in (20, 40, 60):
            q = spin_trajectory(bend * DEG)
            for name, cmd in (("none", None), ("oracle", elastic_oracle(plant.params, q))):
                run = run_spin(plant, bend * DEG, q_motor=cmd, tracker=tracker)
                assert run.tracked_tip2base is not None
                e = spin_errors(run.tracked_tip2base, q)
                et = spin_errors(run.true_tip2base, q)
                rows[name] += [e.position_rmse_mm, e.rotation_rmse_deg]
                rows[name + "_true"] += [et.position_rmse_mm, et.rotation_rmse_deg]
        for k in out:
            out[k].append(rows[k])
    return {k: np.array(v) for k, v in out.items()}


def spin() -> None:
    results = {
        "tuning seeds 0-9": spin_table(range(10)),
        "seeds 100-109": spin_table(range(100, 110)),
    }
    for label, res in results.items():
        print(f"-- {label}: mean (min..max over seeds), EM-tracked [true]")
        for name in ("none", "oracle"):
            for j, bend in enumerate((20, 40, 60)):
                tr = res[name][:, 2 * j : 2 * j + 2]
                tt = res[name + "_true"][:, 2 * j : 2 * j + 2]
                print(
                    f"{name:7s} {bend} deg: pos {tr[:, 0].mean():5.1f} ({tr[:, 0].min():.1f}.."
                    f"{tr[:, 0].max():.1f}) [{tt[:, 0].mean():.1f}] mm, rot {tr[:, 1].mean():5.1f} "
                    f"({tr[:, 1].min():.1f}..{tr[:, 1].max():.1f}) [{tt[:, 1].mean():.1f}] deg"
                )
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    bends = np.array([20, 40, 60])
    for k, (ax, unit) in enumerate(
        zip(axes, ("position RMSE (mm)", "rotation RMSE (deg)"), strict=True)
    ):
        ax.plot(
            bends, [TABLE_NONE[b][k] for b in bends], "ks-", label="paper: without compensation"
        )
        ax.plot(
            bends, [TABLE_DENSE[b][k] for b in bends], "ko--", label="paper: dense compensation"
        )
        for (label, res), color in zip(results.items(), ("tab:blue", "tab:red"), strict=True):
            none = res["none"][:, k::2]
            orac = res["oracle"][:, k::2]
            ax.errorbar(
                bends + 1,
                none.mean(0),
                yerr=none.std(0),
                fmt="s-",
                color=color,
                label=f"twin, none ({label})",
            )
            ax.errorbar(
                bends + 1,
                orac.mean(0),
                yerr=orac.std(0),
                fmt="o--",
                color=color,
                label=f"twin, perfect elastic comp. ({label})",
            )
        ax.set_xlabel("initial AP bend (deg)")
        ax.set_ylabel(unit)
        ax.set_xticks(bends)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("Image spinning, EM-tracked, straight vessel: twin vs paper Table I")
    fig.tight_layout()
    fig.savefig(HERE / "twin_spin.png", dpi=110)
    plt.close(fig)


def reference() -> None:
    p = PlantParams.nominal()
    arms = Tendons.from_params(p).arms
    pos = np.array([[a[1], -a[0]] for a in arms])
    k = np.array([[p.ei_rl_nmm2, p.ei_coupling_nmm2], [p.ei_coupling_nmm2, p.ei_ap_nmm2]])
    fig = plt.figure(figsize=(6, 5))
    ax = fig.add_subplot(projection="3d")
    worst = 0.0
    for tens in ((4, 0, 0, 0), (0, 0, 8, 0), (3, 0, 5, 0), (0, 8, 0, 9), (0, 12, 0, 0)):
        t = np.array(tens, dtype=float)
        sol = solve_tendon_rod(
            pos, t, k, 0.7 * p.ei_ap_nmm2, p.stiffening, 60.0 * p.bending_length_scale
        )
        tip_ref = sol.positions[-1] + 10.0 * sol.tip_rotation[:, 2]
        tip = elastic_tip2base_from_tensions(p, t)[:3, 3]
        worst = max(worst, float(np.linalg.norm(tip - tip_ref)))
        ax.plot(*sol.positions.T, "k-", lw=2)
        ax.plot(*tip, "o", color="tab:orange")
        ax.plot(*tip_ref, "x", color="k")
    ax.set_title(f"Plant (o) vs Cosserat reference (x, lines); worst tip gap {worst:.1e} mm")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    fig.tight_layout()
    fig.savefig(HERE / "twin_reference.png", dpi=110)
    plt.close(fig)
    print(f"reference: worst plant-vs-Cosserat tip gap {worst:.2e} mm")


def widths() -> None:
    sys.path.insert(0, str(HERE.parent.parent / "tests"))
    from sim.test_plant import loop_width_deg  # the test's own measurement

    for v in ("straight", "moderate", "steep"):
        print(f"loop width {v}: {loop_width_deg(v):.2f} deg of knob")


def contact_pass() -> None:
    """Contact force and tip deflection along a pass of the AP knob into the RA wall."""
    from icenav.sim.anatomy import BASE2ANATOMY, default_phantom
    from icenav.sim.beat_imager import SimClock
    from icenav.sim.contact import ContactModel, Walls
    from icenav.sim.disturbed import DisturbedPlant

    clock = SimClock()
    plant = DisturbedPlant(
        CatheterPlant(seed=0),
        clock.now,
        contact=ContactModel(Walls(default_phantom(), BASE2ANATOMY)),
        solve_period_s=0.0,
    )
    knob = np.linspace(0.0, 80.0, 161)
    force, defl, where = [], [], []
    for k in knob:
        plant.move([k * DEG, 0.0, 0.0, 0.0])
        st = plant.state
        force.append(st.contact_force_n)
        defl.append(st.deflection_mm)
        where.append(max(st.contacts, key=lambda c: c.force_n).structure if st.contacts else "")
    fig, ax = plt.subplots(figsize=(6.5, 4))
    ax.plot(knob, force, color="tab:red", label="total contact force (N)")
    ax.set_xlabel("AP knob (deg), translation 0, nominal catheter seed 0")
    ax.set_ylabel("contact force (N)")
    ax2 = ax.twinx()
    ax2.plot(knob, defl, color="tab:blue", ls="--", label="tip deflection (mm)")
    ax2.set_ylabel("deflection of the image centre (mm)")
    first = next((k for k, f in zip(knob, force, strict=True) if f > 0), None)
    ax.set_title(f"Bending into the RA wall (first contact at {first} deg)")
    ax.legend(loc="upper left")
    ax2.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(HERE / "twin_contact.png", dpi=110)
    plt.close(fig)
    print(f"contact: first at {first} deg of knob; at 80 deg {force[-1]:.3f} N on {where[-1]}, "
          f"tip deflected {defl[-1]:.1f} mm")  # fmt: skip


def breathing_trace() -> None:
    """The breathing level of an in-vivo patient and the heart's caudal displacement."""
    from icenav.sim.conditions import build_twin

    twin = build_twin("in-vivo", 110, 100, lambda: 0.0)
    assert twin.breathing is not None
    t = np.linspace(0.0, 30.0, 3001)
    level = twin.breathing.signal(t)
    z = np.array([twin.breathing.translation_mm(x)[2] for x in t])
    fig, ax = plt.subplots(2, 1, figsize=(7, 4.5), sharex=True)
    ax[0].plot(t, level, color="k")
    ax[0].set_ylabel("breathing level r(t)")
    ax[1].plot(t, z, color="tab:green")
    ax[1].set_ylabel("heart superior shift (mm)")
    ax[1].set_xlabel("time (s)")
    ax[0].set_title(f"Breathing of patient 100 (period {twin.patient.breathing_period_s:.1f} s, "
                    f"depth x{twin.patient.breathing_scale:.2f})")  # fmt: skip
    fig.tight_layout()
    fig.savefig(HERE / "twin_breathing.png", dpi=110)
    plt.close(fig)
    print(f"breathing: heart shift {z.min():.2f} .. {z.max():.2f} mm over 30 s")


def stick_slip_returns() -> None:
    """The shaft's lost motion (translation, roll) at the end of 16 identical moves to a view,
    in the phantom and in vivo."""
    from icenav.sim.beat_imager import SimClock
    from icenav.sim.conditions import build_twin

    fig, ax = plt.subplots(1, 2, figsize=(9, 3.6))
    for cond, colour in (("phantom", "tab:blue"), ("in-vivo", "tab:red")):
        clock = SimClock()
        twin = build_twin(cond, 110, 100, clock.now)
        shaft = twin.plant.shaft
        assert shaft is not None
        a = np.zeros(4)
        b = np.array([0.0, 0.0, 30 * DEG, 8.0])
        trans, roll = [], []
        for _ in range(16):
            for q0, q1 in ((a, b), (b, a)):
                for f in np.linspace(0, 1, 200)[1:]:
                    shaft.drive(q0[3] + f * (q1[3] - q0[3]), q0[2] + f * (q1[2] - q0[2]), clock.t)
                    clock.advance(0.01)
                clock.advance(3.0)
                if q1 is b:
                    s, r = shaft.lost_motion(clock.t)
                    trans.append(s)
                    roll.append(np.degrees(r))
        ax[0].plot(range(1, 17), trans, "o-", color=colour, label=cond)
        ax[1].plot(range(1, 17), roll, "o-", color=colour, label=cond)
        print(f"stick-slip {cond}: translation {np.mean(trans):.2f} +- {np.std(trans):.2f} mm, "
              f"roll {np.mean(roll):.2f} +- {np.std(roll):.2f} deg")  # fmt: skip
    ax[0].set_ylabel("lost translation (mm)")
    ax[1].set_ylabel("lost roll (deg)")
    for x in ax:
        x.set_xlabel("return")
        x.legend()
    fig.suptitle(
        "Shaft lost motion 3 s after each return (8 mm, 30 deg moves; catheter 110, patient 100)"
    )
    fig.tight_layout()
    fig.savefig(HERE / "twin_stick_slip.png", dpi=110)
    plt.close(fig)


def disturbances() -> None:
    contact_pass()
    breathing_trace()
    stick_slip_returns()


if __name__ == "__main__":
    if "--disturbances" in sys.argv:
        disturbances()
        sys.exit(0)
    disturbances()
    hysteresis()
    grid()
    reference()
    widths()
    spin()
