"""AsyncCL-v0 on UTIAS MRCLAM Dataset 6: the loader, the measured noise, and the env replaying real robots.

Tests that read the recording skip only when it is absent (CI has it); the others run everywhere."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from mrcomm_env.asynccl import mrclam
from mrcomm_env.asynccl.mrclam import MrclamNotFoundError, estimate_noise, inliers, load_mrclam, measured_noise
from mrcomm_env.asynccl_v0 import parallel_env

needs_data = pytest.mark.skipif(mrclam.default_path() is None, reason="MRCLAM Dataset 6 absent (CI has it)")


# ------------------------------------------------------------------------------------------ arguments, no data needed
@pytest.mark.parametrize("n", [2, 4, 6])
def test_other_team_sizes_are_rejected_naming_n_robots(n):
    with pytest.raises(ValueError, match="'n_robots' must be 5"):
        parallel_env(trajectory="mrclam", n_robots=n)


def test_a_missing_data_set_says_where_it_looked_and_how_to_get_it(tmp_path, monkeypatch):
    with pytest.raises(MrclamNotFoundError) as err:
        parallel_env(trajectory="mrclam", data_dir=tmp_path)
    message = str(err.value)
    assert isinstance(err.value, FileNotFoundError) and isinstance(err.value, ValueError)
    assert "\n" not in message and "'data_dir'" in message and str(tmp_path) in message
    assert mrclam.DOWNLOAD in message and "MRCLAM_DIR" in message
    monkeypatch.setenv("MRCLAM_DIR", str(tmp_path / "nowhere"))
    with pytest.raises(MrclamNotFoundError, match="nowhere"):
        parallel_env(trajectory="mrclam")
    for bad in ("", 3, ["a"]):
        with pytest.raises(ValueError, match="'data_dir'"):
            parallel_env(data_dir=bad)
    parallel_env(data_dir=tmp_path)  # ignored by the synthetic trajectories


def test_the_shared_copy_is_found_from_any_checkout_depth(tmp_path, monkeypatch):
    """A git worktree (``wt/<name>``) sits one level deeper than the main checkout; both find ``../shared``."""
    folder = tmp_path / "shared" / "data" / mrclam.FOLDER
    folder.mkdir(parents=True)
    (folder / "Barcodes.dat").write_text("# header\n1 5\n")
    deep = tmp_path / "wt" / "branch" / "src"
    deep.mkdir(parents=True)
    monkeypatch.delenv("MRCLAM_DIR", raising=False)
    monkeypatch.chdir(deep)
    monkeypatch.setattr(mrclam, "__file__", str(deep / "mrclam.py"))
    assert mrclam.resolve_data_dir() == folder.resolve()


@needs_data
def test_robot_to_robot_measurements_agree_with_motion_capture():
    d = load_mrclam(duration=300.0)
    truth, s, a, b, z = d["truth"], d["meas_step"], d["meas_a"], d["meas_b"], d["meas_z"]
    assert truth.shape[1:] == (5, 3) and len(s) > 100
    assert np.all(a != b) and np.all(np.diff(s) >= 0)
    diff = truth[s, b, :2] - truth[s, a, :2]
    rng = np.hypot(diff[:, 0], diff[:, 1])
    bearing = np.arctan2(diff[:, 1], diff[:, 0]) - truth[s, a, 2]
    err = (z[:, 1] - bearing + np.pi) % (2 * np.pi) - np.pi
    assert np.median(np.abs(z[:, 0] - rng)) < 0.2  # the paper's sensor model: a few percent of d
    assert np.median(np.abs(err)) < 0.05


@needs_data
def test_odometry_dead_reckoning_follows_ground_truth_over_a_few_seconds():
    d = load_mrclam(duration=120.0)
    truth, odo, dt = d["truth"], d["odometry"], d["dt"]
    x = truth[0].copy()
    for k in range(40):  # 2 s of unicycle integration, eq. (1)
        v, w = odo[k, :, 0], odo[k, :, 1]
        x = np.column_stack([x[:, 0] + v * np.cos(x[:, 2]) * dt, x[:, 1] + v * np.sin(x[:, 2]) * dt, x[:, 2] + w * dt])
    assert np.max(np.hypot(*(x[:, :2] - truth[40, :, :2]).T)) < 0.3


# ------------------------------------------------------------------------------------------ the noise estimator
def _synthetic_recording(rng, sv, sw, sd, sth, steps=20_000, dt=0.05, misreadings=7):
    """A recording made by the model the estimator assumes (eq. (1)–(2)), with known noise and a few gross errors."""
    v = 0.05 + 0.2 * rng.random((steps, 5))
    w = 0.5 * np.sin(np.arange(steps)[:, None] * 0.01 + np.arange(5))
    truth = np.zeros((steps + 1, 5, 3))
    truth[0, :, :2] = rng.uniform(-3, 3, (5, 2))
    for k in range(steps):
        phi = truth[k, :, 2]
        truth[k + 1] = np.column_stack(
            [truth[k, :, 0] + v[k] * np.cos(phi) * dt, truth[k, :, 1] + v[k] * np.sin(phi) * dt, phi + w[k] * dt]
        )
    truth[:, :, 2] = (truth[:, :, 2] + np.pi) % (2 * np.pi) - np.pi
    # odometry: the true controls plus the model's noise, v_m = v (1 + σ_v n) (so σ_v·v_m ≈ σ_v·v), ω_m = ω + σ_ω n
    odo = np.stack([v * (1 + sv * rng.standard_normal(v.shape)), w + sw * rng.standard_normal(w.shape)], axis=2)
    odo = np.concatenate([odo, odo[-1:]])
    s = rng.integers(0, steps, 4000)
    a = rng.integers(0, 5, 4000)
    b = (a + rng.integers(1, 5, 4000)) % 5
    diff = truth[s, b, :2] - truth[s, a, :2]
    d = np.hypot(diff[:, 0], diff[:, 1])
    brg = np.arctan2(diff[:, 1], diff[:, 0]) - truth[s, a, 2]
    z = np.column_stack([d / (1 - sd * rng.standard_normal(len(s))), brg + sth * rng.standard_normal(len(s))])
    z[:misreadings, 1] += 2.0  # a wrong barcode: the bearing of someone else
    order = np.lexsort((b, a, s))
    return {
        "truth": truth,
        "odometry": odo,
        "meas_step": s[order],
        "meas_a": a[order],
        "meas_b": b[order],
        "meas_z": z[order],
        "dt": dt,
    }


def test_noise_estimator_recovers_known_noise_and_counts_misreadings():
    rng = np.random.default_rng(3)
    sv, sw, sd, sth = 0.05, np.radians(3.0), 0.03, np.radians(0.5)
    noise = estimate_noise(_synthetic_recording(rng, sv, sw, sd, sth))
    # a σ estimated from M independent squares has relative standard error 1/√(2M); allow 5 of them
    rel = 5 / np.sqrt(2 * noise.odometry_windows)
    assert abs(noise.sigma_v / sv - 1) < rel + sv**2  # + the O(σ_v²) of normalising by v_m instead of v
    assert abs(noise.sigma_omega / sw - 1) < rel
    rel_m = 5 / np.sqrt(2 * (noise.measurements - noise.misreadings))
    assert abs(noise.sigma_d / sd - 1) < rel_m + sd**2
    # the gate at 5 robust σ removes the 7 wrong barcodes and, of a normal sample, only the 6·10⁻⁷ tail
    assert noise.misreadings == 7
    assert abs(noise.sigma_theta / sth - 1) < rel_m


@needs_data
def test_measured_noise_of_dataset_6_is_cached_and_in_the_env():
    noise = measured_noise()
    assert measured_noise() is noise  # estimated once per folder and dt
    # real robots: odometry far noisier than §IV's simulation, range/bearing of the order of it
    assert 0.1 < noise.sigma_v < 1.0 and np.radians(2) < noise.sigma_omega < np.radians(30)
    assert 0.01 < noise.sigma_d < 0.1 and np.radians(0.1) < noise.sigma_theta < np.radians(2)
    assert 0 < noise.misreadings < 0.05 * noise.measurements
    env = parallel_env(trajectory="mrclam", max_cycles=50)
    assert env.noise == (noise.sigma_v, noise.sigma_omega, noise.sigma_d, noise.sigma_theta)
    chosen = parallel_env(trajectory="mrclam", max_cycles=50, sigma_v=0.3, sigma_theta_deg=2.0)
    assert chosen.noise == (0.3, noise.sigma_omega, noise.sigma_d, np.radians(2.0))  # what the filters assume
    assert parallel_env().noise == (0.02, np.radians(1.0), 0.02, np.radians(1.0))  # §IV on the synthetic paths


# ------------------------------------------------------------------------------------------ the env on the data
@needs_data
def test_episode_replays_a_seeded_window_of_the_recording():
    steps = 200
    data = load_mrclam()
    keep = inliers(data)
    env = parallel_env(trajectory="mrclam", max_cycles=steps)
    starts = set()
    for seed in range(6):
        env.reset(seed=seed)
        k0 = env.world.source.k0
        starts.add(k0)
        assert 0 <= k0 and k0 + steps < len(data["truth"])  # inside Robot1's ground truth, the shortest
        for k in range(steps + 1):
            np.testing.assert_array_equal(env.world.x, data["truth"][k0 + k])
            pk = env.est.packets[k]
            np.testing.assert_array_equal(pk.u, data["odometry"][k0 + k])
            sel = keep & (data["meas_step"] == k0 + k)
            np.testing.assert_array_equal(pk.a, data["meas_a"][sel])
            np.testing.assert_array_equal(pk.b, data["meas_b"][sel])
            np.testing.assert_array_equal(pk.z, data["meas_z"][sel])
            np.testing.assert_array_equal(pk.n_meas, np.bincount(pk.a, minlength=5))
            if env.agents:
                env.step({a: 6 for a in env.agents})
    assert len(starts) == 6  # the seed draws the window


def _rollout(env, seed, steps=60):
    obs, infos = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    out = [(obs, infos)]
    for _ in range(steps):
        out.append(env.step({a: int(rng.integers(env.action_space(a).n)) for a in env.agents}))
    return out, env.metrics()


@needs_data
def test_the_seed_determines_the_episode_and_pickling_keeps_it():
    a, ma = _rollout(parallel_env(trajectory="mrclam", max_cycles=60), 11)
    b, mb = _rollout(parallel_env(trajectory="mrclam", max_cycles=60), 11)
    c, mc = _rollout(parallel_env(trajectory="mrclam", max_cycles=60), 12)
    assert ma == mb and ma != mc
    for (obs_a, *rest_a), (obs_b, *rest_b) in zip(a, b, strict=True):
        assert all(np.array_equal(obs_a[k], obs_b[k]) for k in obs_a)
        assert rest_a == rest_b  # rewards, terminations, truncations, infos
    env = parallel_env(trajectory="mrclam", max_cycles=60)
    env.reset(seed=5)
    env.step({a: 1 for a in env.agents})
    twin = pickle.loads(pickle.dumps(env))
    assert len(pickle.dumps(env)) < 2_000_000  # the recording is not pickled, only where the window starts
    for _ in range(20):
        acts = {a: 6 for a in env.agents}
        o1, r1, *_ = env.step(acts)
        o2, r2, *_ = twin.step(acts)
        assert r1 == r2 and all(np.array_equal(o1[k], o2[k]) for k in o1)


@needs_data
def test_cooperation_beats_dead_reckoning_on_real_robots():
    """Scheme 2 (q = ∞) fuses the real relative measurements; silent robots only dead-reckon (and guess the team)."""
    err = {}
    for mode in ("silent", "scheme2_qinf"):
        env = parallel_env(trajectory="mrclam", modes=[mode], max_cycles=300)
        runs = []
        for seed in range(3):
            env.reset(seed=seed)
            while env.agents:
                env.step({a: 0 for a in env.agents})
            runs.append(env.metrics()["rms_position"])
        err[mode] = np.mean(runs)
    assert err["scheme2_qinf"] < 0.5 * err["silent"]


@needs_data
def test_links_and_sensing_radius_apply_to_the_replay():
    env = parallel_env(trajectory="mrclam", max_cycles=100, link_model="disk", comm_radius=2.0, sensing_radius=2.5)
    env.reset(seed=2)
    for _ in range(100):
        x = env.world.x[:, :2]
        dist = np.hypot(*(x[:, None] - x[None]).transpose(2, 0, 1))
        np.testing.assert_array_equal(env.adj, (dist <= 2.0) & ~np.eye(5, dtype=bool))
        assert np.all(env.est.packets[env.tables.t].z[:, 0] <= 2.5)
        env.step({a: 6 for a in env.agents})
