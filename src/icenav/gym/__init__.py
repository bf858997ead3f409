"""Gymnasium environments of the digital twin (the optional extra ``icenav[gym]``).

Importing this package registers, with gymnasium:

- ``icenav/ViewFinding-v0`` (:class:`ViewFindingEnv`): steer the catheter until the ICE image
  shows a target view;
- ``icenav/Spin-v0`` (:class:`SpinEnv`): correct the motor commands of the image-spinning
  motion so the tip follows the intended pose.

::

    import gymnasium
    import icenav.gym  # registers the environments

    env = gymnasium.make("icenav/ViewFinding-v0", image_size=64)
    obs, info = env.reset(seed=0)

Spaces, rewards, seeds: ``docs/gym.md``.
"""

from __future__ import annotations

import gymnasium

from icenav.gym.population import (
    EVALUATION_CATHETERS,
    TRAINING_CATHETERS,
    Patient,
    sample_patient,
)
from icenav.gym.spin import SpinConfig, SpinEnv
from icenav.gym.view_finding import ViewFindingConfig, ViewFindingEnv

__all__ = [
    "ENV_IDS",
    "EVALUATION_CATHETERS",
    "Patient",
    "SpinConfig",
    "SpinEnv",
    "TRAINING_CATHETERS",
    "ViewFindingConfig",
    "ViewFindingEnv",
    "sample_patient",
]

ENV_IDS = ("icenav/ViewFinding-v0", "icenav/Spin-v0")
"""The registered environment ids."""

for _id, _entry in zip(
    ENV_IDS,
    ("icenav.gym.view_finding:ViewFindingEnv", "icenav.gym.spin:SpinEnv"),
    strict=True,
):
    if _id not in gymnasium.registry:
        gymnasium.register(id=_id, entry_point=_entry)
