"""Does any published verdict depend on the bootstrap's seed? Every verdict the generated
tables print (``pved publish``: the paper's claims part by part and family-wise, each
method's standing against PPO, the Eq. 10 reruns), made anew under ``--seeds`` resampling
seeds at each ``--reps``; prints, per resample count, how many verdicts there are and how
many change between seeds, then each one that does (its verdicts and how many seeds gave
each), and the reacher ``quick`` ``pved-align`` standing, the one that once held "level"
in 15 of 20 seeds. :data:`pved.analysis.bootstrap.REPS` is chosen so that none changes.

    nice -n 19 .venv/bin/python benchmarks/interval_stability.py --reps 20000 200000 [--seeds 20]

Reads only the committed records (docs/protocol/); CPU time grows with reps x seeds
(about 22 s of one core per seed at 1,000,000 resamples).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from pved.analysis.publish import verdict_flips  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
WATCHED = "quick: pved-align against ppo on reacher"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, nargs="+", default=[20000])
    parser.add_argument("--seeds", type=int, default=20, help="resampling seeds 0..N-1")
    args = parser.parse_args()
    for reps in args.reps:
        start = time.process_time()
        counts = verdict_flips(ROOT, reps, range(args.seeds))
        flips = {label: by for label, by in counts.items() if len(by) > 1}
        cpu = time.process_time() - start
        print(
            f"reps {reps}: {len(counts)} verdicts, {len(flips)} change between "
            f"{args.seeds} seeds ({cpu:.0f} s CPU)"
        )
        for label, by in sorted(flips.items()):
            print(f"  {label}: " + ", ".join(f"{v} {n}" for v, n in by.items()))
        if WATCHED not in flips:
            watched = ", ".join(f"{v} {n}" for v, n in counts.get(WATCHED, {}).items())
            print(f"  {WATCHED}: {watched}")


if __name__ == "__main__":
    main()
