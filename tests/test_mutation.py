"""The CAV draw reproduces RouteRL's: Python `random` seeded with the env seed, one
`random.uniform` per human (its beta, agents.csv order), then sequential choice + remove."""

from __future__ import annotations

import random

import numpy as np
import pytest

from urb_jax.core.errors import ConfigError
from urb_jax.game.mutation import draw_cavs


class _Human:
    def __init__(self, agent_id: int, beta: float, r: float) -> None:
        self.id = agent_id
        self.beta = random.uniform(beta - r, beta + r)  # RouteRL's Gawron.__init__


def _routerl_literal(seed: int, ids_csv_order: list[int], n_machines: int) -> set[int]:
    """RouteRL 2.0.0's sequence, written out as its code does it (global `random`)."""
    state = random.getstate()
    try:
        random.seed(seed)
        humans = [_Human(i, -1.5, 0.1) for i in ids_csv_order]
        filtered = list(humans)
        picked = []
        for _ in range(n_machines):
            h = random.choice(filtered)
            humans.remove(h)
            filtered.remove(h)
            picked.append(h.id)
        return set(picked)
    finally:
        random.setstate(state)


@pytest.mark.parametrize("seed,n,share", [(42, 222, 0.4), (0, 523, 0.4), (7, 400, 0.25), (42, 10, 1.0)])
def test_draw_matches_routerl_sequence(seed, n, share):
    ids = np.arange(n)
    # Scenario positions are departure-sorted: give position i a shuffled URB id.
    perm = np.random.default_rng(seed).permutation(n)
    mask = draw_cavs(seed, n, share, agent_id=ids[perm])
    expected = _routerl_literal(seed, list(range(n)), int(n * share))
    assert set(int(i) for i in ids[perm][mask]) == expected
    assert mask.sum() == int(n * share)


def test_numpy_draw_is_a_different_set_and_methods_are_checked():
    a = draw_cavs(42, 222, 0.4)
    b = draw_cavs(42, 222, 0.4, method="numpy")
    assert a.sum() == b.sum() == 88 and not np.array_equal(a, b)
    with pytest.raises(ConfigError, match="use one of"):
        draw_cavs(42, 222, 0.4, method="torch")
    with pytest.raises(ConfigError, match="ratio_machines"):
        draw_cavs(42, 222, 1.5)
