#!/usr/bin/env bash
# System libraries pved needs beyond Python wheels: OSMesa for offscreen MuJoCo rendering
# (MUJOCO_GL=osmesa). Installed with apt when missing; a no-op when already there.
set -euo pipefail
if ldconfig -p 2>/dev/null | grep -q 'libOSMesa\.so'; then
  exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
  echo "install-system-deps: libOSMesa is missing and apt-get is unavailable; install OSMesa by hand" >&2
  exit 1
fi
SUDO=""
if [ "$(id -u)" != "0" ]; then SUDO="sudo"; fi
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libosmesa6 >/dev/null
