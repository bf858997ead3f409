"""atheris harness for every loader and parser: ``python fuzz/fuzz.py TARGET -runs=N [corpus]``.

TARGET is one of ``fuzz.targets.TARGETS`` (store, store_rows, robot_config,
joystick_mapping, calibration, igtl_command, igtl_message). Without a corpus directory the
run starts from the target's built-in seeds. Needs the ``fuzz`` extra
(``pip install -e '.[fuzz]'``); ``make test`` runs a seeded corpus of mutated inputs
instead (tests/reliability).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import atheris  # noqa: E402

with atheris.instrument_imports():
    import icenav.compensation.elasticity  # noqa: F401, E402
    import icenav.control.teleop  # noqa: F401, E402
    import icenav.devices.canopen.config  # noqa: F401, E402
    import icenav.io.igtl  # noqa: F401, E402
    import icenav.io.igtl_wire  # noqa: F401, E402
    import icenav.persistence.store  # noqa: F401, E402
    from fuzz.targets import TARGETS, seed_inputs  # noqa: E402


def main() -> None:
    if len(sys.argv) < 2 or sys.argv[1] not in TARGETS:
        sys.exit(
            f"usage: python fuzz/fuzz.py TARGET [libFuzzer options]; TARGET in {sorted(TARGETS)}"
        )
    name = sys.argv[1]
    argv = [sys.argv[0], *sys.argv[2:]]
    if not any(not a.startswith("-") for a in argv[1:]):  # no corpus given: start from seeds
        corpus = Path(tempfile.mkdtemp(prefix=f"icenav-fuzz-{name}-"))
        for i, seed in enumerate(seed_inputs(name)):
            (corpus / f"seed{i}").write_bytes(seed)
        argv.append(str(corpus))
    atheris.Setup(argv, TARGETS[name])
    atheris.Fuzz()


if __name__ == "__main__":
    main()
