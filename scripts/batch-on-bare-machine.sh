#!/usr/bin/env bash
# Run a `pved batch` on a machine that has Python, torch and numpy but no pved install and
# no network (a batch node, a lent accelerator machine), from a copy of this checkout.
#
#   scripts/batch-on-bare-machine.sh WHEELS BATCH PACK_DIR DEADLINE_S [WORKERS]
#
# WHEELS: a folder of the wheels the machine lacks (for CPython 3.12 on x86-64, e.g.
#   pip download --no-deps --only-binary=:all: --python-version 3.12 \
#     --platform manylinux_2_28_x86_64 -d WHEELS mujoco==4.0.0 mujoco-core==4.0.0 \
#     gymnasium==1.4.0 farama-notifications==0.0.6 glfw==2.11.0 pyopengl==3.1.10
# ), installed into a temporary folder. Then `pved batch run` from src/ on WORKERS
# processes (default: every CPU) until DEADLINE_S, packing the run directories into
# PACK_DIR. Nothing renders, so MuJoCo's GL is switched off: a machine without EGL or
# OSMesa libraries runs the batch as well.
set -euo pipefail
if [ "$#" -lt 4 ]; then
  echo "usage: $0 WHEELS BATCH PACK_DIR DEADLINE_S [WORKERS]" >&2
  exit 2
fi
wheels=$1 batch=$2 pack=$3 deadline=$4 workers=${5:-$(nproc)}
here=$(cd "$(dirname "$0")/.." && pwd)
site=$(mktemp -d)
python3 -m pip install -q --no-index --no-deps --no-compile --target "$site" "$wheels"/*.whl
export PYTHONPATH="$site:$here/src${PYTHONPATH:+:$PYTHONPATH}" MUJOCO_GL=disable
python3 -m pved batch run --batch "$batch" --workers "$workers" --deadline-s "$deadline" \
  --pack "$pack"
