"""numpy's PCG64, compiled (``core/pcg64_numba.py``): the same numbers and the same generator state as numpy's
``Generator`` over interleaved draws of every kind the copy-axis worlds make (uniform floats, bounded integers whose
32-bit halves numpy buffers between calls), from drawn seeds."""

from __future__ import annotations

import numpy as np
import pytest

from mrcomm_env.core import pcg64_numba as pcg


@pytest.mark.parametrize("trial", range(20))
def test_compiled_draws_are_numpys_and_leave_its_state(trial):
    plan = np.random.default_rng(1000 + trial)  # what to draw: kinds, sizes and ranges, reproducibly
    seed = int(plan.integers(2**63))
    reference, mirrored = np.random.default_rng(seed), np.random.default_rng(seed)
    state = np.zeros(pcg.STATE_WORDS, dtype=np.uint64)
    pcg.state_of(mirrored, state)
    for _ in range(40):
        size = int(plan.integers(0, 40))
        if plan.random() < 0.4:
            want, got = reference.random(size), np.empty(size)
            pcg.random_fill(state, got)
        else:  # Protocol 1's 100n picks, small ranges (rejections are likely), ranges up to 2^32 − 1
            low = int(plan.integers(0, 5))
            high = low + int(plan.choice([1, 2, 3, 100, 25_600, 6_553_600, 2**31 + 7, 2**32 - 1]))
            want, got = reference.integers(low, high, size=size), np.empty(size, dtype=np.int64)
            pcg.integers_fill(state, low, high, got)
        assert got.tobytes() == want.tobytes()
    pcg.set_state(mirrored, state)
    assert mirrored.bit_generator.state == reference.bit_generator.state  # the buffered 32-bit half included


def test_only_a_pcg64_state_is_taken():
    with pytest.raises(ValueError, match="needs a PCG64 generator, got MT19937"):
        pcg.state_of(np.random.Generator(np.random.MT19937(0)), np.zeros(pcg.STATE_WORDS, dtype=np.uint64))
