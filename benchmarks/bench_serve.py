"""``icenav serve`` streaming in real time to a pyigtl client, with a second idle client.

Starts ``icenav serve`` (the twin, catheter seed 101) as its own process on a free port,
connects an idle pyigtl client and a watching one, and counts for ``ICENAV_BENCH_SERVE_S``
seconds (default 60, the issue's) the distinct ``TipToBase`` and ``Image`` messages (distinct
timestamps) the watching client receives per second. Baseline, measured in the same run: the
rates the server reports having sent over its whole run (its own count), so the ratio shows
what the network path loses. Targets (issue): >= 30 poses/s and >= 15 images/s.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from typing import Any

import pyigtl

from benchmarks.common import Result

DURATION_S = float(os.environ.get("ICENAV_BENCH_SERVE_S", "60"))


class _CountingClient(pyigtl.OpenIGTLinkClient):  # type: ignore[misc]
    """pyigtl's client, keeping the timestamps of every message per device."""

    def __init__(self, port: int) -> None:
        self.stamps: dict[str, set[float]] = {}
        self.counting = threading.Event()
        super().__init__(host="127.0.0.1", port=port)

    def _receive_message_from_socket(self, ssocket: socket.socket) -> bool:
        got = bool(super()._receive_message_from_socket(ssocket))
        if got:
            with self.lock_incoming_messages:
                new = list(self.incoming_messages.values())
                self.incoming_messages = {}
            if self.counting.is_set():
                for m in new:
                    self.stamps.setdefault(m.device_name, set()).add(m.timestamp)
        return got


def _measure(duration_s: float) -> dict[str, Any]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "icenav.apps.cli", "serve", "--igtl-port", "0", "--no-gamepad"]
        + ["--seed", "101"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    port = None
    for line in proc.stdout:
        m = re.search(r"OpenIGTLink on 127\.0\.0\.1:(\d+)", line)
        if m:
            port = int(m.group(1))
            break
    if port is None:
        raise RuntimeError(f"icenav serve did not start: {proc.communicate()[1]}")
    t_start = time.monotonic()
    idle = _CountingClient(port)
    watcher = _CountingClient(port)
    try:
        time.sleep(2.0)  # connect and warm up (a benchmark, not a test)
        watcher.counting.set()
        t0 = time.monotonic()
        time.sleep(duration_s)
        watcher.counting.clear()
        elapsed = time.monotonic() - t0
    finally:
        for c in (watcher, idle):
            c.stop()
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    run_s = time.monotonic() - t_start
    sent = re.search(r"sent (\d+) poses and (\d+) images", out)
    if proc.returncode != 0 or sent is None:
        raise RuntimeError(f"icenav serve failed (exit {proc.returncode}): {err}")
    return {
        "pose_rate": len(watcher.stamps.get("TipToBase", ())) / elapsed,
        "image_rate": len(watcher.stamps.get("Image", ())) / elapsed,
        "sent_pose_rate": int(sent.group(1)) / run_s,
        "sent_image_rate": int(sent.group(2)) / run_s,
    }


def main() -> list[Result]:
    r = _measure(DURATION_S)
    return [
        Result(
            f"serve: distinct TipToBase received ({DURATION_S:.0f} s, 2 clients)",
            r["pose_rate"],
            "/s",
            baseline=r["sent_pose_rate"],
            baseline_name="poses sent by the server over its run",
            target=">= 30 /s",
            met=r["pose_rate"] >= 30.0,
        ),
        Result(
            f"serve: distinct Image received ({DURATION_S:.0f} s, 2 clients)",
            r["image_rate"],
            "/s",
            baseline=r["sent_image_rate"],
            baseline_name="images sent by the server over its run",
            target=">= 15 /s",
            met=r["image_rate"] >= 15.0,
        ),
    ]


if __name__ == "__main__":
    from benchmarks.common import print_results

    print_results(main())
