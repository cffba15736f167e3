"""MemoExecutor: a batch simulates each distinct (choices, CAV mask, seed) once and reuses it."""

from __future__ import annotations

import numpy as np

from urb_jax.sumo_bridge.memo import MemoExecutor


class CountingExecutor:
    def __init__(self) -> None:
        self.days: list[tuple[tuple[int, ...], int, bool]] = []

    def run_days(self, scenario, choices, seeds, is_cav=None):
        masks = is_cav if is_cav is not None else [None] * len(seeds)
        out = []
        for c, s, m in zip(choices, seeds, masks, strict=True):
            self.days.append((tuple(int(x) for x in c), int(s), m is not None and bool(m[0])))
            out.append({"choices": tuple(int(x) for x in c), "seed": int(s)})  # a stand-in DayResult
        return out

    def close(self) -> None:
        pass


def test_duplicates_run_once_and_keep_batch_order():
    inner = CountingExecutor()
    memo = MemoExecutor(inner)
    scn = object()
    a, b = np.array([0, 1, 2]), np.array([3, 2, 1])
    res = memo.run_days(scn, np.stack([a, b, a, a]), [42, 42, 42, 7])
    assert len(inner.days) == 3  # (a, 42), (b, 42), (a, 7)
    assert res[0] is res[2] and res[0] is not res[3]
    res2 = memo.run_days(scn, np.stack([b, a]), [42, 42])  # all seen: nothing simulated
    assert len(inner.days) == 3 and res2[0] is res[1] and res2[1] is res[0]
    assert (memo.simulated, memo.reused) == (3, 3)


def test_cav_mask_is_part_of_the_key():
    inner = CountingExecutor()
    memo = MemoExecutor(inner)
    scn = object()
    c = np.array([[0, 1, 2]] * 2)
    memo.run_days(scn, c, [42, 42], is_cav=np.array([[True, False, False], [False, False, False]]))
    assert len(inner.days) == 2
