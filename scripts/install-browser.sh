#!/usr/bin/env bash
# Install what the console's browser test needs: Debian's chromium (at /usr/bin/chromium) and
# the Playwright Python package, which ships its own driver (we never run `playwright install`:
# it would download a browser build). Idempotent and quiet when all is installed already.
#
# Usage: scripts/install-browser.sh [PYTHON]
#   PYTHON: the interpreter to install playwright into (default: .venv/bin/python; run this
#   after `make install`). Needs root (or sudo) for apt-get when chromium is missing.
set -euo pipefail

cd "$(dirname "$0")/.."
PY="${1:-.venv/bin/python}"

if [ ! -x /usr/bin/chromium ]; then
    echo "install-browser: installing Debian chromium (apt-get)"
    SUDO=""
    if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
    export DEBIAN_FRONTEND=noninteractive
    $SUDO apt-get update -qq
    $SUDO apt-get install -y -qq --no-install-recommends chromium fonts-liberation \
        >/dev/null 2>&1 || {
        echo "install-browser: apt-get install chromium failed" >&2
        exit 1
    }
fi
if [ ! -x /usr/bin/chromium ]; then
    echo "install-browser: /usr/bin/chromium is still missing after apt-get" >&2
    exit 1
fi

if [ ! -x "$PY" ]; then
    echo "install-browser: no interpreter at $PY (run 'make install' first, or pass PYTHON)" >&2
    exit 1
fi
if ! "$PY" -c "import playwright.sync_api" >/dev/null 2>&1; then
    echo "install-browser: installing the playwright Python package into $PY"
    "$PY" -m pip install --quiet "playwright>=1.45"
fi
