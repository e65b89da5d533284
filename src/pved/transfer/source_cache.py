"""The source half of Eq. 10, encoded once per run.

Eq. 10's term is D(q_φS(c | s_S, a_S), q_φT(c | s_T, a_T)). The source row (s_S, a_S)
comes from the bank (``source_bank.py``), which is fixed for the whole run, so its
posterior q_φS depends on nothing the target does: :func:`encode_bank` encodes every bank
row once, and each step looks the posteriors up (:meth:`EncodedBank.lookup`); the
target's rows are encoded once per rollout (:meth:`ShapedBatchedEnv.deferred_terms`).
Until 2026-12-05 both halves were encoded at every step, which cost reacher, whose
physics is cheapest, a fifth of plain PPO's rate (docs/results.md, "What the shaping
costs a run").

The looked-up posteriors are the per-step encoder's to the bit, so the term and the runs
are unchanged and no config key marks the change. What that takes (measured with torch's
MKL on this project's machine): MKL picks its matrix kernel by the batch's row count and
by its thread count, and may round a row otherwise under another. On one thread (PPO's)
a row came out alike in every batch of 16 to 4,096 rows, a multiple of 16 (each
preset's encoder shapes are tested), and alike wherever it sat in a 16-row batch, but
otherwise alone or as a batch's 17th row; on two threads, 16 rows came out otherwise
than 32 or 512. So the bank is encoded on the caller's threads (as the per-step encode
ran), in batches of the row count the shaping is called with (a step's copies, 16 in
every transfer run), or of a multiple of it up to :data:`SINGLE_THREAD_ROWS` on one
thread, the last batch padded with copies of the last row. A caller whose batches
differ in size (the Gymnasium wrapper's single env, encoded :data:`MIN_BATCH_ROWS` rows
at a time) gets the term to float32 rounding (tests/test_shaping_cache.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from pved.errors import PvedError
from pved.models.base import SharedRep, SharedSpaceModel
from pved.transfer.source_bank import SourceBank, source_steps

#: Fewest rows per encoder batch: a single env's bank would otherwise take one forward
#: pass per row (200,000 on humanoid-ant's bank).
MIN_BATCH_ROWS = 16
#: Most rows per encoder batch on one thread: 16-row batches take 4 s on a 200,000-row
#: bank (busy machine), 512-row ones 0.8 s.
SINGLE_THREAD_ROWS = 512


def encode_batch_rows(call_rows: int) -> int:
    """Rows per encoder batch for a shaping called with ``call_rows`` rows at a time,
    that keep the per-step encode's bits (module docstring): ``call_rows`` (at least
    :data:`MIN_BATCH_ROWS`), or on one torch thread its largest multiple up to
    :data:`SINGLE_THREAD_ROWS`."""
    rows = max(int(call_rows), MIN_BATCH_ROWS)
    if torch.get_num_threads() == 1:
        rows *= max(1, SINGLE_THREAD_ROWS // rows)
    return rows


@dataclass(frozen=True)
class EncodedBank:
    """q_φS(c | x_S) of every bank row (the model's ``shared_source``).

    Attributes:
        bank: the bank encoded (compared by identity, so a bank swapped in is encoded anew).
        batch_rows: rows per encoder batch it was encoded with.
        mean: (E, T_max, K) float32, the posterior means (or points).
        logvar: (E, T_max, K) float32 log-variances; None for a deterministic model.
    """

    bank: SourceBank
    batch_rows: int
    mean: np.ndarray
    logvar: np.ndarray | None

    def lookup(self, episode: np.ndarray, t: np.ndarray, time_scale: float = 1.0) -> SharedRep:
        """The source posteriors (N, K) of bank episodes ``episode`` (N,) at the source step
        matching target step ``t`` (N,), the row :meth:`SourceBank.lookup` reads."""
        step = source_steps(t, self.bank.lengths[episode], time_scale)
        logvar = None if self.logvar is None else torch.from_numpy(self.logvar[episode, step])
        return SharedRep(torch.from_numpy(self.mean[episode, step]), logvar)


def encode_bank(
    model: SharedSpaceModel, bank: SourceBank, batch_rows: int = MIN_BATCH_ROWS
) -> EncodedBank:
    """Encode every row of ``bank`` with ``model.shared_source``, ``batch_rows`` rows a
    batch (module docstring), on the caller's threads as the per-step encode ran: the
    BLAS's kernel also depends on its thread count (one in PPO)."""
    if batch_rows < 1:
        raise PvedError(f"the bank is encoded in batches of >= 1 rows, not {batch_rows}")
    episodes, t_max, dim = bank.x.shape
    rows = np.asarray(bank.x).reshape(-1, dim)
    n = len(rows)
    padded = -(-n // batch_rows) * batch_rows
    if padded > n:  # repeat the last row: the pad is encoded and dropped
        rows = np.concatenate([rows, np.repeat(rows[-1:], padded - n, axis=0)])
    x = torch.as_tensor(rows, dtype=torch.float32)
    means, logvars = [], []
    with torch.no_grad():
        for batch in x.split(batch_rows):
            rep = model.shared_source(batch)
            means.append(rep.mean)
            if rep.logvar is not None:
                logvars.append(rep.logvar)
    mean = torch.cat(means)[:n].numpy().reshape(episodes, t_max, -1)
    logvar = torch.cat(logvars)[:n].numpy().reshape(episodes, t_max, -1) if logvars else None
    return EncodedBank(bank, batch_rows, mean, logvar)
