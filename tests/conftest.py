"""Fixtures shared across the test packages."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest


@pytest.fixture(scope="session")
def ray_local() -> Iterator[Any]:
    """A local Ray instance with 2 CPUs on the loopback address, for the whole session
    (started on first use, shut down at the end); skips when Ray cannot be imported."""
    try:
        import ray
    except ImportError as exc:  # the optional extra icenav[cluster] is not installed
        pytest.skip(f"ray cannot be imported on this Python: {exc}")
    ray.init(
        num_cpus=2,
        include_dashboard=False,
        configure_logging=False,
        log_to_driver=False,
        _node_ip_address="127.0.0.1",
    )
    try:
        yield ray
    finally:
        ray.shutdown()


@pytest.fixture(scope="session")
def twin_catheter_calibration() -> Any:
    """A reduced dense+hysteresis fit on twin catheter 52 (a development seed), for the
    calibration-file tests (:func:`tests.support.model_files.small_catheter_calibration`;
    about 5 s on an idle core, once per session)."""
    from tests.support.model_files import small_catheter_calibration

    return small_catheter_calibration(52)
