"""The batched trainer (``mrcomm train --algo ippo|mappo``, ``agents/batched_ppo.py``): its advantages, inputs and
masks against their definitions, that it learns, and that its runs keep every guarantee of ``mrcomm train``."""

from __future__ import annotations

import csv
import json
import zipfile

import numpy as np
import pytest
import torch
from sb3_contrib import MaskablePPO
from stable_baselines3 import PPO
from stable_baselines3.common.logger import Logger

from mrcomm_agents import batched_ppo, training
from mrcomm_agents.artifacts import STATISTICS_FILE, load_statistics
from mrcomm_agents.batched_ppo import BatchedPPO, build_model, check_env, detached_normalizer, make_critic
from mrcomm_agents.learned import LearnedPolicy
from mrcomm_agents.training import CRITIC_FILE, TrainConfig, train
from mrcomm_env.core.batched import BatchedEnv
from mrcomm_env.experiments import runs
from mrcomm_env.experiments.cli import main
from mrcomm_env.registry import make

torch.set_num_threads(1)

ENV = "ChannelAssociation-v0"
ENV_KWARGS = {"n_robots": 3, "max_cycles": 10}
N_AGENTS = 3
COPIES = 4
HYPER = {"n_steps": 8, "batch_size": 32, "n_epochs": 2}
#: agent-steps of one rollout: T steps of every agent of every copy
ROLLOUT = HYPER["n_steps"] * COPIES * N_AGENTS


def config(timesteps: int, algo: str = "ippo", **kw) -> TrainConfig:
    settings = dict(
        env_id=ENV,
        algo=algo,
        timesteps=timesteps,
        seed=3,
        env_kwargs=dict(ENV_KWARGS),
        hyperparams=dict(HYPER),
        n_envs=COPIES,
        net_arch=[16],
        checkpoint_every=ROLLOUT,
        eval_episodes=1,
    )
    settings.update(kw)
    return TrainConfig(**settings)


def trainer(env_id: str, env_kwargs: dict, copies: int, steps: int, normalize: bool = True, algo: str = "ippo"):
    probe = make(env_id, **env_kwargs)
    agent = probe.possible_agents[0]
    obs_space, act_space = probe.observation_space(agent), probe.action_space(agent)
    model = build_model(
        training.algorithm_class(algo, probe), "MlpPolicy", {"net_arch": [16]}, obs_space, act_space,
        {"n_steps": steps, "batch_size": 16, "n_epochs": 1}, 0,
    )  # fmt: skip
    model.set_logger(Logger(folder=None, output_formats=[]))
    critic = optimizer = None
    if algo == "mappo":
        critic, optimizer = make_critic(probe.n_agents, obs_space.shape[0], [16], 1e-3)
    batch = BatchedEnv(lambda: make(env_id, **env_kwargs), copies, copy=False)
    normalizer = detached_normalizer(obs_space.shape, model.gamma) if normalize else None
    return BatchedPPO(model, batch, normalizer, 0, critic, optimizer)


# ------------------------------------------------------------------------------------------------ the algorithm
def test_advantages_are_the_discounted_sums_of_td_residuals_within_each_episode():
    """GAE's definition (Schulman et al. 2016, eq. 16): A_t = Σ_l (γλ)^l δ_{t+l}, the sum stopping where the episode
    ends; δ_t = r_t + γ V(s_{t+1}) − V(s_t), with V(s_{t+1}) = 0 after a step that ended an episode. The trainer
    computes it by the backward recursion; here it is the explicit sum, row by row."""
    run = trainer(ENV, ENV_KWARGS, 2, 7, normalize=False)
    rng = np.random.default_rng(5)
    t, rows = run.buf_rewards.shape
    run.buf_rewards[:] = rng.normal(size=(t, rows))
    run.buf_values[:] = rng.normal(size=(t, rows))
    run.buf_starts[:] = rng.random((t, rows)) < 0.25
    run.next_starts = (rng.random(rows) < 0.25).astype(np.float32)
    last_values = rng.normal(size=rows).astype(np.float32)
    gamma, lam = 0.9, 0.8
    run._advantages(last_values, gamma, lam)
    starts = np.vstack([run.buf_starts, run.next_starts[None]])  # starts[k]: step k begins an episode
    values = np.vstack([run.buf_values, last_values[None]]).astype(np.float64)
    expected = np.zeros((t, rows))
    for r in range(rows):
        for s in range(t):
            total, weight = 0.0, 1.0
            for k in range(s, t):
                continues = 0.0 if starts[k + 1, r] else 1.0
                delta = run.buf_rewards[k, r] + gamma * values[k + 1, r] * continues - values[k, r]
                total += weight * delta
                if not continues:
                    break
                weight *= gamma * lam
            expected[s, r] = total
    # float32 arithmetic over at most 7 terms of size O(1): a relative error of a few float32 ulps
    np.testing.assert_allclose(run.advantages, expected, rtol=1e-5, atol=1e-5)


def test_observations_are_normalised_as_vecnormalize_does_up_to_float32_rounding():
    run = trainer(ENV, ENV_KWARGS, 2, 4)
    rng = np.random.default_rng(1)
    d = run.obs_dim
    run.normalizer.obs_rms.mean = rng.normal(size=d)
    run.normalizer.obs_rms.var = rng.uniform(0.001, 4.0, size=d)
    raw = rng.normal(scale=3.0, size=(50, d)).astype(np.float32)
    ours = run._normalized(raw)
    reference = run.normalizer.normalize_obs(raw).astype(np.float32)
    assert ours.dtype == np.float32
    assert np.abs(reference).max() == pytest.approx(10.0)  # some entries are clipped, at ±clip_obs
    # |x| ≤ 10 after three float32 operations: at most about 3 · 10 · 2⁻²⁴ ≈ 2e-6 apart
    np.testing.assert_allclose(ours, reference, rtol=0, atol=4e-6)


def test_a_copy_cut_off_by_max_cycles_bootstraps_from_its_final_observation():
    """SB3's rule for a time limit: the last reward of a truncated episode gets γ·V(final observation)."""
    run = trainer("MapSync-v0", {"max_cycles": 2}, 3, 3, normalize=False)
    seen = []
    step = run.batch.step

    def recording(actions):
        result = step(actions)
        seen.append((result.rewards.copy(), dict(result.final_observations), result.truncated.copy()))
        return result

    run.batch.step = recording
    run.collect()
    rewards, finals, truncated = seen[1]  # the second step ends every copy by the time limit
    assert truncated.all() and sorted(finals) == [0, 1, 2]
    final = np.concatenate([finals[i] for i in range(3)]).astype(np.float32)
    with torch.no_grad():
        values = run.policy.predict_values(torch.from_numpy(final)).flatten().numpy()
    expected = rewards.reshape(-1) + run.model.gamma * values
    np.testing.assert_allclose(run.buf_rewards[1], expected, rtol=1e-6, atol=1e-6)
    assert (run.buf_starts[2] == 1).all()  # the step after it begins new episodes
    np.testing.assert_allclose(run.buf_rewards[0], seen[0][0].reshape(-1), rtol=1e-6)  # no bootstrap elsewhere


def test_masked_actions_come_from_the_feasible_ones_and_the_masks_are_the_envs():
    run = trainer("RendezvousMapping-v0", {"max_cycles": 6, "n_vehicles": 2, "n_landmarks": 3, "k_candidates": 5}, 3, 5)
    assert isinstance(run.model, MaskablePPO)
    expected = np.concatenate([env.action_masks() for env in run.batch.envs])
    np.testing.assert_array_equal(run.next_masks, expected)  # the info columns are env.action_masks()
    run.collect()
    assert run.buf_masks is not None and not run.buf_masks.all()  # some actions were infeasible
    taken = run.buf_actions.astype(np.int64)
    feasible = np.take_along_axis(run.buf_masks, taken[..., None], axis=2)
    assert feasible.all()


def test_mappo_critic_reads_each_copys_state_beside_the_agents_own_observation():
    """The critic's state of each copy is that copy's ``env.state()``, and its value is the MLP of the concatenation
    (state, own observation): its split first layer is that layer's linear map, computed without the concatenation."""
    run = trainer("MapSync-v0", {}, 3, 2, normalize=False, algo="mappo")
    critic = run.critic
    obs = torch.from_numpy(run.next_obs)
    states = critic.state_of(obs).numpy()
    for copy, env in enumerate(run.batch.envs):
        np.testing.assert_array_equal(states[copy], env.state())
    n, d = run.n, run.obs_dim
    concatenated = np.concatenate([np.repeat(states, n, axis=0), run.next_obs], axis=1)
    weight = torch.cat([critic.state_layer.weight, critic.own_layer.weight], dim=1)
    with torch.no_grad():
        hidden = torch.from_numpy(concatenated) @ weight.T + critic.state_layer.bias
        expected = critic.head(hidden).squeeze(-1).numpy()
        values = critic(obs).numpy()
    assert concatenated.shape[1] == n * d + d
    # the same sums in another order: float32 rounding over N·D + D = 15 terms of size O(1)
    np.testing.assert_allclose(values, expected, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize(
    "env_id, env_kwargs",
    [
        ("MapSync-v0", {}),
        ("RendezvousMapping-v0", {"max_cycles": 6, "n_vehicles": 2, "n_landmarks": 3, "k_candidates": 5}),  # masked
    ],
)
def test_mappo_acts_with_the_actions_and_log_probabilities_of_sb3s_own_forward(env_id, env_kwargs):
    """MAPPO computes the actor alone (its values come from its own critic): from the same random state it draws the
    actions SB3's ``forward`` draws, with the same log-probabilities, masked where the env masks."""
    run = trainer(env_id, env_kwargs, 3, 2, algo="mappo")
    obs = torch.from_numpy(run.next_obs)
    masks = run.next_masks
    torch.manual_seed(11)
    with torch.no_grad():
        distribution = run.actor_distribution(obs, masks)
        actions = distribution.get_actions(deterministic=False)
        log_probs = distribution.log_prob(actions)
    torch.manual_seed(11)
    with torch.no_grad():
        if masks is None:
            expected_actions, _, expected_log_probs = run.policy(obs)
        else:
            expected_actions, _, expected_log_probs = run.policy(obs, action_masks=masks)
    assert (masks is None) == (env_id == "MapSync-v0")
    torch.testing.assert_close(actions.reshape(expected_actions.shape), expected_actions, rtol=0, atol=0)
    torch.testing.assert_close(log_probs, expected_log_probs, rtol=0, atol=0)


def test_mappo_critic_takes_its_own_layers_and_keeps_them_on_resume(tmp_path):
    # the actor stays [16] (config's net_arch) while the critic is [24, 8]; a resumed run must rebuild the critic
    # with the widths its checkpoint holds, or loading its weights fails
    train(config(ROLLOUT, "mappo", critic_arch=[24, 8]), tmp_path / "run", progress=False)
    critic = torch.load(tmp_path / "run" / CRITIC_FILE, weights_only=True)["critic"]
    assert critic["state_layer.weight"].shape == (24, N_AGENTS * run_obs_dim())
    assert critic["own_layer.weight"].shape == (24, run_obs_dim())
    assert [tuple(w.shape) for k, w in critic.items() if k.startswith("head.") and k.endswith("weight")] == [
        (8, 24),
        (1, 8),
    ]
    train(None, tmp_path / "run", resume=True, progress=False, requested={"timesteps": 2 * ROLLOUT})
    model = LearnedPolicy(tmp_path / "run", ENV, "mappo").model
    assert model.num_timesteps == 2 * ROLLOUT
    assert [m.out_features for m in model.policy.mlp_extractor.policy_net if hasattr(m, "out_features")] == [16]


@pytest.mark.parametrize(
    ("algo", "critic_arch", "message"),
    [
        ("ippo", [32], "applies to mappo only"),
        ("mappo", [], "non-empty list of integers"),
        ("mappo", [32, 0], "non-empty list of integers"),
        ("mappo", "64", "non-empty list of integers"),
    ],
)
def test_a_bad_critic_arch_is_refused_before_any_work(tmp_path, algo, critic_arch, message):
    with pytest.raises(ValueError, match=f"argument 'critic_arch'.*{message}"):
        train(config(ROLLOUT, algo, critic_arch=critic_arch), tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


def run_obs_dim() -> int:
    env = make(ENV, **ENV_KWARGS)
    return int(np.prod(env.observation_space(env.possible_agents[0]).shape))


def test_an_env_with_its_own_state_is_refused_for_mappo_only():
    class OwnState(type(make("MapSync-v0"))):
        def _state(self):
            return np.zeros(3, dtype=np.float32)

    env = OwnState()
    check_env(env, "ippo")
    with pytest.raises(ValueError, match="defines its own state"):
        check_env(env, "mappo")


def test_ippo_learns_mapsync_within_a_few_seconds(tmp_path):
    """MapSync's default env: the held-out return of the trained policy beats the untrained one's by far (the
    untrained policy syncs at random and pays for its bits)."""
    run = train(
        TrainConfig(env_id="MapSync-v0", algo="ippo", timesteps=65_536, seed=0, eval_episodes=2), tmp_path / "r",
        progress=False,
    )  # fmt: skip
    with open(run / "progress.csv", newline="") as fh:
        returns = [float(r["heldout/episode_return"]) for r in csv.DictReader(fh) if r["heldout/episode_return"]]
    first, last = returns[0], returns[-1]
    assert last > first + 0.5 * abs(first), returns


# ------------------------------------------------------------------------------------------------ run folders
def interrupt_after_updates(monkeypatch, count: int) -> None:
    """Ctrl-C during the rollout after the ``count``-th update."""
    updates = []
    original = BatchedPPO.collect

    def collect(self):
        if len(updates) == count:
            raise KeyboardInterrupt
        updates.append(1)
        return original(self)

    monkeypatch.setattr(BatchedPPO, "collect", collect)


def optimizer_steps(optimizer) -> int:
    return int(max(float(s["step"]) for s in optimizer.state_dict()["state"].values()))


@pytest.mark.parametrize("algo", ["ippo", "mappo"])
def test_resume_after_ctrl_c_loses_neither_steps_nor_optimizers_nor_statistics(tmp_path, monkeypatch, algo):
    rollouts = 4
    target = rollouts * ROLLOUT
    interrupt_after_updates(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        train(config(target, algo), tmp_path / "run", progress=False)
    monkeypatch.undo()
    newest = training.checkpoints(tmp_path / "run")[0]
    state = json.loads((newest / "state.json").read_text())
    assert state["num_timesteps"] == 2 * ROLLOUT and state["training_seconds"] > 0
    assert (newest / CRITIC_FILE).exists() == (algo == "mappo")
    # training's own time goes on from what the checkpoint kept (set far beyond this test's seconds to tell)
    (newest / "state.json").write_text(json.dumps({**state, "training_seconds": 1_000.0}))

    train(None, tmp_path / "run", resume=True, progress=False)
    with open(tmp_path / "run" / "progress.csv", newline="") as fh:
        seconds = [float(r["time/training_seconds"]) for r in csv.DictReader(fh) if r.get("time/training_seconds")]
    assert seconds[0] == 0.0 and 1_000.0 < seconds[-1] < 1_000.0 + 60.0
    assert 1_000.0 < json.loads((tmp_path / "run" / "state.json").read_text())["training_seconds"] < 1_060.0
    model = LearnedPolicy(tmp_path / "run", ENV, algo).model
    assert model.num_timesteps == target
    # each epoch takes ⌈rows / minibatch⌉ optimizer steps; mappo draws whole copies' rows (N at a time), so its
    # minibatch is ⌊32 / 3⌋ = 10 copies' rows and a rollout of 32 copies' rows takes 4 steps, ippo's 96 rows 3
    blocks, per_batch = (ROLLOUT // N_AGENTS, HYPER["batch_size"] // N_AGENTS) if algo == "mappo" else (ROLLOUT, 32)
    per_rollout = HYPER["n_epochs"] * -(-blocks // per_batch)
    assert optimizer_steps(model.policy.optimizer) == rollouts * per_rollout
    if algo == "mappo":
        critic = torch.load(tmp_path / "run" / CRITIC_FILE, weights_only=True)
        assert int(max(float(s["step"]) for s in critic["optimizer"]["state"].values())) == rollouts * per_rollout
    # one observation per agent-step, plus the reset observations of the start and of the resumption
    stats = load_statistics(tmp_path / "run" / STATISTICS_FILE)
    assert stats.obs_rms.count == pytest.approx(target + 2 * COPIES * N_AGENTS, abs=1e-3)
    with open(tmp_path / "run" / "progress.csv", newline="") as fh:
        steps = [int(float(r["time/total_timesteps"])) for r in csv.DictReader(fh)]
    assert steps == [0] + [ROLLOUT * (k + 1) for k in range(rollouts)] + [target]


@pytest.mark.parametrize("algo", ["ppo", "ippo"])
def test_an_interrupted_run_is_evaluated_with_its_newest_checkpoint_and_says_so(tmp_path, capsys, algo):
    run = tmp_path / "run"
    if algo == "ppo":
        cfg = config(4 * 16 * N_AGENTS, "ppo", n_envs=1, hyperparams={"n_steps": 16, "batch_size": 24, "n_epochs": 1})
        cfg.checkpoint_every = 16 * N_AGENTS
    else:
        cfg = config(4 * ROLLOUT)
    train(cfg, run, progress=False)
    (run / "model.zip").unlink()  # as a run stopped with Ctrl-C leaves it: checkpoints, no final model
    (run / "done.json").unlink()
    capsys.readouterr()
    assert main(["evaluate", ENV, "--policy", f"{algo}:{run}", "--episodes", "1", "--json", str(tmp_path / "e.json"), "--quiet",
                 *[x for k, v in ENV_KWARGS.items() for x in ("--param", f"{k}={v}")]]) == 0  # fmt: skip
    err = capsys.readouterr().err
    newest = training.checkpoints(run)[0].name
    assert f"using its newest checkpoint, {newest}" in err
    assert json.loads((tmp_path / "e.json").read_text())["policy"] == f"{algo}:{run}"


def test_evaluate_takes_an_ippo_run_like_any_learned_policy(tmp_path):
    run = train(config(2 * ROLLOUT), tmp_path / "run", progress=False)
    policy = LearnedPolicy(run, ENV, "ippo")
    assert isinstance(policy.model, PPO) and policy.model.num_timesteps == 2 * ROLLOUT
    with pytest.raises(training.RunError, match="trained with ippo, not mappo"):
        LearnedPolicy(run, ENV, "mappo")


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--config", "BAD"], "'n_steps' must be an integer ≥ 1, got 0"),
        (["--param", "n_robots=3", "--grid", "n_envs=1000000"], "'n_envs' (1000000 copies) needs an estimated"),
    ],
)
def test_bad_settings_are_refused_in_one_line_before_any_work(tmp_path, capsys, extra, message):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"ippo": {"n_steps": 0}}))
    extra = [str(bad) if x == "BAD" else x for x in extra]
    assert main(["train", ENV, "--algo", "ippo", "--out", str(tmp_path / "run"), "--quiet", *extra]) != 0
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "run" / "config.json").exists()


def test_a_sweep_of_seeds_trains_ippo_runs_through_the_runner(tmp_path, capsys):
    settings = tmp_path / "settings.json"
    settings.write_text(json.dumps({"ippo": {**HYPER, "n_envs": COPIES, "net_arch": [16], "timesteps": ROLLOUT}}))
    params = [x for k, v in ENV_KWARGS.items() for x in ("--param", f"{k}={v}")]
    out = tmp_path / "sweep"
    argv = ["train", ENV, "--algo", "ippo", "--config", str(settings), "--seeds", "0,1", "--out", str(out)]
    assert main([*argv, "--quiet", "--eval-episodes", "1", *params]) == 0
    with open(out / "summary.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["seed"]) for r in rows] == [0, 1]
    for row in rows:
        record = json.loads((out / row["run"] / "config.json").read_text())
        assert record["algo"] == "ippo" and record["n_envs"] == COPIES


@pytest.mark.xdist_group("processes")
def test_a_sweep_on_two_workers_trains_the_models_of_one_worker(tmp_path):
    """A sweep's workers own one core each, yet train the bits ``--workers 1`` trains: the update keeps its two
    torch threads (rounding depends on the thread count), and its threads wait passively instead of spinning
    against the other worker's. Large enough (64 × 64 layers, 2,048-row minibatches) that the thread count
    changes the bits of the update."""
    settings = tmp_path / "settings.json"
    hyper = {"n_steps": 16, "batch_size": 2048, "n_epochs": 2, "n_envs": 64, "net_arch": [64, 64]}
    settings.write_text(json.dumps({"ippo": {**hyper, "timesteps": 2 * 16 * 64 * 2}}))
    models = {}
    for workers in (1, 2):
        out = tmp_path / f"workers{workers}"
        argv = ["train", "MapSync-v0", "--algo", "ippo", "--config", str(settings), "--seeds", "0,1", "--out", str(out)]
        assert main([*argv, "--quiet", "--eval-episodes", "1", "--workers", str(workers)]) == 0
        for run in sorted(out.glob("*/s*")):
            with zipfile.ZipFile(run / "model.zip") as archive:
                models[workers, run.name] = archive.read("policy.pth")
    assert models[1, "s0"] != models[1, "s1"]  # the seeds train different models, so equality below means something
    assert models[1, "s0"] == models[2, "s0"] and models[1, "s1"] == models[2, "s1"]


def test_the_configs_reader_names_the_batched_trainers_as_the_trainer_does():
    from mrcomm_env.experiments.runs import BATCHED_TRAINERS

    assert BATCHED_TRAINERS == batched_ppo.BATCHED_ALGORITHMS


def test_the_default_copies_aim_at_128_agent_rows_within_bounds():
    assert training.default_config(ENV, "ippo") == {**batched_ppo.DEFAULTS}
    cfg = TrainConfig(env_id=ENV, algo="ippo", env_kwargs=dict(ENV_KWARGS)).validate()
    assert cfg.n_envs == 43  # ⌈128 / 3⌉ copies of 3 robots
    assert batched_ppo.default_copies(1) == 128 and batched_ppo.default_copies(100) == 16  # the lower bound
    assert TrainConfig(env_id=ENV, env_kwargs=dict(ENV_KWARGS)).validate().n_envs == 4  # SB3's as before


# ------------------------------------------------------------------------------------------------ bench and race
def test_the_bench_times_whole_rollouts_after_an_untimed_one():
    from mrcomm_env.experiments.bench_train import batched_throughput

    result = batched_throughput(ENV, ENV_KWARGS, 10, "mappo", 2)
    rollout = 64 * 2 * N_AGENTS  # the bench's 64 steps per rollout, of every agent of both copies
    assert result["agent_steps"] == 3 * rollout  # at least three rollouts, whole ones, the warm-up not counted
    assert 0 < result["env_step_share"] < 1
    assert result["ppo_agent_steps_per_s"] > result["agent_steps_per_s"] > 0
    assert result["slots"] == 2 * N_AGENTS and result["copies"] == 2


def test_race_refuses_a_warm_started_configuration_and_shares_the_problem_settings():
    from mrcomm_env.experiments.race import race_configs

    with pytest.raises(ValueError, match="starts from a clone"):
        race_configs("MultiHop-v0")
    sb3, batched, spec = race_configs("MapSync-v0")
    shipped = training.default_config("MapSync-v0", "ppo")
    assert sb3["algo"] == "ppo" and batched["algo"] == "ippo"
    assert sb3["env_kwargs"] == batched["env_kwargs"] == shipped["env_kwargs"]
    assert sb3["timesteps"] == shipped["timesteps"] and batched["timesteps"] == 2 * shipped["timesteps"]
    assert sb3["eval_every"] == batched["eval_every"]  # evaluated at the same agent-steps
    for key in ("learning_rate", "gamma", "gae_lambda", "ent_coef"):
        assert batched["hyperparams"][key] == sb3["hyperparams"][key] == shipped[key]
    for key in ("n_steps", "batch_size", "n_epochs"):  # batching: SB3's shipped, the trainer's defaults
        assert sb3["hyperparams"][key] == shipped[key] and batched["hyperparams"][key] == batched_ppo.DEFAULTS[key]
    TrainConfig(seed=0, **sb3).validate()
    TrainConfig(seed=0, **batched).validate()


def test_race_verdict_is_the_first_time_the_batched_trainer_reaches_sb3s_final_return():
    from mrcomm_env.experiments.race import summarize

    def points(seconds, returns):
        return [{"agent_steps": 10.0 * k, "seconds": s, "return": r, "metric": 0.0, "bits": 1.0} for k, (s, r) in
                enumerate(zip(seconds, returns))]  # fmt: skip

    curves = {
        "sb3": [points([0, 50, 100], [-9, -5, -3]), points([0, 60, 120], [-9, -4, -5])],  # final mean −4, 110 s
        "ippo": [points([0, 10, 20, 30], [-9, -4.5, -3.9, -3]), points([0, 12, 24], [-9, -4, -2])],  # 20 s, 12 s
    }
    summary = summarize(curves, algo="ippo")
    assert summary["target_return"] == -4.0
    assert summary["ippo"]["seconds_to_target"] == [20, 12]
    assert summary["share_of_sb3_time"] == pytest.approx(16 / 110)
    assert summary["verdict"] == "met"
    curves["ippo"][1] = points([0, 12], [-9, -8])  # one seed never gets there
    assert summarize(curves, "ippo")["verdict"] == "not reached by every seed"


@pytest.mark.parametrize("algo", ["ppo", "ippo"])
def test_every_heldout_row_says_how_long_training_took_without_the_evaluations(tmp_path, algo):
    hyper = {"n_steps": 16, "batch_size": 24, "n_epochs": 1} if algo == "ppo" else HYPER
    run = train(config(6 * ROLLOUT, algo, hyperparams=hyper, eval_every=ROLLOUT), tmp_path / "run", progress=False)
    with open(run / "progress.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r.get("heldout/episode_return")]
    seconds = [float(r["time/training_seconds"]) for r in rows]
    assert len(rows) >= 4 and seconds[0] == 0.0
    assert all(b >= a for a, b in zip(seconds, seconds[1:])) and seconds[-1] > 0  # never backwards
    evaluating = [float(r["time/heldout_seconds"]) for r in rows]
    assert all(b > a for a, b in zip(evaluating[1:], evaluating[2:]))  # every evaluation adds its own time


# ------------------------------------------------------------------------------------------------ best checkpoint
def heldout_rows(run) -> list[tuple[int, float]]:
    """(agent-steps, held-out mean return) of every held-out evaluation a run logged, in order."""
    with open(run / "progress.csv", newline="") as fh:
        return [
            (int(float(r["time/total_timesteps"])), float(r["heldout/episode_return"]))
            for r in csv.DictReader(fh)
            if r.get("heldout/episode_return")
        ]


@pytest.mark.parametrize("algo", ["ppo", "ippo", "mappo"])
def test_the_best_checkpoint_is_the_policy_its_best_heldout_evaluation_scored(tmp_path, algo):
    """rl-zoo3's ``best_model``: ``best.json`` names the checkpoint of the evaluation with the highest held-out return
    after agent-step 0 (the first on a tie), and that checkpoint, played again on the same held-out episodes, scores
    that return to the last digit (the policy saved is the policy evaluated, with its normalisation). It outlives
    the rotation of the regular checkpoints, and ``checkpoint="best"`` acts with it."""
    from mrcomm_agents.heldout import HELDOUT_SEEDS, evaluate_episodes

    if algo == "ppo":
        hyper = {"n_steps": 16, "batch_size": 24, "n_epochs": 2}
        cfg = config(8 * 16 * N_AGENTS, "ppo", n_envs=1, hyperparams=hyper, eval_every=16 * N_AGENTS)
    else:
        cfg = config(8 * ROLLOUT, algo, eval_every=ROLLOUT)
    cfg.eval_episodes = 2
    cfg.hyperparams["learning_rate"] = 3e-3  # the policy moves enough between evaluations for returns to differ
    run = train(cfg, tmp_path / "run", progress=False)
    rows = heldout_rows(run)
    candidates = [(steps, value) for steps, value in rows if steps > 0]
    assert len(candidates) >= 6 and len({v for _, v in candidates}) > 1, rows
    top = max(value for _, value in candidates)
    first_step = next(steps for steps, value in candidates if value == top)
    record = json.loads((run / training.BEST_FILE).read_text())
    assert record["episode_return"] == top and record["heldout"]["episode_return"] == top
    best = training.best_checkpoint(run)
    assert best.name == record["checkpoint"]
    # an SB3 rollout's evaluation scores the policy that collected it, saved under the rollout's start
    rollout = 16 * N_AGENTS if algo == "ppo" else ROLLOUT
    expected_steps = first_step - rollout if algo == "ppo" and first_step != cfg.timesteps else first_step
    assert record["num_timesteps"] == expected_steps == json.loads((best / "state.json").read_text())["num_timesteps"]
    # kept beside the newest regular checkpoints, however old
    assert best in training.checkpoints(run)
    assert len(training.checkpoints(run)) <= training.KEEP_CHECKPOINTS + 1
    policy = LearnedPolicy(run, ENV, algo, checkpoint="best")
    assert policy.source == best and policy.model.num_timesteps == expected_steps
    again = evaluate_episodes(
        policy.model, policy.normalizer, ENV, cfg.env_kwargs, range(HELDOUT_SEEDS, HELDOUT_SEEDS + 2), True
    )
    assert again["episode_return"] == top


def test_a_resumed_run_forgets_a_best_kept_after_the_checkpoint_it_goes_on_from(tmp_path):
    """The stretch after the checkpoint a resumed run goes on from is trained again on other episodes: a best kept
    in it belongs to a policy the run no longer leads to."""
    (tmp_path / training.BEST_FILE).write_text(
        json.dumps({"checkpoint": "step-000000000096", "num_timesteps": 96, "episode_return": -1.0})
    )
    assert training.BestCheckpoint(tmp_path, resumed_at=192).record["num_timesteps"] == 96
    assert (tmp_path / training.BEST_FILE).exists()
    assert training.BestCheckpoint(tmp_path, resumed_at=48).record is None
    assert not (tmp_path / training.BEST_FILE).exists()


def test_a_run_without_a_best_checkpoint_and_a_bad_checkpoint_setting_are_refused_naming_them(tmp_path, capsys):
    run = train(config(2 * ROLLOUT, eval_episodes=0), tmp_path / "run", progress=False)
    with pytest.raises(training.RunError, match="names no best checkpoint"):
        LearnedPolicy(run, ENV, "ippo", checkpoint="best")
    capsys.readouterr()
    assert main(["evaluate", ENV, "--policy", f"ippo:{run}", "--policy-param", "checkpoint=best", "--quiet"]) != 0
    err = capsys.readouterr().err
    assert "names no best checkpoint" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    with pytest.raises(training.RunError, match="'checkpoint' must be one of final, best, got 'newest'"):
        LearnedPolicy(run, ENV, "ippo", checkpoint="newest")
    assert LearnedPolicy(run, ENV, "ippo", checkpoint="final").model.num_timesteps == 2 * ROLLOUT


# ------------------------------------------------------------------------------------------------ schedules
@pytest.mark.parametrize("algo", ["ppo", "ippo"])
def test_lin_settings_anneal_linearly_to_zero_and_come_back_from_the_run_folder(tmp_path, monkeypatch, algo):
    """rl-zoo3's ``"lin_<start>"``: the learning rate and both clip ranges of each update are ``start`` × the share of
    the run's agent-steps still to come, as logged; a loaded (or resumed) model has the same schedules back."""
    rollouts = 4
    if algo == "ppo":
        rollout = 16 * N_AGENTS
        hyper = {"n_steps": 16, "batch_size": 24, "n_epochs": 1}
        cfg = config(rollouts * rollout, "ppo", n_envs=1, hyperparams=hyper)
        cfg.checkpoint_every = rollout
    else:
        rollout, cfg = ROLLOUT, config(rollouts * ROLLOUT)
    cfg.hyperparams.update(learning_rate="lin_0.001", clip_range="lin_0.3", clip_range_vf="lin_0.2")
    if algo == "ippo":  # stopped after two updates and resumed: the schedule goes on from the checkpoint
        interrupt_after_updates(monkeypatch, 2)
        with pytest.raises(KeyboardInterrupt):
            train(cfg, tmp_path / "run", progress=False)
        monkeypatch.undo()
        train(None, tmp_path / "run", resume=True, progress=False)
    else:
        train(cfg, tmp_path / "run", progress=False)
    with open(tmp_path / "run" / "progress.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r.get("train/learning_rate")]
    # each update k = 1…4 runs after the k-th rollout, at progress_remaining = 1 − k/4 (SB3's
    # _update_current_progress_remaining; SB3 logs an update's values with the next rollout's row)
    expected = [1.0 - k / rollouts for k in range(1, rollouts + 1)]
    logged_rates = [float(r["train/learning_rate"]) for r in rows]
    logged_clips = [float(r["train/clip_range"]) for r in rows]
    logged_value_clips = [float(r["train/clip_range_vf"]) for r in rows]
    assert logged_rates == pytest.approx([0.001 * f for f in expected], rel=1e-9, abs=1e-15), logged_rates
    assert logged_clips == pytest.approx([0.3 * f for f in expected], rel=1e-9, abs=1e-15), logged_clips
    assert logged_value_clips == pytest.approx([0.2 * f for f in expected], rel=1e-9, abs=1e-15), logged_value_clips
    assert json.loads((tmp_path / "run" / "config.json").read_text())["hyperparams"]["learning_rate"] == "lin_0.001"
    model = LearnedPolicy(tmp_path / "run", ENV, algo).model
    assert model.lr_schedule(0.5) == pytest.approx(0.0005) and model.clip_range(0.25) == pytest.approx(0.075)
    assert model.clip_range_vf(0.5) == pytest.approx(0.1)


@pytest.mark.parametrize(
    "value, message",
    [
        ("lin_fast", "argument 'learning_rate' must be a number or 'lin_<number>'"),
        ("cos_0.001", "argument 'learning_rate' must be a number or 'lin_<number>'"),
        ("lin_-0.001", "'learning_rate'"),  # the start is checked against the documented range
        ("lin_nan", "argument 'learning_rate' must be a number or 'lin_<number>'"),
    ],
)
def test_a_bad_schedule_is_refused_in_one_line_before_any_work(tmp_path, capsys, value, message):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"ippo": {"learning_rate": value}}))
    assert main(["train", ENV, "--algo", "ippo", "--out", str(tmp_path / "run"), "--quiet", "--config", str(bad)]) != 0
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "run" / "config.json").exists()


def test_only_the_annealable_settings_take_the_lin_notation(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"ippo": {"gamma": "lin_0.9"}}))
    assert main(["train", ENV, "--algo", "ippo", "--out", str(tmp_path / "run"), "--quiet", "--config", str(bad)]) != 0
    assert "argument 'gamma' must be a number, got 'lin_0.9'" in capsys.readouterr().err


def record_thread_counts(monkeypatch) -> list[int]:
    """Every ``torch.set_num_threads`` call from now on (the calls still take effect)."""
    calls: list[int] = []
    original = torch.set_num_threads

    def record(n: int) -> None:
        calls.append(n)
        original(n)

    monkeypatch.setattr(torch, "set_num_threads", record)
    return calls


def test_update_threads_is_a_setting_of_the_run_used_by_every_update_and_kept_on_resume(tmp_path, monkeypatch):
    """``update_threads``: each update runs on that many torch threads (3 here, which no default gives on any
    machine), and the rollout on one; the run folder keeps the setting, and a resumed run goes on with it."""
    try:
        calls = record_thread_counts(monkeypatch)
        interrupt_after_updates(monkeypatch, 1)
        with pytest.raises(KeyboardInterrupt):
            train(config(3 * ROLLOUT, update_threads=3), tmp_path / "run", progress=False)
        assert calls.count(3) == 1 and set(calls) == {1, 3}
        assert json.loads((tmp_path / "run" / "config.json").read_text())["update_threads"] == 3
        monkeypatch.undo()
        calls = record_thread_counts(monkeypatch)
        train(None, tmp_path / "run", resume=True, progress=False)
        assert calls.count(3) == 2 and set(calls) == {1, 3}  # the two updates left
    finally:
        torch.set_num_threads(1)  # as this module runs; the interrupt above leaves the update's 3


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--algo", "ppo", "--update-threads", "2"], "argument 'update_threads' applies to ippo and mappo only"),
        (["--algo", "ippo", "--update-threads", "0"], "--update-threads: must be an integer ≥ 1"),
    ],
)
def test_update_threads_outside_the_batched_trainer_or_below_one_is_refused_in_one_line(
    tmp_path, capsys, argv, message
):
    assert main(["train", ENV, *argv, "--out", str(tmp_path / "run"), "--quiet"]) != 0
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "run" / "config.json").exists()


@pytest.mark.parametrize("value", [0, True, 1.5])
def test_update_threads_from_a_configuration_must_be_a_whole_count(value):
    with pytest.raises(ValueError, match="argument 'update_threads' must be None or an integer ≥ 1"):
        config(ROLLOUT, update_threads=value).validate()


def test_a_run_trains_the_same_bits_whatever_processes_step_its_copies(tmp_path):
    """``env_workers``: the copies step in one process or in three (shards of 2, 1 and 1 copies), and the run's
    model, statistics and training return are the same to the bit; the copies' processes are not part of the run's
    identity."""
    weights, statistics, returns = {}, {}, {}
    for workers in (1, 3):
        out = tmp_path / f"workers{workers}"
        train(config(3 * ROLLOUT, env_workers=workers), out, progress=False)
        with zipfile.ZipFile(out / "model.zip") as archive:
            weights[workers] = archive.read("policy.pth")
        statistics[workers] = (out / STATISTICS_FILE).read_bytes()
        with open(out / "progress.csv", newline="") as handle:
            returns[workers] = [row["rollout/ep_rew_mean"] for row in csv.DictReader(handle)]
        assert json.loads((out / "config.json").read_text())["env_workers"] == workers
    assert weights[1] == weights[3] and statistics[1] == statistics[3] and returns[1] == returns[3]
    assert any(returns[1]), returns  # episodes ended while training: the returns compared are not all empty


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--algo", "ppo", "--env-workers", "2"], "argument 'env_workers' applies to ippo and mappo only"),
        (["--algo", "ippo", "--env-workers", "0"], "--env-workers: must be an integer ≥ 1"),
        (["--algo", "ippo", "--env-workers", "99"], "argument 'env_workers' must be at most n_envs"),
    ],
)
def test_env_workers_outside_the_batched_trainer_or_its_copies_is_refused_in_one_line(tmp_path, capsys, argv, message):
    assert main(["train", ENV, *argv, "--out", str(tmp_path / "run"), "--quiet"]) != 0
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "run" / "config.json").exists()


# ------------------------------------------------------------------------------------------------ kickstarting
def emit_on_own_id_bit(seed: int):
    """A frozen policy of ChannelAssociation's spaces that emits exactly when the normalised first feature (the own
    ID bit a blink code sends now) is positive: a choice that depends on the state, unlike a random network's."""
    probe = make(ENV, **ENV_KWARGS)
    agent = probe.possible_agents[0]
    model = build_model(
        training.algorithm_class("ippo", probe), "MlpPolicy", {"net_arch": [16]}, probe.observation_space(agent),
        probe.action_space(agent), {"n_steps": 8, "batch_size": 16, "n_epochs": 1}, seed,
    )  # fmt: skip
    policy = model.policy
    first = policy.mlp_extractor.policy_net[0]
    with torch.no_grad():
        first.weight.zero_()
        first.bias.zero_()
        first.weight[0, 0] = 5.0
        policy.action_net.weight.zero_()
        policy.action_net.bias.zero_()
        policy.action_net.weight[1, 0] = 10.0
    return policy.requires_grad_(False)


def agreement_with(tr: BatchedPPO, teacher, rollouts: int = 3) -> float:
    """The share of the states of ``rollouts`` fresh rollouts where the policy's and the teacher's modes agree."""
    agree = total = 0
    for _ in range(rollouts):
        tr.collect()
        obs = torch.from_numpy(tr.buf_obs.reshape(-1, tr.obs_dim))
        with torch.no_grad():
            mine = tr.actor_distribution(obs, None).get_actions(deterministic=True)
            theirs = teacher.get_distribution(obs).get_actions(deterministic=True)
        agree += int((mine == theirs).sum())
        total += len(mine)
    return agree / total


def test_kickstarting_pulls_the_policy_to_its_teachers_choices_and_plain_ppo_does_not():
    after = {}
    for coef in (0.0, 5.0):
        tr = trainer(ENV, ENV_KWARGS, COPIES, 8)  # the same seed: the same start and the same first rollouts
        teacher = emit_on_own_id_bit(seed=1)
        if coef:
            tr.kickstart(teacher, coef, 10**9)
        before = agreement_with(tr, teacher)
        for _ in range(10):
            tr.collect()
            tr.update(1.0)
        after[coef] = agreement_with(tr, teacher)
    # a Discrete(2) choice: a policy that ignores the teacher agrees with it about half the time
    assert before < 0.8 and after[0.0] < 0.8, (before, after)
    assert after[5.0] >= 0.95, (before, after)


def kickstart_run(tmp_path, **settings) -> list[str]:
    """``mrcomm train`` argv of a warm-started ippo run of 4 rollouts that kickstarts over the first 2."""
    cfg = tmp_path / "kickstart.json"
    block = {**HYPER, "n_envs": COPIES, "net_arch": [16], "eval_episodes": 0, "checkpoint_every": ROLLOUT}
    block.update({"kickstart_coef": 2.0, "kickstart_steps": 2 * ROLLOUT, "freeze_normalization": True, **settings})
    cfg.write_text(json.dumps({"ippo": block}))
    argv = ["train", ENV, "--algo", "ippo", "--init-from", "baseline:id_bits", "--config", str(cfg), "--quiet"]
    argv += ["--timesteps", str(4 * ROLLOUT), "--out", str(tmp_path / "run")]
    return argv + [x for k, v in ENV_KWARGS.items() for x in ("--param", f"{k}={v}")]


def logged(run, column: str) -> list[float]:
    with open(run / "progress.csv", newline="") as fh:
        return [float(r[column]) for r in csv.DictReader(fh) if r.get(column)]


@pytest.mark.parametrize("warmup", [0, ROLLOUT])
def test_the_kickstarting_weight_falls_linearly_to_zero_and_a_resumed_run_reads_its_teacher_again(
    tmp_path, monkeypatch, warmup
):
    run = tmp_path / "run"
    interrupt_after_updates(monkeypatch, 1)
    assert main(kickstart_run(tmp_path, critic_warmup=warmup)) == 130  # Ctrl-C after the first update
    monkeypatch.undo()
    teacher_file = run / training.KICKSTART_TEACHER_FILE
    written = teacher_file.read_bytes()
    assert main(["train", ENV, "--resume", "--out", str(run), "--quiet"]) == 0
    # the weight of the rollouts starting at agent-steps 0, R, 2R, 3R: 2 · (1 − start / 2R), then 0; a critic-only
    # update (the critic warm-up of the first rollout) applies none
    weights = [0.0 if warmup else 2.0, 1.0, 0.0, 0.0]
    assert logged(run, "train/kickstart_weight") == weights
    losses = logged(run, "train/kickstart_loss")
    assert len(losses) == 4 and all((loss > 0) == (w > 0) for loss, w in zip(losses, weights, strict=True)), losses
    assert teacher_file.read_bytes() == written  # the clone as cloned, read again on resume, never retrained
    teacher_file.unlink()
    assert main(["train", ENV, "--resume", "--timesteps", str(5 * ROLLOUT), "--out", str(run), "--quiet"]) != 0


@pytest.mark.parametrize(
    "argv, settings, message",
    [
        ([], {"kickstart_steps": 0}, "'kickstart_steps' must be an integer ≥ 1 with 'kickstart_coef' > 0"),
        ([], {"kickstart_coef": -1.0}, "'kickstart_coef' must be a number ≥ 0"),
        ([], {"kickstart_coef": 0.0}, "'kickstart_steps' needs 'kickstart_coef' > 0"),
        (["--algo", "ppo"], {}, "'kickstart_coef' needs algo ippo or mappo and a warm start"),
        (["--no-warm-start"], {"freeze_normalization": False}, "needs algo ippo or mappo and a warm start"),
        ([], {"freeze_normalization": False}, "'kickstart_coef' needs 'freeze_normalization': true"),
    ],
)
def test_bad_kickstarting_settings_are_refused_in_one_line_before_any_work(tmp_path, capsys, argv, settings, message):
    full = kickstart_run(tmp_path, **settings)
    if "--no-warm-start" in argv:
        at = full.index("--init-from")
        del full[at : at + 2]
    if "--algo" in argv:
        full[full.index("--algo") + 1] = argv[1]
        cfg = tmp_path / "kickstart.json"
        cfg.write_text(json.dumps({"ppo": json.loads(cfg.read_text())["ippo"]}))
    assert main(full) != 0
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "run" / "config.json").exists()


def test_a_runs_folder_digest_leaves_out_its_stepping_processes_and_keeps_every_other_setting():
    settings = {"env_id": ENV, "algo": "ippo", "seed": 0, "timesteps": 100, "n_envs": 4}
    folder = runs.run_folder("lam=0", settings)
    assert runs.run_folder("lam=0", {**settings, "env_workers": 2}) == folder  # the same numbers, the same run
    assert runs.run_folder("lam=0", {**settings, "n_envs": 8}) != folder
    assert runs.run_folder("lam=0", {**settings, "seed": 1}) == folder.replace("/s0", "/s1")
