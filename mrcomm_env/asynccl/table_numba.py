"""One exchange of eq. (4)-(5) over all links of a small team, compiled (numba): ``InfoTables._exchange_dense``,
then the new complete frontiers, delay statistics (eq. (7)) and discard rule (``InfoTables._settle``).

The same integer bookkeeping and bit counts (sums of whole bits, exact in float64) as the pairwise exchange
``InfoTables._exchange_pairs``, written as loops over (sender j, receiver i, row v). The pairwise exchange handles
every case (any N, budgets, the q-rule variants) and is this kernel's oracle: ``tests/asynccl/test_asynccl.py``
checks that both give identical tables and bits.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from mrcomm_env.core.backend import configure_numba_cache

configure_numba_cache()  # before the @njit(cache=True) below: never cache into the package

NO_ROW_LIMIT = 2**62  # larger than any step index (a plain constant: numba freezes it at compile time)


@njit(cache=True)
def offers(modes, latest, disc, t, scheme1, qinf):
    """``InfoTables._offers``: the upper end of each row a sender offers, from T_t^{j-} (eq. (4)-(5)), (N senders,
    N rows): its whole table (q = ∞, and silent senders, who send nothing), only its own row up to t (Scheme 1), or
    its rows up to its discard frontier + q (Scheme 2); ``latest`` itself when every sender is at q = ∞."""
    n = latest.shape[0]
    every_qinf = True
    for j in range(n):
        if modes[j] < qinf:
            every_qinf = False
    if every_qinf:
        return latest
    hi_s = latest.copy()
    for j in range(n):
        m = modes[j]
        if m == scheme1:
            for v in range(n):
                hi_s[j, v] = -1
            hi_s[j, j] = t
        elif m >= 1 and m < qinf:
            cap = disc[j] + m
            for v in range(n):
                if latest[j, v] > cap:
                    hi_s[j, v] = cap
    return hi_s


@njit(cache=True)
def exchange_dense(
    modes,
    adj,
    delivered,
    latest,
    disc,
    known,
    c,
    cum_bits,
    W,
    silent,
    scheme1,
    qinf,
    header_bits,
    entry_bits,
    t,
    hist_diff,
    delay_sum,
    oracle,
):
    """Bits and links per sender, the new ``latest``, ``known``, ``c`` and ``disc``, and the delay statistics.

    Returns (bits, links, latest, known, c, disc, delay_sum, added delay count, any_link); ``hist_diff`` is
    updated in place. Each sender's offers are :func:`offers`. With no link at all nothing changes (``any_link``
    False).
    """
    n = latest.shape[0]
    hi_s = offers(modes, latest, disc, t, scheme1, qinf)
    bits = np.zeros(n)
    links = np.zeros(n)
    any_link = False
    for j in range(n):
        if modes[j] == silent:
            continue
        for i in range(n):
            if adj[j, i]:
                links[j] += 1.0
                any_link = True
    new_latest = latest.copy()
    new_known = known.copy()
    if not any_link:
        return bits, links, latest, known, c, disc, delay_sum, 0, False
    for j in range(n):
        if links[j] == 0.0:
            continue
        header = header_bits
        if modes[j] >= qinf:  # q = ∞ sends its list L_j: one entry per non-discarded row
            for v in range(n):
                if latest[j, v] > disc[j]:
                    header += entry_bits
        payload = 0.0  # packets hi_s[j, v] ≥ k > latest[i, v] of every row the receiver lacks
        for i in range(n):
            if adj[j, i]:
                for v in range(n):
                    if hi_s[j, v] > latest[i, v]:
                        payload += cum_bits[v, (hi_s[j, v] + 1) % W] - cum_bits[v, (latest[i, v] + 1) % W]
        bits[j] = payload + header * links[j]
    for j in range(n):
        if modes[j] == silent:
            continue
        for i in range(n):
            if not (adj[j, i] and delivered[j, i]):
                continue
            after = NO_ROW_LIMIT  # min over rows of what j knows i holds after its own delivery
            for v in range(n):
                if hi_s[j, v] > new_latest[i, v]:
                    new_latest[i, v] = hi_s[j, v]
                if disc[j] > new_known[i, v]:  # i learns j's discard frontier ...
                    new_known[i, v] = disc[j]
                after = min(after, max(latest[i, v], hi_s[j, v]))
            if c[j] > new_known[i, j]:  # ... and j's complete frontier
                new_known[i, j] = c[j]
            if after > new_known[j, i]:
                new_known[j, i] = after
    # ``_settle``: steps c+1 … c_new become computable at t, delays t − k (eq. (7)); histogram as differences
    new_c = c.copy()
    added = 0
    for i in range(n):
        frontier = t
        for v in range(n):
            frontier = min(frontier, new_latest[i, v])
        if frontier > c[i]:
            ai, bi = c[i], frontier
            delay_sum += (bi - ai) * t - (ai + bi + 1) * (bi - ai) / 2.0
            added += bi - ai
            hist_diff[t - bi] += 1
            hist_diff[t - ai] -= 1
            new_c[i] = frontier
    new_disc = disc.copy()
    lowest = new_c.min()
    for i in range(n):
        new_known[i, i] = new_c[i]  # what robot i itself has complete
    for i in range(n):
        if oracle:  # variant: a column is dropped as soon as every robot has it
            new_disc[i] = lowest
        else:  # discard rule of §III-A.3 / §III-B.3: complete here and known complete everywhere
            m = new_known[i, 0]
            for v in range(1, n):
                m = min(m, new_known[i, v])
            new_disc[i] = max(disc[i], m)
    return bits, links, new_latest, new_known, new_c, new_disc, delay_sum, added, True
