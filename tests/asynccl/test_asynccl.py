"""AsyncCL-v0: information tables, delays against the paper's analysis, bits, memory, bad input."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from helpers.asynccl_reference import own_pose_traces, reference_errors, reference_observation
from helpers.numerics import assert_close_conditioned, tolerance

from mrcomm_baselines import make_policy
from mrcomm_env.asynccl import env_numba, theory
from mrcomm_env.asynccl.table import QINF, SCHEME1, SILENT, InfoTables
from mrcomm_env.asynccl.world import HEADER_BITS, LIST_ENTRY_BITS
from mrcomm_env.asynccl_v0 import parallel_env
from mrcomm_env.core.comm import apply_packet_loss, bernoulli_links


# ------------------------------------------------------------------------------------------ tables
def set_reference(n, modes_seq, links_seq):
    """Eq. (4)-(5) with explicit sets of (robot, step): S_k^j from T_k^{j-}, T^+ = T^- ∪ received."""
    held = [{(i, 0)} for i in range(n)]
    frontiers = []
    for t, (mode, adj) in enumerate(zip(modes_seq, links_seq, strict=True)):
        before = [set(h) for h in held]
        for j in range(n):
            if mode[j] == SILENT:
                continue
            offer = {(v, k) for (v, k) in before[j] if mode[j] == QINF or v == j}
            for i in np.nonzero(adj[j])[0]:
                held[i] |= offer
        frontiers.append(
            [
                min(max(k for (v, k) in held[i] if v == r) if any(v == r for v, _ in held[i]) else -1 for r in range(n))
                for i in range(n)
            ]
        )
        for i in range(n):
            held[i].add((i, t + 1))
    return frontiers


@pytest.mark.parametrize("mode", [QINF, SCHEME1, "mixed"])
def test_complete_frontiers_match_explicit_information_sets(mode):
    rng = np.random.default_rng(7)
    n, steps = 5, 60
    modes_seq = [rng.choice([SILENT, SCHEME1, QINF], n) if mode == "mixed" else np.full(n, mode) for _ in range(steps)]
    links_seq = [bernoulli_links(rng, n, 0.4) for _ in range(steps)]
    ref = set_reference(n, modes_seq, links_seq)
    tab = InfoTables(n, 1000)
    tab.reset(np.full(n, 100.0))
    for t in range(steps):
        tab.exchange(modes_seq[t], links_seq[t], links_seq[t], None)
        # the complete frontier is the oldest row end (rows are prefixes)
        np.testing.assert_array_equal(tab.c, np.minimum(ref[t], t), err_msg=f"step {t}")
        tab.new_step(np.full(n, 100.0))


def test_qinf_sends_exactly_the_missing_packets_plus_the_list():
    """D1/D2 book-keeping: payload = packets the receiver lacks; header = L_i entries + frontiers."""
    rng = np.random.default_rng(3)
    n = 4
    tab = InfoTables(n, 1000)
    sizes = {}
    b0 = rng.integers(100, 400, n).astype(float)
    tab.reset(b0)
    sizes.update({(v, 0): b0[v] for v in range(n)})
    held = [{(i, 0)} for i in range(n)]
    modes = np.full(n, QINF)
    for t in range(40):
        adj = bernoulli_links(rng, n, 0.3)
        before = [set(h) for h in held]
        disc, latest = tab.disc.copy(), tab.latest.copy()
        bits, links = tab.exchange(modes, adj, adj, None)
        for j in range(n):
            expect = 0.0
            for i in np.nonzero(adj[j])[0]:
                expect += sum(sizes[p] for p in before[j] - before[i])
                held[i] |= before[j]
            rows_held = int(np.sum(latest[j] > disc[j]))
            expect += links[j] * (HEADER_BITS + LIST_ENTRY_BITS * rows_held)
            assert bits[j] == expect, (t, j)  # sums of integers below 2⁵³: exact in float64
        b = rng.integers(100, 400, n).astype(float)
        tab.new_step(b)
        for i in range(n):
            held[i].add((i, t + 1))
            sizes[(i, t + 1)] = b[i]


def test_q1_sends_only_the_oldest_column_and_discards_bound_the_table():
    tab = InfoTables(3, 1000)
    tab.reset(np.full(3, 100.0))
    silent = np.full(3, SILENT)
    none = np.zeros((3, 3), dtype=bool)
    for _ in range(5):  # 5 steps without links: every robot holds only its own row 0…5
        tab.exchange(silent, none, none, None)
        tab.new_step(np.full(3, 100.0))
    adj = np.zeros((3, 3), dtype=bool)
    adj[0, 1] = adj[1, 0] = True
    tab.exchange(np.full(3, 1), adj, adj, None)
    assert tab.latest[1, 0] == 0 and tab.latest[0, 1] == 0  # only column 0 (the oldest) moved
    # with all links for long enough, q = 1 completes and discards columns one after another
    full = ~np.eye(3, dtype=bool)
    for _ in range(60):
        tab.new_step(np.full(3, 100.0))
        tab.exchange(np.full(3, 1), full, full, None)
    assert tab.c.min() > 5 and tab.disc.min() > 0
    assert tab.table_size().max() < 3 * (tab.t - tab.disc.min() + 1)


def test_dense_and_pairwise_exchanges_agree():
    """The compiled dense exchange (small teams without a budget) and the pairwise one (any N, budgets, its oracle)
    give identical tables and bits, under mixed modes, all-q=∞ steps, packet loss and silent steps."""
    rng = np.random.default_rng(0)
    for run in range(8):
        n, hist = int(rng.integers(2, 8)), int(rng.integers(3, 30))
        a = InfoTables(n, hist, "oracle" if run % 4 == 3 else "paper")
        a.reset(rng.integers(100, 300, n).astype(float))
        for step in range(60):
            modes = np.full(n, QINF) if step % 3 == 0 else rng.choice(np.array([SILENT, SCHEME1, 1, 2, 4, QINF]), n)
            adj = bernoulli_links(rng, n, 0.5 if step % 7 else 0.0)
            d = apply_packet_loss(rng, adj, 0.2 if step % 2 else 0.0)
            b = copy.deepcopy(a)
            r1 = a._exchange_dense(modes, adj, d)
            r2 = b._exchange_pairs(modes, adj, d, None)
            np.testing.assert_array_equal(r1[0], r2[0])
            np.testing.assert_array_equal(r1[1], r2[1])
            for f in ("latest", "c", "disc", "known"):
                np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
            assert (a.delay_sum, a.delay_count) == (b.delay_sum, b.delay_count)
            np.testing.assert_array_equal(a.delay_histogram(), b.delay_histogram())
            a.new_step(rng.integers(100, 300, n).astype(float))
        assert a.c.min() > 0  # the tables did fill over the run


def test_bit_budget_truncates_oldest_first():
    env = parallel_env(
        n_robots=2,
        link_probability=1.0,
        estimation=False,
        modes=["silent", "scheme2_qinf"],
        bit_budget=float(HEADER_BITS + 2 * LIST_ENTRY_BITS + 2 * 176),
    )
    env.reset(seed=0)
    for _ in range(6):
        env.step({"robot_0": 0, "robot_1": 0})
    # a packet with one measurement is 40 + 64 + 72 = 176 bits: the budget fits exactly two, the oldest
    _, _, _, _, infos = env.step({"robot_0": 1, "robot_1": 1})
    assert env.tables.latest[1, 0] == 1 and env.tables.latest[0, 1] == 1
    assert infos["robot_0"]["bits_sent"] <= env.cfg["bit_budget"]


# ------------------------------------------------------------------------------------------ delays
def delay_run(n, mode, steps, seed):
    env = parallel_env(n_robots=n, estimation=False, max_cycles=steps, max_history=steps + 5, modes=[mode])
    env.reset(seed=seed)
    act = {a: 0 for a in env.possible_agents}
    while env.agents:
        env.step(act)
    return env.tables.delay_histogram()


@pytest.mark.parametrize("n", [3, 5])
def test_scheme1_delay_follows_eq_9_to_11(n):
    hist = sum(delay_run(n, "scheme1", 1500, s) for s in range(2))
    d = np.arange(len(hist))
    assert (hist * d).sum() / hist.sum() == pytest.approx(theory.scheme1_expected_delay(n, 0.5), abs=0.06)
    for t in range(3):  # P(delay = t) of eq. (10)
        pt = theory.scheme1_cdf(t, n, 0.5) - theory.scheme1_cdf(t - 1, n, 0.5)
        assert hist[t] / hist.sum() == pytest.approx(pt, abs=0.03)


def test_qinf_delays_follow_eq_15_16_and_the_exact_p_delay_1():
    hist3 = sum(delay_run(3, "scheme2_qinf", 1500, s) for s in range(2))
    d = np.arange(len(hist3))
    assert (hist3 * d).sum() / hist3.sum() == pytest.approx(theory.scheme2_qinf_n3_expected_delay(0.5), abs=0.04)
    assert hist3[0] / hist3.sum() == pytest.approx(0.25, abs=0.03)  # p^(N-1)
    assert hist3[1] / hist3.sum() == pytest.approx(theory.p_delay_eq1_exact(3, 0.5), abs=0.03)
    hist5 = delay_run(5, "scheme2_qinf", 2000, 1)
    assert hist5[1] / hist5.sum() == pytest.approx(theory.p_delay_eq1_exact(5, 0.5), abs=0.03)


def test_theory_reproduces_the_papers_scheme1_column_and_eq_18_is_exact():
    for n, row in theory.PAPER_TABLE1.items():
        assert theory.scheme1_expected_delay(n, 0.5) == pytest.approx(row[0], abs=6e-5)
    for n in (3, 4, 5):
        # both sum same-sign probability terms (Σ|terms| ≤ 1): the enumeration 2^{N(N−1)/2} products of ≤ 2^{N−1}
        # sums, the printed eq. (17)-(18) N terms of ≤ N + 5 factors; their roundings are the operation count
        pairs = n * (n - 1) // 2
        ops = 2**pairs + 2 ** (n - 1) + pairs + n * (n + 5) + 3
        assert_close_conditioned(
            theory.p_delay_eq1_as_printed(n, 0.5),
            theory.p_delay_eq1_exact(n, 0.5),
            tolerance(1.0, ops),
            err_msg=f"N={n}",
        )
    # eq. (15)-(16) for p = 1: delay 0 always; for p → 0 the delay grows
    assert theory.scheme2_qinf_n3_expected_delay(1.0) == 0.0
    assert theory.scheme2_qinf_n3_expected_delay(0.1) > theory.scheme2_qinf_n3_expected_delay(0.5)


def test_schemes_order_delay_and_bits_as_in_the_paper():
    res = {}
    for mode in ("scheme2_qinf", "scheme1", "scheme2_q1"):
        env = parallel_env(n_robots=5, estimation=False, max_cycles=400, modes=[mode])
        env.reset(seed=2)
        while env.agents:
            env.step({a: 0 for a in env.agents})
        res[mode] = env.metrics()
    assert res["scheme2_qinf"]["mean_delay"] < res["scheme1"]["mean_delay"] < res["scheme2_q1"]["mean_delay"]
    assert res["scheme2_q1"]["bits_per_link"] < res["scheme1"]["bits_per_link"] < res["scheme2_qinf"]["bits_per_link"]


# ------------------------------------------------------------------------------------------ memory, API
def test_memory_stays_bounded_when_nobody_talks():
    env = parallel_env(n_robots=3, max_history=20, max_cycles=150, modes=["silent"])
    env.reset(seed=0)
    while env.agents:
        env.step({a: 0 for a in env.agents})
        assert env.tables.table_size().max() <= 3 * 22
        assert len(env.est.packets) <= 23 and len(env.est.central) <= 23
    m = env.metrics()
    assert m["abandoned_steps"] > 0 and np.isfinite(m["rms_position"])


def test_random_modes_with_a_tiny_memory_stay_finite():
    """Columns leave memory while robots still need them: robots abandon them and carry on."""
    env = parallel_env(n_robots=4, max_history=3, max_cycles=120, link_probability=0.3)
    space = env.action_space("robot_0")
    space.seed(1)
    env.reset(seed=1)
    while env.agents:
        _, rew, _, _, infos = env.step({a: space.sample() for a in env.agents})
        assert np.isfinite(list(rew.values())).all()
        assert max(i["table_size"] for i in infos.values()) <= 4 * 5
    assert env.metrics()["abandoned_steps"] > 0 and not env.est.exact.all()


def test_baselines_run_and_use_their_mode():
    for name in ("scheme1", "scheme2_q1", "scheme2_q2", "scheme2_q4", "scheme2_q8", "scheme2_qinf", "silent", "random"):
        env = parallel_env(max_cycles=15)
        pol = make_policy("mrcomm/AsyncCL-v0", name)
        obs, _ = env.reset(seed=1)
        pol.reset(env.local_views(), 1)
        while env.agents:
            acts = pol.act(obs, env.local_views())
            if name != "random":
                assert set(acts.values()) == {env.mode_names.index(name)}
            obs, *_ = env.step(acts)
    with pytest.raises(ValueError, match="modes"):
        make_policy("mrcomm/AsyncCL-v0", "scheme1").reset(parallel_env(modes=["silent"]).local_views(), 0)


@pytest.mark.parametrize(
    "arg,bad",
    [
        ("n_robots", 1),
        ("link_probability", 1.5),
        ("link_probability", -0.1),
        ("modes", ["scheme2_q0"]),
        ("modes", ["broadcast"]),
        ("sigma_v", -0.01),
        ("sigma_theta_deg", -1.0),
        ("sigma_d", -0.5),
        ("sigma_omega_deg", -2.0),
    ],
)
def test_bad_input_names_the_argument(arg, bad):
    with pytest.raises(ValueError, match=f"'{arg}'"):
        parallel_env(**{arg: bad})


def test_observations_and_infos():
    env = parallel_env(max_cycles=30)
    obs, infos = env.reset(seed=0)
    space = env.observation_space("robot_0")
    for _ in range(30):
        obs, rew, _, _, infos = env.step({a: env.mode_names.index("scheme2_qinf") for a in env.agents})
        assert all(space.contains(o) for o in obs.values())
    assert set(infos["robot_0"]) == set(env.INFO_KEYS)
    # the default reward is minus the mean delay t − c (in tens of steps) minus λ per kbit sent per robot;
    # the infos' delay is read after the world moved on to t + 1, one step more than at the exchange
    n = env.n_agents
    kbit_per_robot = sum(i["bits_sent"] for i in infos.values()) / (1000.0 * n)
    delay = np.mean([i["delay"] for i in infos.values()]) - 1.0
    expect = -delay / 10.0 - env.cfg["lam"] * kbit_per_robot
    assert_close_conditioned(rew["robot_0"], expect, tolerance(abs(expect) + 1.0, 2 * n + 6), err_msg="reward")


def test_position_reward_is_the_causal_error_and_needs_estimation():
    env = parallel_env(max_cycles=10, reward="position", lam=0.5)
    env.reset(seed=1)
    for _ in range(10):
        _, rew, _, _, infos = env.step({a: env.mode_names.index("scheme1") for a in env.agents})
    n = env.n_agents
    err = np.mean([i["rms_position"] for i in infos.values()])
    kbit_per_robot = sum(i["bits_sent"] for i in infos.values()) / (1000.0 * n)
    expect = -err - 0.5 * kbit_per_robot
    # the same N errors and bits summed in another order (same-sign terms, cond 1)
    assert_close_conditioned(rew["robot_0"], expect, tolerance(abs(expect), 2 * n + 6), err_msg="reward")
    with pytest.raises(ValueError, match="'reward'"):
        parallel_env(reward="position", estimation=False)


def test_observation_is_agent_relative():
    # robot i's block k describes robot (i + k + 1) mod N: linked flags match the links of the coming exchange
    env = parallel_env(n_robots=4, max_cycles=5)
    obs, _ = env.reset(seed=3)
    for i in range(4):
        blocks = obs[f"robot_{i}"][: 3 * 3].reshape(3, 3)
        others = [(i + k) % 4 for k in (1, 2, 3)]
        np.testing.assert_array_equal(blocks[:, 0], env.adj[i, others].astype(np.float32))
        behind = env.tables.t - env.tables.latest[i, others]
        np.testing.assert_allclose(blocks[:, 1], behind / (behind + 10.0), rtol=1e-6)


@pytest.mark.parametrize(
    "kwargs",
    [
        {},  # the default: five robots estimating
        {"n_robots": 2, "max_history": 3},  # one other robot; columns leave memory
        {"n_robots": 9, "link_model": "disk", "comm_radius": 3.0, "packet_loss": 0.3},  # sparse, lossy
        {"n_robots": 12, "estimation": False},  # the delay-only bookkeeping: no trace, no errors
    ],
)
def test_compiled_observation_and_errors_are_the_numpy_codes_bit_for_bit(kwargs):
    """The same state observed, and its errors measured, by the env (compiled) and by their numpy oracles: byte for
    byte, every step."""
    env = parallel_env(max_cycles=40, **kwargs)
    env.reset(seed=6)
    rng = np.random.default_rng(8)
    steps = 0
    while env.agents:
        env.step({a: int(rng.integers(env.action_space(a).n)) for a in env.agents})
        want, got = [reference_observation(env)], [env._observe()]
        if env.cfg["estimation"]:
            pos, ori, mean_pos, mean_ori = reference_errors(env)
            kept = (env._sum_pos, env._sum_ori, env._n_err)
            env._errors()  # measured again on the state the step left (the world has moved on to the next step)
            want += [pos, ori, kept[0] + mean_pos, kept[1] + mean_ori, kept[2] + 1, mean_pos]
            got += [env._err_pos, env._err_ori, env._sum_pos, env._sum_ori, env._n_err, env._mean_pos]
            env._sum_pos, env._sum_ori, env._n_err = kept
            # the own-pose traces in float64, before the observation's log scale
            want.append(own_pose_traces(env))
            got.append(env_numba.own_pose_traces(env.est.P))
        for expected, value in zip(want, got, strict=True):
            assert np.asarray(expected).dtype == np.asarray(value).dtype
            assert np.asarray(expected).tobytes() == np.asarray(value).tobytes()
        steps += 1
    assert steps > 10
