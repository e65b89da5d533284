#!/usr/bin/env bash
# Prepare a `pved batch` for a lent machine whose command carries at most 64 MiB of this
# checkout (the working tree, the wheels, the batch's models and banks together):
#
#   scripts/device-batch-prepare.sh BATCH LIMIT PROTOCOL [PROTOCOL...]
#
# Exports at most LIMIT runs of each PROTOCOL into BATCH (which must not exist; put it
# under a git-ignored `runs/` folder, e.g. devbatch/b, so that only `carry` moves it),
# claimed for 40 minutes, with `--max-input-mib` set to what is left of the 64 MiB after
# the tracked files and the wheels in .whl/ (and a 2 MiB margin), then prints what to
# carry and the command to run there. Bring the packed runs back with
#   .venv/bin/pved batch import --protocol PROTOCOL <files>/runs*.tar.gz
# and end the claims on the runs that did not come back with `pved batch release`.
set -euo pipefail
if [ "$#" -lt 3 ]; then
  echo "usage: $0 BATCH LIMIT PROTOCOL [PROTOCOL...]" >&2
  exit 2
fi
batch=$1 limit=$2
shift 2
cd "$(dirname "$0")/.."
if [ ! -d .whl ] || [ -z "$(ls .whl/*.whl 2>/dev/null)" ]; then
  echo ".whl/ holds no wheels: fetch them first (../shared/device/wheels.sh, versions as in .venv)" >&2
  exit 1
fi
tree=$(git ls-files -z | du -cb --files0-from=- | tail -1 | cut -f1)
wheels=$(du -cb .whl/*.whl | tail -1 | cut -f1)
room=$(( (64 * 1048576 - tree - wheels) / 1048576 - 2 ))
if [ "$room" -lt 1 ]; then
  echo "no room for a batch: tree $((tree / 1048576)) MiB + wheels $((wheels / 1048576)) MiB" >&2
  exit 1
fi
.venv/bin/pved batch export --protocol "$@" --batch "$batch" --limit "$limit" \
  --claim-minutes 40 --max-input-mib "$room"
echo "inputs: $(du -sm "$batch" | cut -f1) MiB of $room MiB left beside the tree and wheels"
echo "carry: [\".whl\", \"$batch/runs\"]"
echo "command: bash scripts/batch-on-bare-machine.sh .whl $batch \$OUT/b DEADLINE_S 16"
