#!/usr/bin/env bash
# The browser tests/test_live_page.py drives (headless, through playwright): Debian's chromium if
# it is there or can be installed with apt (as root or with sudo), else Playwright's own build.
set -euo pipefail
# The npm packages of the tests (tests/js: @mcap/core, protobufjs for the Foxglove-reader test; iwer for the headset page and rehearsal tests), when npm is there.
if command -v npm >/dev/null 2>&1; then
    npm ci --prefix "$(dirname "$0")/../tests/js" --no-audit --no-fund --silent
fi
if command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; then
    exit 0
fi
if command -v apt-get >/dev/null 2>&1; then
    if [ "$(id -u)" = 0 ]; then
        apt-get update -qq && apt-get install -y -qq chromium >/dev/null && exit 0
    elif command -v sudo >/dev/null 2>&1; then
        sudo apt-get update -qq && sudo apt-get install -y -qq chromium >/dev/null && exit 0
    fi
fi
python -m playwright install chromium
