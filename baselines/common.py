"""What the scripted policies share beyond the interface (``mrcomm_env.core.policy``): the random policy."""

from __future__ import annotations

from mrcomm_env.core.policy import LocalViews, Policy


class RandomPolicy(Policy):
    """Uniformly random actions from each agent's action space (seeded through ``reset``)."""

    name = "random"

    def reset(self, views: LocalViews, seed: int | None = None) -> None:
        super().reset(views, seed)
        self._space = views.action_space
        self._space.seed(int(self.rng.integers(2**31)))

    def act(self, observations, views):
        return {agent: self._space.sample() for agent in observations}
