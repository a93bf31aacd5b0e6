#!/usr/bin/env bash
# In CI (CI=true), make sure headless Chromium is installed, for the test that loads eval's
# index.html in a real browser (about a minute of apt on a fresh Debian machine). Elsewhere it
# does nothing: that test then skips itself with one line when no Chromium is found.
set -euo pipefail
if [ "${CI:-}" != "true" ] || command -v chromium >/dev/null 2>&1; then
    exit 0
fi
if [ "$(id -u)" -ne 0 ] || ! command -v apt-get >/dev/null 2>&1; then
    echo "ensure-chromium: error: CI needs Chromium for the browser test; install Debian's 'chromium' package" >&2
    exit 1
fi
echo "ensure-chromium: installing Debian's chromium (for the eval page's browser test)" >&2
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq chromium >/dev/null
echo "ensure-chromium: installed: $(dpkg-query -W -f='${Package} ${Version}' chromium)" >&2
