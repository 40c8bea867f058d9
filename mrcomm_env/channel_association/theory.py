"""The paper's models in code (Ivanov & Shell), plus exact results they are checked against.

Stationary neighbourhood (§4), w wireless and v ≤ w visual IDs, every robot emits with probability p:

* :func:`bp_completion_time` — eq. (1), the branching-process approximation ln(wv − v)/|ln m|, m = ½.
* :func:`fraction_matched_model` — eq. (2)–(3), F_t = F_init m^t and P = ((v − 1)/v)^F_t with w = v.
* :func:`exact_completion_time` — *exact* E[T] for p = ½ and any w, a cheaper route than the paper's
  absorbing chain over Bell(w) i-states. After t steps every robot has a uniform random t-bit activity
  string (M = 2^t values); the i-state is final exactly when each of the v visible robots' strings
  differs from all w − 1 other strings, so
  P(T ≤ t) = M(M−1)…(M−v+1) · (M−v)^(w−v) / M^w  and  E[T] = Σ_t P(T > t).
* :func:`markov_completion_time` — the absorbing Markov chain, exact for any p, on a lumped state
  space: an i-state is a partition of the wireless IDs into classes of identical history, and only the
  multiset of (visible, invisible) class sizes matters. Used for w ≤ 8 (the paper's range) and to
  cross-check the closed form.
* :func:`exact_fraction_matched` — exact E[fraction matched](t) = Σ_k C(t,k) p^k q^(t−k) (1 − p^k q^(t−k))^(w−1).
* :func:`fewest_emissions` — the fewest message pairs with which *any* policy, even one that knows the layout,
  makes every i-state of a stationary scene final within t steps: an integer program over the robots' t-step
  emission patterns (the bound docs/learning.md holds the learned codes to).

Mobile observer (§5), equal wireless and visual range r, speed d per step, density ρ (robots/area):

* :func:`edge_recursion` — eq. (4), the two sub-processes acting on the number of edges.
* :func:`overlap_area` — eq. (5); frontier = πr² − A_O(d); age-region areas A_k = A_O((k−1)d) − A_O(kd).
* :func:`two_region_model` — eq. (6)–(11): migrator + true + false edges, λ_T+ = E[v_new],
  λ_F+ = Var[v_new] + E[v_new]² − E[v_new] (eq. 10, variance from simulation), p− from eq. (11).
* :func:`multi_region_model` — eq. (12)–(13): one type per age region, survival A_(k+1)/A_k.
* :func:`mobile_fraction_matched_model` — §5.7: eq. (3) applied per age region, weighted by area.
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np
from scipy.optimize import Bounds, LinearConstraint, milp
from scipy.sparse import csr_matrix


# ====================================================================== stationary (§4)
def bp_completion_time(w: int, v: int, m: float = 0.5) -> float:
    """Eq. (1): expected extinction time of the false-edge population, ln(wv − v) / |ln m|."""
    return math.log(max(w * v - v, 1)) / abs(math.log(m))


def false_edges(w: int, v: int, t, m: float = 0.5):
    """Eq. (2): expected false edges after t steps, (wv − v) m^t."""
    return (w * v - v) * np.power(m, t)


def fraction_matched_model(v: int, t, m: float = 0.5):
    """Eq. (2)–(3) with w = v, as the paper sets it: ((v − 1)/v)^F_t."""
    t = np.asarray(t, dtype=np.float64)
    if v <= 1:
        return np.ones_like(t)
    return ((v - 1) / v) ** false_edges(v, v, t, m)


def completion_cdf(w: int, v: int, t: int) -> float:
    """Exact P(T ≤ t) for p = ½ (see the module docstring)."""
    if not 1 <= v <= w:
        raise ValueError(f"need 1 ≤ v ≤ w, got w={w}, v={v}")
    M = 2.0**t
    if M < v:
        return 0.0
    logp = sum(math.log1p(-i / M) for i in range(1, v)) if v > 1 else 0.0
    if w > v:
        if M == v:
            return 0.0
        logp += (w - v) * math.log1p(-v / M)
    return math.exp(logp)


def exact_completion_time(w: int, v: int, tol: float = 1e-15) -> float:
    """Exact E[T] for a fair coin: Σ_t (1 − P(T ≤ t)); terms vanish like w·v·2^-t."""
    total, t = 0.0, 0
    while True:
        tail = 1.0 - completion_cdf(w, v, t)
        total += tail
        t += 1
        if tail < tol and t > 2:
            return total
        if t > 4000:  # pragma: no cover - cannot happen for w < 2^60
            return total


def completion_pmf(w: int, v: int, t_max: int) -> np.ndarray:
    """Exact P(T = t) for t = 0 … t_max (p = ½)."""
    cdf = np.array([completion_cdf(w, v, t) for t in range(t_max + 1)])
    return np.diff(np.concatenate(([0.0], cdf)))


def fewest_emissions(
    tracked: list[tuple[int, np.ndarray, np.ndarray]], n_robots: int, steps: int
) -> tuple[int, np.ndarray] | None:
    """The fewest emissions (message pairs) that make every observer's i-state final within ``steps`` steps of a
    perfect channel, and the emission patterns that achieve it (``(n_robots, steps)`` bool, a robot per row); None
    when no patterns can (more robots must differ than 2^steps patterns allow).

    ``tracked`` lists ``(observer, wireless robots, visual robots)`` as :meth:`ChannelAssociationEnv.tracked_robots`
    gives it at the start of an episode. An edge survives exactly while its two IDs' activities agree (Algorithm 1,
    lines 15–16), so an i-state is final after the ``steps`` steps exactly when each visual robot's pattern differs
    from that of every other wireless robot of the same observer. Whatever a policy reads or adapts to, the patterns
    it emits in an episode that ends by ``steps`` satisfy that, so this is a lower bound for every policy; a policy
    that finishes earlier emitted a prefix, and padding it with silence changes neither distinctness nor cost.

    The program: x[r, c] = 1 when robot r emits pattern c (one pattern each); per observer and pattern, at most one
    robot of every group that must differ pairwise (its visual robots, alone and with each wireless-only robot) takes
    it; minimise the emissions Σ popcount(c) x[r, c]. HiGHS solves it to a zero gap."""
    if steps < 0 or n_robots < 1:
        raise ValueError(f"need steps ≥ 0 and n_robots ≥ 1, got steps={steps}, n_robots={n_robots}")
    k = 1 << steps
    popcount = np.array([bin(c).count("1") for c in range(k)], dtype=np.float64)
    groups = set()
    for _, wireless, visual in tracked:
        visual_set = {int(r) for r in visual}
        groups.add(tuple(sorted(visual_set)))
        groups.update(tuple(sorted(visual_set | {int(h)})) for h in wireless if int(h) not in visual_set)
    groups = {g for g in groups if len(g) > 1}
    if any(len(g) > k for g in groups):
        return None
    rows, cols = [], []
    for i, group in enumerate(sorted(groups)):  # row i * k + c: the group's robots share pattern c at most once
        members = np.asarray(group, dtype=np.int64)
        for pattern in range(k):
            rows.append(np.full(len(members), i * k + pattern))
            cols.append(members * k + pattern)
    variables = n_robots * k
    one_pattern = csr_matrix(
        (np.ones(variables), (np.repeat(np.arange(n_robots), k), np.arange(variables))), shape=(n_robots, variables)
    )
    constraints = [LinearConstraint(one_pattern, 1, 1)]
    if groups:
        row, col = np.concatenate(rows), np.concatenate(cols)
        distinct = csr_matrix((np.ones(len(row)), (row, col)), shape=(len(groups) * k, variables))
        constraints.append(LinearConstraint(distinct, -np.inf, 1))
    result = milp(
        np.tile(popcount, n_robots),
        constraints=constraints,
        integrality=np.ones(variables),
        bounds=Bounds(0, 1),
        options={"mip_rel_gap": 0.0},
    )
    if result.status != 0:
        return None
    chosen = result.x.reshape(n_robots, k).argmax(axis=1)
    patterns = ((chosen[:, None] >> np.arange(steps)[None, :]) & 1).astype(bool)
    return int(patterns.sum()), patterns


def markov_completion_time(w: int, v: int, p: float = 0.5) -> float:
    """Exact E[T] from the absorbing Markov chain on lumped i-states (any emission probability p).

    State: sorted tuple of (a, b) = (visible, invisible) sizes of the classes of wireless IDs with
    identical history that still matter (a ≥ 1 and not the finished (1, 0)). One step splits every
    class independently by who emitted; E[S] = (1 + Σ_{S'≠S} P(S→S') E[S']) / (1 − P(S→S)).
    """
    if not 1 <= v <= w:
        raise ValueError(f"need 1 ≤ v ≤ w, got w={w}, v={v}")
    q = 1.0 - p

    @cache
    def splits(a: int, b: int):
        """[(prob, ((a1, b1), (a2, b2)))] over how many visible/invisible members emitted."""
        out = []
        for a1 in range(a + 1):
            for b1 in range(b + 1):
                k = a1 + b1
                pr = math.comb(a, a1) * math.comb(b, b1) * p**k * q ** (a + b - k)
                out.append((pr, ((a1, b1), (a - a1, b - b1))))
        return out

    def norm(blocks):
        return tuple(sorted(x for x in blocks if x[0] >= 1 and x != (1, 0)))

    @cache
    def expect(state) -> float:
        if not state:
            return 0.0
        dist: dict = {(): 1.0}
        for a, b in state:  # convolve the independent splits
            nxt: dict = {}
            for rest, pr0 in dist.items():
                for pr, parts in splits(a, b):
                    key = rest + parts
                    nxt[key] = nxt.get(key, 0.0) + pr0 * pr
            dist = {}
            for key, pr in nxt.items():
                k = norm(key)
                dist[k] = dist.get(k, 0.0) + pr
        stay = dist.pop(state, 0.0)
        return (1.0 + sum(pr * expect(s) for s, pr in dist.items())) / (1.0 - stay)

    return expect(norm(((v, w - v),)))


def exact_fraction_matched(w: int, t, p: float = 0.5) -> np.ndarray:
    """Exact expected fraction of visible IDs with a unique history after t steps (w IDs in range)."""
    ts = np.atleast_1d(np.asarray(t, dtype=np.int64))
    out = np.empty(len(ts))
    for i, tt in enumerate(ts):
        k = np.arange(tt + 1)
        logc = np.array([math.lgamma(tt + 1) - math.lgamma(x + 1) - math.lgamma(tt - x + 1) for x in k])
        px = np.exp(k * math.log(p) + (tt - k) * math.log(1 - p))
        out[i] = float(np.sum(np.exp(logc) * px * (1.0 - px) ** (w - 1)))
    return out


# ====================================================================== mobile (§5)
def edge_recursion(m: float, new_edges, t0: float = 0.0) -> np.ndarray:
    """Eq. (4): T_t = T_(t−1) m + N_t — multiplicative elimination plus additive new edges."""
    out, T = [], t0
    for n_t in np.atleast_1d(new_edges):
        T = T * m + n_t
        out.append(T)
    return np.array(out)


def overlap_area(r: float, d) -> np.ndarray:
    """Eq. (5): area shared by two disks of radius r whose centres are d apart (0 for d ≥ 2r)."""
    d = np.minimum(np.asarray(d, dtype=np.float64), 2.0 * r)
    return 2.0 * r * r * np.arccos(d / (2.0 * r)) - d * np.sqrt(np.maximum(r * r - (d / 2.0) ** 2, 0.0))


def age_region_areas(r: float, d: float) -> np.ndarray:
    """Areas A_1 (frontier) … A_K of the regions that have been in range 1 … K steps (Fig. 19)."""
    if d <= 0:
        return np.array([math.pi * r * r])
    k_max = int(math.ceil(2.0 * r / d))
    k = np.arange(1, k_max + 1)
    return overlap_area(r, (k - 1) * d) - overlap_area(r, k * d)


def two_region_model(
    r: float,
    d: float,
    rho: float,
    var_new: float,
    steps: int = 400,
    m_t: float = 1.0,
    m_f: float = 0.5,
    start=(0.0, 0.0),
    true_exit: str = "paper",
) -> dict:
    """Eq. (6)–(11). Returns per-step true/false edges and the ratio of total to true edges.

    ``true_exit="paper"`` uses eq. (11) for both edge types; ``"single"`` lets a true edge (both IDs
    are one robot) leave with probability v_exit/v_rest only.
    """
    area = math.pi * r * r
    a_f = area - float(overlap_area(r, d))  # frontier (= exit) area
    e_new = rho * a_f
    lam_t = e_new  # λ_T+ = v_new
    lam_f = var_new + e_new**2 - e_new  # eq. (10)
    x = (rho * a_f) / (rho * (area - a_f))  # v_exit / v_rest (= w_exit / w_rest)
    p_out = 2 * x - x * x  # eq. (11)
    p_t = p_out if true_exit == "paper" else x
    M = np.array([[1.0, lam_t, lam_f], [0.0, m_t * (1 - p_t), 0.0], [0.0, 0.0, m_f * (1 - p_out)]])
    P = np.array([1.0, *start])
    hist = np.empty((steps, 3))
    for i in range(steps):  # eq. (8): P_{i+1} = P_i M
        P = P @ M
        hist[i] = P
    e_t, e_f = hist[:, 1], hist[:, 2]
    return {
        "true": e_t,
        "false": e_f,
        "ratio": (e_t + e_f) / np.maximum(e_t, 1e-12),
        "steady_ratio": 1.0 + (lam_f / (1 - m_f * (1 - p_out))) / (lam_t / (1 - m_t * (1 - p_t))),
        "lambda_t": lam_t,
        "lambda_f": lam_f,
        "p_out": p_out,
    }


def multi_region_model(
    r: float, d: float, rho: float, var_new: float, steps: int = 400, m_t: float = 1.0, m_f: float = 0.5
) -> dict:
    """Eq. (12)–(13): one edge type per age region; survival to the next region A_(k+1)/A_k."""
    A = age_region_areas(r, d)
    e_new = rho * A[0]
    lam = {"true": e_new, "false": var_new + e_new**2 - e_new}
    surv = np.append(A[1:] / A[:-1], 0.0)  # the last region leaves the range
    out = {}
    for kind, m in (("true", m_t), ("false", m_f)):
        pop = np.zeros(len(A))
        tot = np.empty(steps)
        for i in range(steps):
            pop = np.concatenate(([lam[kind]], (pop * surv * m)[:-1]))
            tot[i] = pop.sum()
        out[kind] = tot
    out["ratio"] = (out["true"] + out["false"]) / np.maximum(out["true"], 1e-12)
    out["steady_ratio"] = float(out["ratio"][-1])
    return out


def mobile_fraction_matched_model(r: float, d: float, rho: float, m: float = 0.5) -> float:
    """§5.7: each age region is an independent i-state of v_k = ρA_k IDs filtered for k steps."""
    A = age_region_areas(r, d)
    k = np.arange(1, len(A) + 1)
    v = rho * A
    with np.errstate(divide="ignore", invalid="ignore"):
        p = np.where(v > 1.0, ((v - 1.0) / v) ** ((v * v - v) * m**k), 1.0)
    return float(np.sum(A * p) / np.sum(A))
