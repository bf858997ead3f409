"""Make docs/figures/gym_view_finding.png and print the similarity table of docs/gym.md.

For each valve view of icenav/ViewFinding-v0 (64 x 64 pictures, episode seed 1): the picture
from the random start, the picture with the twin's catheter commanded to the view's model
joint state, and the target. The table: mean similarity over 40 steps at a fixed pose, for
the model itself as the plant at the view (the ceiling), the twin catheter at ``q_view``,
and the random start, patients 0-2.

Run: ``.venv/bin/python docs/figures/make_gym_figures.py`` (about 15 s).
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from icenav.geometry.kinematics import forward  # noqa: E402
from icenav.gym import ViewFindingEnv  # noqa: E402
from icenav.sim.anatomy import EXAMPLE_VIEWS  # noqa: E402

HERE = Path(__file__).parent
ZERO = np.zeros(4, dtype=np.float32)


class ModelPlant:
    """The constant-curvature model as the plant: reaches the view's pose exactly."""

    def __init__(self) -> None:
        self.q = np.zeros(4)

    def reset(self, q: Any = None) -> None:
        self.q = np.zeros(4) if q is None else np.asarray(q, dtype=np.float64)

    def move(self, q: Any) -> Any:
        self.q = np.asarray(q, dtype=np.float64)
        return forward(self.q)

    @property
    def state(self) -> SimpleNamespace:
        return SimpleNamespace(tip2base=forward(self.q))


def mean_similarity(env: ViewFindingEnv, options: dict[str, Any], n: int = 40) -> float:
    _, info = env.reset(seed=1, options=options)
    s = [info["similarity"]]
    for _ in range(n):
        s.append(env.step(ZERO)[4]["similarity"])
    return float(np.mean(s))


def main() -> None:
    ideal = ViewFindingEnv(plant_factory=lambda seed, vessel: (ModelPlant(), None))
    twin = ViewFindingEnv(render_mode="rgb_array")
    print("view, patient: ceiling (model plant at the view) / twin at q_view / random start")
    for view, q in EXAMPLE_VIEWS.items():
        for patient in range(3):
            opts: dict[str, Any] = {"view": view, "patient_seed": patient}
            row = (
                mean_similarity(ideal, {**opts, "q_start": q}),
                mean_similarity(twin, {**opts, "q_start": q}),
                mean_similarity(twin, opts),
            )
            print(f"  {view:<16s} {patient}: " + " / ".join(f"{v:.3f}" for v in row))
    fig, axes = plt.subplots(3, 3, figsize=(7.5, 7.5))
    for i, (view, q) in enumerate(EXAMPLE_VIEWS.items()):
        _, start = twin.reset(seed=1, options={"view": view, "patient_seed": 0})
        start_img = twin.render()
        _, at = twin.reset(seed=1, options={"view": view, "patient_seed": 0, "q_start": q})
        at_img = twin.render()
        assert start_img is not None and at_img is not None
        n = twin.config.image_size
        panels = [
            (start_img[:, :n, 0], f"random start\ns = {start['similarity']:.2f}"),
            (at_img[:, :n, 0], f"twin catheter at q_view\ns = {at['similarity']:.2f}"),
            (at_img[:, n:, 0], f"target: {view.replace('_', ' ')}"),
        ]
        for ax, (img, title) in zip(axes[i], panels, strict=True):
            ax.imshow(img, cmap="gray", vmin=0, vmax=255)
            ax.set_title(title, fontsize=9)
            ax.axis("off")
    fig.suptitle("icenav/ViewFinding-v0 observations (64 x 64), patient 0")
    fig.tight_layout()
    path = HERE / "gym_view_finding.png"
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
