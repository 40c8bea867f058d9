"""RendezvousMapping-v0 (paper 004): the information filter against filterpy, and fusion without double counting
(the channel filter, packet logs and their bound)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import InformationFilter
from helpers.rendezvous import make_packet, random_spd
from hypothesis import given, settings
from hypothesis import strategies as st

from mrcomm_env.rendezvous import filters, world
from mrcomm_env.rendezvous.env import RendezvousMappingEnv

EPS = np.finfo(float).eps


# ------------------------------------------------------------------------------------------------ filter
def test_vectorised_information_filter_matches_filterpy_on_the_same_observations():
    rng = np.random.default_rng(4)
    L, m = 6, 80
    Y0 = np.stack([random_spd(rng, 0.05) for _ in range(L)])
    mu0 = rng.uniform(0, 100, size=(L, 2))
    y0 = np.einsum("lij,lj->li", Y0, mu0)
    landmarks = rng.integers(0, L, size=m)
    R_inv = np.stack([np.linalg.inv(random_spd(rng, 4.0)) for _ in range(m)])
    z = mu0[landmarks] + rng.normal(0, 2.0, size=(m, 2))
    Y, y = Y0.copy(), y0.copy()
    filters.observe(Y, y, landmarks, z, R_inv)
    for lm in range(L):
        f = InformationFilter(dim_x=2, dim_z=2)
        f.x = mu0[lm].copy()
        f.P_inv = Y0[lm].copy()
        f.H = np.eye(2)
        for k in np.flatnonzero(landmarks == lm):
            f.update(z[k], R_inv=R_inv[k])
        # the two differ only by round-off: a sum of k terms (relative k·ε) and one 2×2 solve (cond·ε) on
        # values of size |μ|
        n_obs = max(int((landmarks == lm).sum()), 1)
        cond = np.linalg.cond(Y[lm])
        np.testing.assert_allclose(Y[lm], f.P_inv, rtol=0, atol=8 * n_obs * EPS * np.abs(f.P_inv).max())
        mean = filters.mean_of(Y[lm], y[lm])
        np.testing.assert_allclose(mean, f.x.ravel(), rtol=0, atol=16 * n_obs * cond * EPS * np.abs(mu0).max())


def test_logdet_and_mean_of_match_numpy():
    rng = np.random.default_rng(0)
    Y = np.stack([random_spd(rng) for _ in range(20)])
    y = rng.normal(size=(20, 2))
    np.testing.assert_allclose(filters.logdet2(Y), np.linalg.slogdet(Y)[1], rtol=1e-12)
    np.testing.assert_allclose(filters.mean_of(Y, y), np.linalg.solve(Y, y[..., None])[..., 0], rtol=1e-10)


# ------------------------------------------------------------------------------------------------ fusion
class Gathered:
    """The test's own record of every packet each vehicle made, apart from ``TeamMaps`` (which lets packets go)."""

    def __init__(self, maps: filters.TeamMaps):
        self.maps = maps
        self.packets: list[list[filters.Packet]] = [[] for _ in range(maps.n)]

    def add_own(self, v, packet):
        self.maps.add_own(v, packet)
        if len(packet.landmarks):
            self.packets[v].append(packet)

    def summed(self, version) -> tuple[np.ndarray, np.ndarray]:
        """Prior plus the packets a version vector names, summed afresh."""
        Y, y = self.maps.Y0.copy(), self.maps.y0.copy()
        for u, packets in enumerate(self.packets):
            for p in packets[: version[u]]:
                np.add.at(Y, p.landmarks, p.count[:, None, None] * self.maps.R_inv)
                np.add.at(y, p.landmarks, p.dy)
        return Y, y


def check_no_double_counting(record: Gathered):
    """Every map equals prior + each packet it holds, summed once afresh."""
    maps = record.maps
    for w in range(maps.n):
        Y, y = record.summed(maps.known[w])
        tol = 64 * EPS * max(1.0, np.abs(Y).max())
        np.testing.assert_allclose(maps.Y[w], Y, rtol=0, atol=tol)
        np.testing.assert_allclose(maps.y[w], y, rtol=0, atol=tol * 10)
        # what the maps sum afresh (from the common map on) is that too
        Yw, yw = maps.information_of(maps.known[w])
        np.testing.assert_allclose(Yw, Y, rtol=0, atol=tol)
        np.testing.assert_allclose(yw, y, rtol=0, atol=tol * 10)
    Yc, _ = record.summed(maps.known.min(0))
    np.testing.assert_allclose(maps.common_Y, Yc, rtol=0, atol=64 * EPS * max(1.0, np.abs(Yc).max()))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), n=st.integers(2, 6), events=st.integers(1, 25))
def test_fused_map_over_any_meeting_sequence_equals_the_centralized_sum(seed, n, events):
    rng = np.random.default_rng(seed)
    L = 7
    Y0 = np.broadcast_to(np.eye(2) * 0.04, (L, 2, 2)).copy()
    maps = filters.TeamMaps(n, Y0, rng.normal(size=(L, 2)), random_spd(rng))
    record = Gathered(maps)
    for _ in range(events):
        for v in range(n):  # some vehicles gather something in this window
            if rng.random() < 0.6:
                record.add_own(v, make_packet(rng, L))
        # a random set of meetings: random groups, each fused over a random tree
        pos = rng.uniform(0, 30, size=(n, 2))
        links = world.vehicle_links(pos, float(rng.uniform(0, 30)))
        labels, parent = world.spanning_forest(pos, links)
        for g in range(labels.max() + 1):
            members = np.flatnonzero(labels == g)
            maps.fuse_group(members, parent)
            assert (maps.known[members] == maps.known[members].max(0)).all()
        maps.update_common()
        check_no_double_counting(record)
    # everyone meets at last: every map and the fused global map are the centralised sum
    star = np.r_[-1, np.zeros(n - 1, dtype=np.int64)]
    maps.fuse_group(np.arange(n), star)
    maps.update_common()
    Yc, yc = record.summed([len(p) for p in record.packets])
    assert all(log.kept == 0 for log in maps.logs)  # everyone holds everything: every packet was let go
    if maps.common_known.any():  # a version below the common map's names packets that are gone
        with pytest.raises(ValueError, match="'version'"):
            maps.information_of(np.zeros(n, dtype=np.int64))
    for w in range(n):
        np.testing.assert_allclose(maps.Y[w], Yc, rtol=0, atol=64 * EPS * np.abs(Yc).max())
        np.testing.assert_allclose(maps.y[w], yc, rtol=0, atol=640 * EPS * max(1.0, np.abs(yc).max()))
    np.testing.assert_allclose(maps.common_Y, Yc, rtol=0, atol=64 * EPS * np.abs(Yc).max())


def test_channel_filter_is_the_common_information_and_fusion_adds_only_the_difference():
    rng = np.random.default_rng(7)
    L = 5
    maps = filters.TeamMaps(3, np.broadcast_to(np.eye(2), (L, 2, 2)).copy(), np.zeros((L, 2)), random_spd(rng))
    for v in range(3):
        maps.add_own(v, make_packet(rng, L))
    maps.fuse_group(np.array([0, 1]), np.array([-1, 0, -1]))
    maps.add_own(0, make_packet(rng, L))
    maps.add_own(2, make_packet(rng, L))
    common_Y, _ = maps.channel_information(0, 2)
    union_Y, _ = maps.information_of(np.maximum(maps.known[0], maps.known[2]))
    # Y_a + Y_b − common = union: the channel filter removes exactly what would be counted twice
    np.testing.assert_allclose(maps.Y[0] + maps.Y[2] - common_Y, union_Y, rtol=1e-12)


def test_a_reconnecting_vehicle_sends_only_what_the_others_lack():
    rng = np.random.default_rng(3)
    L = 6
    maps = filters.TeamMaps(3, np.broadcast_to(np.eye(2), (L, 2, 2)).copy(), np.zeros((L, 2)), random_spd(rng))
    chain = np.array([-1, 0, 1])  # 0 — 1 — 2
    for v in range(3):
        maps.add_own(v, make_packet(rng, L))
    maps.fuse_group(np.arange(3), chain)
    # vehicle 2 is cut off and gathers two packets; 0 and 1 gather one each and fuse without it
    p2 = [make_packet(rng, L), make_packet(rng, L)]
    for p in p2:
        maps.add_own(2, p)
    maps.add_own(0, make_packet(rng, L))
    maps.add_own(1, make_packet(rng, L))
    maps.fuse_group(np.array([0, 1]), np.array([-1, 0, -1]))
    sent = maps.fuse_group(np.arange(3), chain)
    assert sent[(2, 1)] == sum(p.bits(L) for p in p2)  # only its own two new packets
    lacking = maps.packets(0)[-1].bits(L) + maps.packets(1)[-1].bits(L)
    assert sent[(1, 2)] == lacking
    assert sent[(1, 0)] == sum(p.bits(L) for p in p2) and sent[(0, 1)] == 0
    again = maps.fuse_group(np.arange(3), chain)  # nothing new: nothing sent
    assert all(bits == 0 for bits in again.values())


def test_a_packet_log_lets_go_only_of_packets_everyone_holds_and_keeps_their_bits():
    rng = np.random.default_rng(5)
    log = filters.PacketLog()
    made = [make_packet(rng, 50) for _ in range(40)]
    for p in made:
        log.append(p, p.bits(50))
    bits = np.cumsum([0] + [p.bits(50) for p in made])
    log.drop_before(10)  # fewer to let go than to keep: nothing moves yet
    assert (log.first, log.kept, log.made) == (0, 40, 40)
    log.drop_before(25)  # now as many to go as to stay
    assert (log.first, log.kept, log.made) == (25, 15, 40)
    for k in range(25, 41):
        assert log.bits_before(k) == bits[k]
    for kept, p in zip(log.packets(), made[25:], strict=True):
        assert np.array_equal(kept.landmarks, p.landmarks) and np.array_equal(kept.count, p.count)
        assert kept.dy.tobytes() == p.dy.tobytes()
    with pytest.raises(ValueError, match="not all kept"):
        log.span(24, 30)
    more = make_packet(rng, 50)
    log.append(more, more.bits(50))
    assert log.made == 41 and log.bits_before(41) == bits[40] + more.bits(50)
    assert np.array_equal(log.packets()[-1].landmarks, more.landmarks)


def test_a_connected_team_holds_no_packet_everyone_has_however_long_the_episode():
    """Packets every vehicle holds are in the fused map and never sent again: a team that stays connected keeps
    none of them, over a horizon in which it makes thousands (they were all kept for the whole episode once)."""
    env = RendezvousMappingEnv(
        n_vehicles=4, n_landmarks=30, area=900.0, d_comms=math.inf, obs_per_landmark=10_000, max_cycles=1500
    )
    env.reset(seed=2)
    most = 0
    while env.agents:
        env.step({a: 0 for a in env.agents})
        most = max(most, sum(log.kept for log in env.maps.logs))
    assert sum(log.made for log in env.maps.logs) > 1000
    assert most == 0


def test_packet_logs_of_a_split_team_stay_within_the_bound_the_memory_estimate_counts():
    """With d_comms = 0 vehicles fuse only when they meet at one point, and the logs grow: their arrays stay within
    ``STORED_ENTRY_BYTES`` per entry made, apart from their first few rows (the estimate's term: an entry holds one
    observation or more, and the sensor floor bounds the observations)."""
    env = RendezvousMappingEnv(
        n_vehicles=6, n_landmarks=40, area=1600.0, d_comms=0.0, obs_per_landmark=10_000, max_cycles=400
    )
    env.reset(seed=4)
    made = [0]
    add_own = env.maps.add_own

    def counted(v, packet):
        made[0] += len(packet.landmarks)
        add_own(v, packet)

    env.maps.add_own = counted
    rng = np.random.default_rng(4)
    most = 0
    while env.agents:
        env.step({a: int(rng.integers(env.action_space(a).n)) for a in env.agents})
        logs = env.maps.logs
        most = max(most, sum(log.entries for log in logs))
        held = sum(a.nbytes for log in logs for a in (log.landmarks, log.dy, log.count, log.bounds, log.cum_bits))
        assert made[0] <= env.world_count.sum()
        assert held <= filters.STORED_ENTRY_BYTES * made[0] + len(logs) * 8 * 40
    assert most > 200  # the logs did grow
