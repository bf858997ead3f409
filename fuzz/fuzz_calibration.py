"""atheris harness: `python fuzz/fuzz_calibration.py -runs=N [corpus]` (see targets.py)."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import atheris  # noqa: E402

with atheris.instrument_imports():
    import icenav.compensation  # noqa: F401, E402
    import icenav.hw.config  # noqa: F401, E402
    import icenav.io.igtl  # noqa: F401, E402
    import icenav.io.joystick  # noqa: F401, E402
    import icenav.store  # noqa: F401, E402
    from fuzz.targets import TARGETS, seed_inputs  # noqa: E402

TARGET = TARGETS["calibration"]


def main() -> None:
    argv = list(sys.argv)
    if not any(not a.startswith("-") for a in argv[1:]):  # no corpus given: start from seeds
        corpus = Path(tempfile.mkdtemp(prefix="icenav-fuzz-calibration-"))
        for i, seed in enumerate(seed_inputs("calibration")):
            (corpus / f"seed{i}").write_bytes(seed)
        argv.append(str(corpus))
    atheris.Setup(argv, TARGET)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
