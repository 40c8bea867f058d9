"""Scripted emission policies for mrcomm/ChannelAssociation-v0 (Ivanov & Shell, paper 001).

* ``coin_flip`` — the paper's rule (Algorithms 1–2): every robot emits a message pair with probability ½.
* ``bernoulli`` — emit with probability ``p`` (§6.5 discusses p ≠ ½: fewer messages, slower elimination).
* ``id_bits`` — beyond the paper: a deterministic code. In step t robot i emits bit (t mod (B+1)) of its
  own address; step B of every cycle is a beacon in which everyone emits, so Algorithm 2 can pick up
  robots whose address bits are all 0. With ``bits`` = 0 the address is the robot index and
  B = ⌈log2 N⌉ (the smallest ID space holding the population): a known neighbourhood is then resolved
  after exactly B steps whatever its size. With ``bits`` = B > ⌈log2 N⌉ the addresses are distinct
  random B-bit numbers (a sparse global space such as IPv4 or MAC addresses, drawn from the policy
  seed); a neighbourhood is resolved once the address prefixes differ — like a coin flip, but never
  later than B steps.
* ``random`` — uniform random actions (the same distribution as ``coin_flip``, drawn through gymnasium).

Each robot uses only what it knows: its own ID (agent index) and the shared step clock.
"""

from __future__ import annotations

import math

import numpy as np

from mrcomm_baselines.common import RandomPolicy
from mrcomm_env.core.config import Int, Param, Real
from mrcomm_env.core.policy import Policy

ENV_ID = "mrcomm/ChannelAssociation-v0"
DEFAULT_POLICY = "coin_flip"


class BernoulliPolicy(Policy):
    """Each robot independently emits a message pair with probability ``p`` every step."""

    name = "bernoulli"
    FROM_PAPER = "§6.5, p ≠ ½"
    PARAMS = {
        "p": Param(
            0.5,
            "probability of emitting a message pair each step",
            Real(0.0, 1.0, lo_open=True, hi_open=True, fuzz=(0.05, 0.95)),
        )
    }

    #: uniform draws taken from the generator at once (for several steps of a small team). The generator
    #: fills doubles in order, so the coins are exactly those of one ``random(len(agents))`` per step.
    BLOCK = 1024

    def reset(self, views, seed=None):
        super().reset(views, seed)
        self._start(self.params["p"])

    def _start(self, p: float) -> None:
        self._p = p
        self._coins, self._at = [], 0  # drawn coins (0/1 ints) and the next unused one

    def act(self, observations, views):
        agents = list(observations)
        k, at = len(agents), self._at
        if at + k > len(self._coins):  # refill, keeping the unused coins first
            fresh = self.rng.random(max(k, self.BLOCK)) < self._p
            self._coins = self._coins[at:] + fresh.view(np.int8).tolist()
            at = 0
        self._at = at + k
        return dict(zip(agents, self._coins[at : at + k], strict=True))


class CoinFlipPolicy(BernoulliPolicy):
    """The paper's fair coin (p = ½)."""

    name = "coin_flip"
    FROM_PAPER = "Algorithms 1–2"
    PARAMS = {}

    def reset(self, views, seed=None):
        Policy.reset(self, views, seed)
        self._start(0.5)


class IdBitsPolicy(Policy):
    """Blink the bits of the own ID on a fixed schedule, with an all-emit beacon closing each cycle."""

    name = "id_bits"
    PARAMS = {"bits": Param(0, "ID length B in bits (0 = ⌈log2 N⌉)", Int(0, 64, fuzz=(0, 16)))}

    def reset(self, views, seed=None):
        super().reset(views, seed)
        n = views.n_agents
        dense = max(1, int(math.ceil(math.log2(n))))
        b = self.params["bits"] or dense
        if b < dense:
            raise ValueError(f"parameter 'bits' = {b} cannot give {n} robots distinct addresses (need ≥ {dense})")
        self.B = b
        if b == dense:
            ids = np.arange(n, dtype=np.uint64)
        else:  # distinct random addresses in a 2^B space
            ids = np.empty(0, dtype=np.uint64)
            while len(ids) < n:
                ids = np.unique(
                    np.concatenate((ids, self.rng.integers(0, 2**b, size=n, dtype=np.uint64, endpoint=False)))
                )
            ids = self.rng.permutation(ids)[:n]
        self.addresses = ids
        shifts = np.arange(b, dtype=np.uint64)
        #: (B + 1, N) schedule: row t = emissions in step t of each cycle; the last row is the beacon
        self.table = np.vstack(
            (((ids[None, :] >> shifts[:, None]) & np.uint64(1)).astype(np.int64), np.ones((1, n), dtype=np.int64))
        )
        self._index = {a: views.index(a) for a in views.possible_agents}

    def act(self, observations, views):
        row = self.table[views.step % (self.B + 1)]
        return {a: int(row[self._index[a]]) for a in observations}


POLICIES = {
    "coin_flip": CoinFlipPolicy,
    "bernoulli": BernoulliPolicy,
    "id_bits": IdBitsPolicy,
    "random": RandomPolicy,
}
