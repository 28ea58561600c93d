#!/usr/bin/env bash
# What the browser tests need: the npm packages of tests/js (@mcap/core and protobufjs for the Foxglove-reader test,
# iwer for the headset page and the rehearsal) and a headless Chromium (Debian's, else Playwright's own build).
# Nothing here is fatal: what cannot be installed is one warning, and the tests that need it skip with the reason.
set -uo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
warn() { echo "install-test-browser: warning: $*; the tests that need it will be skipped" >&2; }

if command -v npm >/dev/null 2>&1; then
    timeout 600 npm ci --prefix "$here/tests/js" --no-audit --no-fund --silent || warn "npm ci in tests/js failed"
fi
if command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; then
    exit 0
fi
sudo=""
[ "$(id -u)" = 0 ] || { command -v sudo >/dev/null 2>&1 && sudo="sudo -n"; }
if command -v apt-get >/dev/null 2>&1 && { [ "$(id -u)" = 0 ] || [ -n "$sudo" ]; }; then
    # apt waits for a lock another apt holds, but not for ever
    apt=($sudo apt-get -o DPkg::Lock::Timeout=300 -qq)
    if timeout 900 "${apt[@]}" update && timeout 900 "${apt[@]}" install -y chromium >/dev/null; then
        exit 0
    fi
    warn "apt-get could not install chromium"
fi
if timeout 600 python -m playwright install chromium >/dev/null 2>&1; then
    exit 0
fi
warn "no headless Chromium could be installed (neither apt nor Playwright's download)"
exit 0
