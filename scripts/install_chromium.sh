#!/usr/bin/env bash
# Headless Chromium for the UI test (tests/test_ui.py) and screenshots of the MLflow UI.
# Idempotent: does nothing when `chromium` is already on PATH; otherwise installs Debian's
# `chromium` package (and fonts-liberation, so pages have text) with apt-get (non-interactive,
# quiet; through sudo when not root).
# Exit status: 0 when `chromium` is on PATH afterwards, 1 otherwise (with the reason on stderr).
set -euo pipefail

if command -v chromium >/dev/null 2>&1; then
    exit 0
fi

if ! command -v apt-get >/dev/null 2>&1; then
    echo "install_chromium.sh: chromium is not installed and there is no apt-get here;" \
         "install Chromium (a 'chromium' command on PATH) by hand" >&2
    exit 1
fi

SUDO=()
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
        SUDO=(sudo -n)
    else
        echo "install_chromium.sh: chromium is not installed; installing it needs root" \
             "(run: sudo apt-get install chromium)" >&2
        exit 1
    fi
fi

export DEBIAN_FRONTEND=noninteractive
# another apt/dpkg (e.g. unattended-upgrades) may hold the lock for a while: wait for it
APT_OPTS=(-qq -y -o DPkg::Lock::Timeout=600 -o Dpkg::Use-Pty=0)
echo "install_chromium.sh: installing Debian's chromium package ..." >&2
# a failed index update is not fatal: the package may still be installable from the current lists
"${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get "${APT_OPTS[@]}" update >/dev/null \
    || echo "install_chromium.sh: apt-get update failed; trying the current package lists" >&2
"${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get "${APT_OPTS[@]}" \
    install --no-install-recommends chromium fonts-liberation >/dev/null

if ! command -v chromium >/dev/null 2>&1; then
    echo "install_chromium.sh: apt-get finished but there is still no chromium on PATH" >&2
    exit 1
fi
echo "install_chromium.sh: $(chromium --version 2>/dev/null)" >&2
