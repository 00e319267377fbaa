#!/usr/bin/env bash
# `make browser-tools`: headless Chromium from Debian's registry, with which
# tests/integration/test_browser_views.py opens the web viewer of a real run and looks at what
# it drew. As root with apt-get, it is installed if missing (~20 s); otherwise it says why
# not and succeeds, and the test prints "SKIPPED: <reason>".
set -euo pipefail

say() { echo "make browser-tools: $*"; }

if command -v chromium > /dev/null || command -v chromium-browser > /dev/null; then
    say "chromium is installed"
    exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
    say "SKIPPED: chromium missing and not root: install it to run the browser test"
    exit 0
fi
if ! command -v apt-get > /dev/null; then
    say "SKIPPED: chromium missing and no apt-get: install it to run the browser test"
    exit 0
fi
say "installing chromium"
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends chromium > /dev/null
say "installed"
