#!/usr/bin/env bash
# Install Debian's headless-capable Chromium when it is missing (the report's browser test uses it).
# Idempotent: prints the binary's path and does nothing else when Chromium is already there.
# Needs root (or sudo) for apt-get; downloads nothing but Debian packages.
set -euo pipefail
for exe in "${CHROMIUM:-}" /usr/bin/chromium /usr/bin/chromium-browser; do
    if [ -n "$exe" ] && [ -x "$exe" ]; then echo "$exe"; exit 0; fi
done
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
    command -v sudo >/dev/null || { echo "install_chromium.sh: Chromium is missing and installing it needs root (apt-get install -y chromium)" >&2; exit 1; }
    SUDO="sudo -n"
fi
export DEBIAN_FRONTEND=noninteractive
echo "install_chromium.sh: installing Debian's chromium package" >&2
$SUDO apt-get update -qq >&2
$SUDO apt-get install -y -qq --no-install-recommends chromium fonts-dejavu-core >&2
[ -x /usr/bin/chromium ] || { echo "install_chromium.sh: apt-get finished but /usr/bin/chromium is missing" >&2; exit 1; }
echo /usr/bin/chromium
