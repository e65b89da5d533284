#!/usr/bin/env bash
# Every pair's protocol at one budget, one pair after another, on this machine, in a way
# that outlives it: each pair is first restored from what the repository holds of it
# (`make restore`: its committed summary of finished runs, or a local archive; a pair
# already published comes back finished and is not run again), then run
# (`make reproduce`), its finished runs archived and summarised every 10 minutes while it
# runs (`make archive`), and, once its summary.json is there, its subspaces report made
# and everything published (`make subspaces`, `make publish`). Committing the summaries
# is left to whoever runs it. Rerunning the same command resumes.
#
#   BUDGET=paper WORKERS=2 PAIRS="walker-hopper jaco-fetch" bash scripts/protocol_queue.sh
set -u
cd "$(dirname "$0")/.."
BUDGET=${BUDGET:-paper}
WORKERS=${WORKERS:-2}
# reacher first: published at every budget it has, it is only restored, for `pved claims`
PAIRS=${PAIRS:-"reacher walker-hopper jaco-fetch humanoid-ant"}
ARCHIVE_EVERY_S=${ARCHIVE_EVERY_S:-600}

make .venv/.installed >/dev/null || exit 1
for pair in $PAIRS; do
    if [ -f "docs/protocol/$pair-$BUDGET/summary.json" ]; then
        # finished and published: a machine without its runs gets them back from the
        # committed summary, published files and all (`pved claims` reads their curves
        # when the next pair is published); nothing is made again
        if [ ! -f "reports/$pair-$BUDGET/summary.json" ]; then
            make restore PAIR="$pair" BUDGET="$BUDGET" || exit 1
        fi
        echo "$pair-$BUDGET: finished and published"
        continue
    fi
    if [ -f "docs/protocol/$pair-$BUDGET/protocol.json" ] || [ -d "archive/$pair-$BUDGET" ]; then
        make restore PAIR="$pair" BUDGET="$BUDGET" || exit 1
    fi
    # the archive keeps up while the protocol runs, and once more when it ends
    (while sleep "$ARCHIVE_EVERY_S"; do
        nice -n 10 make archive PAIR="$pair" BUDGET="$BUDGET" >/dev/null 2>&1
    done) &
    archiver=$!
    make reproduce PAIR="$pair" BUDGET="$BUDGET" WORKERS="$WORKERS"
    status=$?
    kill "$archiver" 2>/dev/null
    make archive PAIR="$pair" BUDGET="$BUDGET" || exit 1
    if [ "$status" -ne 0 ] || [ ! -f "reports/$pair-$BUDGET/summary.json" ]; then
        echo "$pair-$BUDGET: the protocol ended with status $status; stopping here" >&2
        exit 1
    fi
    make subspaces PAIR="$pair" BUDGET="$BUDGET" && make publish PAIR="$pair" BUDGET="$BUDGET" || exit 1
done
