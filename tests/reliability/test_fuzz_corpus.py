"""The fuzz targets (fuzz/targets.py) over a seeded corpus of mutated inputs, without atheris,
so that CI exercises every loader and parser with bad input: each input is accepted or
rejected with an IcenavError, never anything else."""

from __future__ import annotations

import random
import sys
import tempfile
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from fuzz.targets import TARGETS, mutate, seed_inputs  # noqa: E402

N_INPUTS = {
    "store": 200,
    "store_rows": 60,
    "robot_config": 800,
    "joystick_mapping": 800,
    "calibration": 800,
    "igtl_command": 2000,
    "igtl_message": 2000,
}

# Loaders that let a non-icenav error out (none now: the robot-config and joystick-mapping
# loaders were fixed after this suite found them; add an entry to track a new finding).
KNOWN_DEFECTS: dict[str, tuple[type[BaseException], ...]] = {}


def test_every_target_has_a_seed_and_a_budget() -> None:
    assert set(N_INPUTS) == set(TARGETS)
    for name in TARGETS:
        assert seed_inputs(name)


@pytest.mark.parametrize("name", sorted(TARGETS))
def test_seeds_are_accepted(name: str) -> None:
    for seed in seed_inputs(name):
        TARGETS[name](seed)


@pytest.mark.parametrize("name", sorted(TARGETS))
def test_mutated_inputs_are_accepted_or_rejected_cleanly(name: str) -> None:
    rng = random.Random(f"icenav-{name}")
    seeds = seed_inputs(name)
    target = TARGETS[name]
    known = KNOWN_DEFECTS.get(name, ())
    n_known = 0
    for i in range(N_INPUTS[name]):
        data = mutate(rng.choice(seeds), rng, rng.randrange(1, 6))
        try:
            target(data)
        except known:
            n_known += 1
        except Exception as exc:
            path = Path(tempfile.gettempdir()) / f"icenav-fuzz-{name}-{i}.bin"
            path.write_bytes(data)
            raise AssertionError(f"{name}: input {i} (saved to {path}) raised {exc!r}") from exc
    assert n_known < N_INPUTS[name]  # most inputs reach the loader's own checks


def _load_mapping_text(tmp_path: Path, data: bytes) -> None:
    from icenav.control.teleop import load_mapping

    p = tmp_path / "m.toml"
    p.write_bytes(data)
    load_mapping(p)


def test_robot_config_not_utf8_is_a_file_format_error(tmp_path: Path) -> None:
    from icenav.devices.canopen.config import load_robot_config
    from icenav.errors import FileFormatError

    p = tmp_path / "r.toml"
    p.write_bytes(b"# \xff\n[bus]\n")
    with pytest.raises(FileFormatError):
        load_robot_config(p)


@pytest.mark.parametrize(
    "data",
    [b"# \xff\n", b"[joystick]\naxis_phi1 = [1]\n", b'knob_rate_deg = "x"\n', b"joystick = 3\n"],
    ids=["not-utf8", "list-index", "text-rate", "not-a-table"],
)
def test_bad_joystick_mapping_is_a_file_format_error(tmp_path: Path, data: bytes) -> None:
    from icenav.errors import FileFormatError

    with pytest.raises(FileFormatError):
        _load_mapping_text(tmp_path, data)
