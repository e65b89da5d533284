#!/usr/bin/env bash
# System packages pved needs beyond Python wheels, each installed with apt only when missing
# (a no-op when everything is there):
#   - OSMesa (libosmesa6) for offscreen MuJoCo rendering (MUJOCO_GL=osmesa);
#   - Chromium (chromium), the headless browser the tests open `pved report` HTML in.
set -euo pipefail

missing=()
if ! ldconfig -p 2>/dev/null | grep -q 'libOSMesa\.so'; then
  missing+=(libosmesa6)
fi
if ! command -v chromium >/dev/null 2>&1; then
  missing+=(chromium)
fi
if [ "${#missing[@]}" -eq 0 ]; then
  exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
  echo "install-system-deps: ${missing[*]} missing and apt-get is unavailable; install by hand" >&2
  exit 1
fi
SUDO=""
if [ "$(id -u)" != "0" ]; then SUDO="sudo"; fi
# One index update for everything that is missing.
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
