"""mrcomm/ChannelAssociation-v0's filters and scenes are strategies behind one interface (issue 10).

The three filters implement :class:`AssociationFilter` with the same ``step`` signature, and the
methods the environment reads (edges, unique matches, one observer's candidates) describe the same
i-state in all three. The i-state itself is read off the literal 0/1 matrix ``E`` of the dense filter.
"""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from mrcomm_env.channel_association.env import ChannelAssociationEnv
from mrcomm_env.channel_association.filters import AssociationFilter, BitsetFilter, DenseFilter, SparseFilter
from mrcomm_env.channel_association.scenes import DenseFieldScene, NeighborhoodScene, SparseFieldScene


def make_filters(n: int, extra: bool):
    return (
        DenseFilter(n, n, n, drop_time=3, extra_edges=extra),
        BitsetFilter(n, n, n, drop_time=3, extra_edges=extra),
        SparseFilter(n, drop_time=3, extra_edges=extra),
    )


def test_filters_implement_the_protocol_with_one_step_signature():
    protocol_step = list(inspect.signature(AssociationFilter.step).parameters)[1:]
    for f in make_filters(4, False):
        assert isinstance(f, AssociationFilter)
        params = inspect.signature(f.step).parameters.values()
        positional = [p.name for p in params if p.kind is p.POSITIONAL_OR_KEYWORD]
        assert len(positional) == len(protocol_step)  # extras, if any, are keyword-only
        assert all(p.default is not p.empty for p in params if p.kind is p.KEYWORD_ONLY)


@pytest.mark.parametrize("extra", [False, True])
def test_edges_matches_and_candidates_agree_with_the_istate(extra):
    rng = np.random.default_rng(4)
    n = 10
    filters = make_filters(n, extra)
    for f in filters:
        f.rng = np.random.default_rng(0)  # the same local labels in all three
    dense, _, sparse = filters
    keys = np.arange(n)[:, None] * n + np.arange(n)[None, :]
    for _ in range(40):
        in_range = rng.random((n, n)) < 0.7
        v_in = in_range & (rng.random((n, n)) < 0.8)
        emit = rng.random(n) < 0.5
        recv, vact = in_range & emit, v_in & emit
        for f in filters[:2]:
            f.step(recv, vact, v_in, lists=True)
        sparse.step(np.sort(keys[recv]), np.sort(keys[vact]), lambda k, v_in=v_in: v_in.ravel()[k], lists=True)
        E = dense.E
        edges = set(zip(*np.nonzero(E)))
        one = E.sum(1) == 1  # (observer, visual slot) with one candidate
        unique = {(b, h, s) for b, h, s in edges if one[b, s]}
        for f in filters:
            assert set(zip(*(a.tolist() for a in f.edges()))) == {tuple(map(int, e)) for e in edges}
            assert set(zip(*(a.tolist() for a in f.matches()))) == {tuple(map(int, e)) for e in unique}
            for b in range(n):
                cands = f.candidates(b)
                assert sorted(cands.values()) == sorted(
                    np.nonzero(E[b, :, s])[0].tolist() for s in np.nonzero(dense.vt[b])[0]
                )
                assert all(c == sorted(c) for c in cands.values())


@pytest.mark.parametrize(
    "kwargs,scene,backend",
    [
        ({"scene": "neighborhood"}, NeighborhoodScene, "bitset"),
        ({"scene": "neighborhood", "miss_tolerance": 1}, NeighborhoodScene, "dense"),
        ({"scene": "neighborhood", "w": 65, "v": 3}, NeighborhoodScene, "dense"),
        ({"n_robots": 64}, DenseFieldScene, "bitset"),
        ({"n_robots": 64, "miss_tolerance": 2}, DenseFieldScene, "dense"),
        ({"n_robots": 65}, SparseFieldScene, "sparse"),
    ],
)
def test_the_env_picks_its_strategies_at_construction(kwargs, scene, backend):
    env = ChannelAssociationEnv(**kwargs, max_cycles=5)
    env.reset(seed=0)
    assert type(env.scene) is scene and env.backend == backend
    assert isinstance(env.filter, AssociationFilter)
