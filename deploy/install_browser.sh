#!/usr/bin/env bash
# `make browser-tools`: headless Chromium from Debian's registry, with which
# tests/integration/test_browser_views.py opens the web viewer of a real run and looks at what
# it drew. As root with apt-get, it is installed if missing (~20 s); otherwise it says why
# not and succeeds, and the test prints "SKIPPED: <reason>".
set -euo pipefail

say() { echo "make browser-tools: $*"; }
source "$(dirname "${BASH_SOURCE[0]}")/apt_lib.sh"

if command -v chromium > /dev/null || command -v chromium-browser > /dev/null; then
    say "chromium is installed"
    exit 0
fi
install_or_skip chromium "install it to run the browser test"
say "installing chromium"
apt_install chromium
say "installed"
