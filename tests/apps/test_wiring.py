"""The console's anatomy from the wiring: meshes and their labels in the base frame."""

from __future__ import annotations

import numpy as np

from icenav.apps.wiring import anatomy_labels, anatomy_meshes
from icenav.sim.anatomy import BASE2ANATOMY, Tissue, default_phantom


def test_labels_anchor_each_mesh_in_the_base_frame() -> None:
    ph = default_phantom()
    meshes = {m.name: m for m in anatomy_meshes(ph)}
    labels = {lm.key: lm for lm in anatomy_labels(ph)}
    for key in ("ra", "rv", "la", "lv", "aorta", "ivc", "svc", "tricuspid_valve"):
        assert f"anatomy-{key}" in meshes
        mesh = meshes[f"anatomy-{key}"]
        p = np.asarray(labels[key].point)
        lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
        assert np.all(p >= lo - 1e-9) and np.all(p <= hi + 1e-9), key
    # the RA anchor maps back into RA blood
    ra = BASE2ANATOMY[:3, :3] @ np.asarray(labels["ra"].point) + BASE2ANATOMY[:3, 3]
    assert ph.labels_at(ra, 0.0) == Tissue.RA_BLOOD
    # orientation marker: anterior is base +x (the image direction at q = 0), superior +z
    np.testing.assert_allclose(labels["dir-A"].point, [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(labels["dir-S"].point, [0.0, 0.0, 1.0], atol=1e-12)
    assert labels["interatrial_septum"].label == "IAS"
