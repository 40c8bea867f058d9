"""The candidate policies' action distributions (``agents/policies.py``)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from mrcomm_agents.policies import CandidateExtractor, SubsetDistribution

torch.set_num_threads(1)


def all_subsets(k: int, c: int) -> torch.Tensor:
    """Every MultiBinary action with at most c of k bits set, one per row."""
    rows = [
        [1.0 if i in chosen else 0.0 for i in range(k)]
        for j in range(c + 1)
        for chosen in itertools.combinations(range(k), j)
    ]
    return torch.tensor(rows, dtype=torch.float64)


@pytest.mark.parametrize("k, c", [(5, 3), (4, 1), (6, 2), (3, 3)])
def test_subset_probabilities_sum_to_one_over_every_choice(k, c):
    generator = torch.Generator().manual_seed(k * 10 + c)
    logits = torch.randn(2, k + 1, generator=generator, dtype=torch.float64) * 2
    actions = all_subsets(k, c)
    dist = SubsetDistribution(k, c).proba_distribution(logits.repeat_interleave(len(actions), dim=0))
    log_p = dist.log_prob(actions.repeat(2, 1)).reshape(2, -1)
    # a sum of ~2^k terms of size ~1: float64 rounding is far below 1e-12
    torch.testing.assert_close(log_p.exp().sum(dim=1), torch.ones(2, dtype=torch.float64), rtol=0, atol=1e-12)


def test_subset_probability_of_a_pair_is_the_sum_over_its_two_draw_orders():
    # K = 3 candidates and stop, scores 0, log 2, log 3 and stop log 4: Z = 1 + 2 + 3 + 4 = 10. Choosing exactly
    # {0, 1} with c = 2: 1/10 · 2/9 + 2/10 · 1/8 (no stop after the second draw, c is reached)
    logits = torch.tensor([[0.0, np.log(2), np.log(3), np.log(4)]], dtype=torch.float64)
    dist = SubsetDistribution(3, 2).proba_distribution(logits)
    expected = 1 / 10 * 2 / 9 + 2 / 10 * 1 / 8
    assert dist.log_prob(torch.tensor([[1.0, 1.0, 0.0]])).exp().item() == pytest.approx(expected, rel=1e-12)
    # {2} alone: 3/10, then stop among 1 + 2 + 4 = 7 left
    assert dist.log_prob(torch.tensor([[0.0, 0.0, 1.0]])).exp().item() == pytest.approx(3 / 10 * 4 / 7, rel=1e-12)
    # nothing: stop first
    assert dist.log_prob(torch.tensor([[0.0, 0.0, 0.0]])).exp().item() == pytest.approx(4 / 10, rel=1e-12)
    # more bits than c: the first c in candidate order count, as the env sends them
    assert dist.log_prob(torch.tensor([[1.0, 1.0, 1.0]])).item() == pytest.approx(np.log(expected), rel=1e-12)


def test_subset_samples_follow_the_probabilities_and_the_mode_is_the_greedy_draw():
    k, c = 4, 2
    logits = torch.tensor([[1.0, 0.2, -0.5, 0.7, 0.1]], dtype=torch.float64)  # the last: stop
    dist = SubsetDistribution(k, c).proba_distribution(logits.repeat(20_000, 1))
    torch.manual_seed(0)
    samples = dist.sample()
    assert ((samples.sum(dim=1) <= c) & ((samples == 0) | (samples == 1)).all(dim=1)).all()
    actions = all_subsets(k, c)
    exact = SubsetDistribution(k, c).proba_distribution(logits.repeat(len(actions), 1)).log_prob(actions).exp()
    observed = torch.stack([(samples == a).all(dim=1).double().mean() for a in actions])
    # 20,000 draws: a frequency p has standard error sqrt(p(1 − p)/20000) ≤ 0.0036; 5 standard errors
    assert torch.all((observed - exact).abs() <= 5 * torch.sqrt(exact * (1 - exact) / 20_000) + 1e-9)
    # the mode draws the best two (candidates 0 and 3) and never reaches stop, scored below both
    mode = SubsetDistribution(k, c).proba_distribution(logits).mode()
    assert mode.tolist() == [[1.0, 0.0, 0.0, 1.0]]
    stop_first = SubsetDistribution(k, c).proba_distribution(torch.tensor([[0.0, 0.0, 0.0, 0.0, 5.0]])).mode()
    assert stop_first.tolist() == [[0.0, 0.0, 0.0, 0.0]]


def train_subset_policy(tmp_path, env_kwargs: dict, algo: str, n_envs: int):
    """A few rollouts of the ``candidate_subset`` policy on a MultiHop 3×3 grid (m = 3: at most 2 of 8 candidates)."""
    from mrcomm_agents.training import TrainConfig, train

    config = TrainConfig(
        env_id="MultiHop-v0",
        algo=algo,
        timesteps=9 * 8 * n_envs,
        seed=1,
        env_kwargs=env_kwargs,
        hyperparams={"n_steps": 8, "batch_size": 24, "n_epochs": 1},
        n_envs=n_envs,
        net_arch=[16],
        policy="candidate_subset",
        eval_episodes=0,
    )
    return train(config, tmp_path / "run", progress=False)


def test_a_subset_policy_is_refused_without_a_choose_in_the_layout(tmp_path):
    from mrcomm_agents.training import TrainConfig

    with pytest.raises(ValueError, match="candidate_subset"):
        TrainConfig(env_id="RendezvousMapping-v0", policy="candidate_subset").validate()


def test_a_subset_policy_trains_saves_loads_and_never_selects_more_than_the_slot_holds(tmp_path):
    from mrcomm_agents.learned import LearnedPolicy
    from mrcomm_env.experiments.evaluation import run_episode
    from mrcomm_env.registry import make

    kwargs = {"grid_side": 3, "slot_size": 3, "max_cycles": 6}
    run = train_subset_policy(tmp_path, kwargs, "ppo", n_envs=1)
    for deterministic in (True, False):
        policy = LearnedPolicy(run, "MultiHop-v0", deterministic=deterministic)
        assert isinstance(policy.model.policy.action_dist, SubsetDistribution)
        env = make("MultiHop-v0", **kwargs)
        observations, _ = env.reset(seed=3)
        policy.reset(env.local_views(), seed=3)
        for _ in range(4):
            actions = policy.act(observations, env.local_views())
            assert all(int(np.sum(a)) <= kwargs["slot_size"] - 1 for a in actions.values())
            observations, *_ = env.step(actions)
        assert np.isfinite(run_episode(env, policy, 4)["weighted_mean_age"])


def subset_policy(stop_bias: float, subset: bool = True):
    """A fresh candidate policy over MultiHop's 3×3 grid (m = 3: choose 2 of 8 candidates)."""
    from stable_baselines3.common.utils import ConstantSchedule

    from mrcomm_agents.policies import CandidatePolicy
    from mrcomm_env.registry import make

    env = make("MultiHop-v0", grid_side=3, slot_size=3, max_cycles=6)
    torch.manual_seed(0)
    policy = CandidatePolicy(
        env.observation_space(env.possible_agents[0]),
        env.action_space(env.possible_agents[0]),
        ConstantSchedule(3e-4),
        layout=env.observation_layout(),
        hidden=16,
        context=True,
        subset=subset,
        stop_bias=stop_bias,
    )
    observations, _ = env.reset(seed=0)
    return policy, torch.as_tensor(np.stack(list(observations.values())), dtype=torch.float32)


def test_a_stop_bias_starts_random_weights_filling_the_slot():
    unbiased, obs = subset_policy(0.0)
    biased, _ = subset_policy(-3.0)
    with torch.no_grad():
        sent = biased.predict(obs.numpy(), deterministic=True)[0].sum(axis=1)
        stop = biased.get_distribution(obs).logits  # the scores, "stop" last
        base = unbiased.get_distribution(obs).logits
    assert sent.tolist() == [2.0] * obs.shape[0]  # every robot fills its m − 1 = 2 relays
    # the bias moves the "stop" score and nothing else
    assert torch.allclose(stop[:, :-1], base[:, :-1]) and torch.allclose(stop[:, -1], base[:, -1] - 3.0)


@pytest.mark.parametrize(
    "stop_bias, subset, match", [(-3.0, False, "'candidate_subset' only"), (math.nan, True, "finite")]
)
def test_a_stop_bias_is_refused_where_it_means_nothing(stop_bias, subset, match):
    with pytest.raises(ValueError, match=match):
        subset_policy(stop_bias, subset=subset)


def test_a_masked_subset_is_the_subset_distribution_over_the_allowed_candidates_alone():
    """Masking candidates 1 and 4 of five leaves exactly the Plackett–Luce draw over candidates 0, 2, 3 and "stop"
    (the distribution of those scores alone): every set holding a masked candidate has probability 0."""
    k, c = 5, 3
    generator = torch.Generator().manual_seed(7)
    logits = torch.randn(1, k + 1, generator=generator, dtype=torch.float64) * 2
    allowed = [0, 2, 3]
    mask = torch.tensor([[i in allowed for i in range(k)]])
    actions = all_subsets(k, c)
    masked = SubsetDistribution(k, c).proba_distribution(logits.repeat(len(actions), 1))
    masked.apply_masking(mask.repeat(len(actions), 1))
    p = masked.log_prob(actions).exp()
    reduced_logits = logits[:, allowed + [k]]
    inside = actions[:, [1, 4]].sum(dim=1) == 0
    reduced = SubsetDistribution(len(allowed), c).proba_distribution(reduced_logits.repeat(int(inside.sum()), 1))
    expected = torch.zeros(len(actions), dtype=torch.float64)
    expected[inside] = reduced.log_prob(actions[inside][:, allowed]).exp()
    torch.testing.assert_close(p, expected, rtol=1e-12, atol=1e-300)
    # sb3-contrib's MultiBinary layout (may be 0, may be 1 per bit) masks the same; None undoes the masking
    both = torch.stack([torch.ones_like(mask), mask], dim=-1).reshape(1, 2 * k)
    again = SubsetDistribution(k, c).proba_distribution(logits)
    again.apply_masking(both)
    torch.testing.assert_close(again.logits, masked.logits[:1])
    again.apply_masking(None)
    assert torch.equal(again.logits, logits)
    with pytest.raises(ValueError, match="columns"):
        again.apply_masking(torch.ones(1, k + 1, dtype=torch.bool))


def test_masked_draws_and_the_mode_never_pick_a_masked_candidate():
    k, c = 6, 3
    logits = torch.tensor([[3.0, 2.5, 2.0, -1.0, -2.0, 1.0, -4.0]])  # masked 0, 1: the two best scores
    mask = torch.tensor([[False, False, True, True, True, True]])
    dist = SubsetDistribution(k, c).proba_distribution(logits.repeat(5_000, 1))
    dist.apply_masking(mask.repeat(5_000, 1))
    torch.manual_seed(1)
    assert dist.sample()[:, :2].sum().item() == 0
    # the greedy draw over what is left: 2 (2.0) and 5 (1.0), then 3 (−1.0) ahead of stop (−4.0)
    assert dist.mode()[0].tolist() == [0.0, 0.0, 1.0, 1.0, 0.0, 1.0]
    # nothing allowed: the draw stops at once
    dist.apply_masking(torch.zeros(5_000, k, dtype=torch.bool))
    assert dist.mode().sum().item() == 0


def test_sb3_masks_spell_a_multibinary_mask_per_value_and_pass_others_unchanged():
    from gymnasium import spaces

    from mrcomm_agents.heldout import sb3_masks

    per_bit = np.array([[True, False, True], [False, False, True]])
    assert sb3_masks(per_bit, spaces.MultiBinary(3)).tolist() == [
        [True, True, True, False, True, True],
        [True, False, True, False, True, True],
    ]
    discrete = np.array([[True, False, True]])
    assert sb3_masks(discrete, spaces.Discrete(3)).tolist() == discrete.tolist()
    # already in sb3-contrib's layout
    assert sb3_masks(np.ones((1, 6), dtype=bool), spaces.MultiBinary(3)).shape == (1, 6)


@pytest.mark.parametrize("algo", ["ippo", "maskable_ppo"])
def test_a_subset_policy_on_multihop_with_mask_unheld_trains_masked_and_picks_only_held_estimates(tmp_path, algo):
    """With ``mask_unheld`` the batched trainer (and SB3's MaskablePPO) build the masked candidate policy; the trained
    policy, sampled or greedy, selects only candidates its robot holds at the frame's start."""
    from mrcomm_agents.learned import LearnedPolicy
    from mrcomm_agents.policies import MaskableCandidatePolicy
    from mrcomm_env.registry import make

    kwargs = {"grid_side": 3, "slot_size": 3, "max_cycles": 6, "mask_unheld": True}
    run = train_subset_policy(tmp_path, kwargs, algo, n_envs=2)
    picks = 0
    for deterministic in (True, False):
        policy = LearnedPolicy(run, "MultiHop-v0", deterministic=deterministic)
        assert type(policy.model).__name__ == "MaskablePPO"
        assert isinstance(policy.model.policy, MaskableCandidatePolicy)
        env = make("MultiHop-v0", **kwargs)
        observations, _ = env.reset(seed=3)
        policy.reset(env.local_views(), seed=3)
        while env.agents:
            held = env.action_masks()
            actions = policy.act(observations, env.local_views())
            chosen = np.stack([actions[a] for a in env.agents]) > 0.5
            assert not (chosen & ~held).any()
            picks += int(chosen.sum())
            observations, *_ = env.step(actions)
    assert picks > 0  # the check above saw selections, not a policy that always stops


@pytest.mark.parametrize("context", [True, False])
def test_the_candidate_networks_are_mlps_of_each_candidates_concatenated_inputs(context):
    """Each candidate's score (and the critic's embedding of it) is the MLP of the concatenation (its features, the
    robot's own features[, the list's summary]), as the layers' shapes declare; the extractor splits the first layer
    so as never to build it. Scores, values and every parameter's gradient agree up to float rounding."""
    torch.manual_seed(3)
    k, f, g, hidden = 7, 4, 3, 16
    extractor = CandidateExtractor(k, f, g, extra_actions=2, hidden=hidden, context=context)
    obs = torch.rand(50, k * f + g + 2)  # two trailing numbers that are not part of the layout
    cand, own = obs[:, : k * f].reshape(-1, k, f), obs[:, k * f : k * f + g]
    paired = torch.cat([cand, own[:, None, :].expand(-1, k, -1)], dim=-1)

    def reference() -> tuple[torch.Tensor, torch.Tensor]:
        scorer_inputs = paired
        if context:
            embedded = extractor.context(paired)
            summary = torch.cat([embedded.mean(dim=1), embedded.max(dim=1).values], dim=-1)
            scorer_inputs = torch.cat([paired, summary[:, None, :].expand(-1, k, -1)], dim=-1)
        logits = torch.cat([extractor.scorer(scorer_inputs).squeeze(-1), extractor.extra(own)], dim=-1)
        pooled = extractor.value_candidates(paired).mean(dim=1)
        return logits, extractor.value_head(torch.cat([pooled, extractor.value_own(own)], dim=-1))

    def gradients(outputs: tuple[torch.Tensor, torch.Tensor]) -> list[torch.Tensor]:
        extractor.zero_grad()
        (outputs[0].square().sum() + outputs[1].square().sum()).backward()
        return [p.grad.clone() for p in extractor.parameters()]

    expected, got = reference(), (extractor.forward_actor(obs), extractor.forward_critic(obs))
    assert got[0].shape == (50, k + 2) and got[1].shape == (50, hidden)
    # the same float32 sums in another order: at most F + G + 2·hidden = 39 terms of size O(1) per first-layer unit
    for a, b in zip(got, expected):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
    # a gradient also sums over the 50 rows and 7 candidates, in another order
    for a, b in zip(gradients(got), gradients(reference())):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)
