"""What a policy may see of an environment, and the interface every policy implements.

Scripted baselines (``baselines/``) and learned policies (``agents/``) are compared on the same metrics,
so what each reads has to be visible. A policy gets two things:

* the **observations** the env returns (what a learned policy is trained on), and
* a read-only :class:`LocalViews`: for every robot, what that robot legitimately knows (its own filter,
  table or estimate list), as declared by the env's ``LOCAL_VIEW`` and listed in ``docs/envs/*.md``.

It never gets the env itself. A policy that needs knowledge no single robot has says so in
``GLOBAL_KNOWLEDGE`` (a sentence); the docs list it beside the policy.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, ClassVar, Protocol

import numpy as np
from gymnasium import spaces

from mrcomm_env.core.config import Param, validate_config


class PerRobotSource(Protocol):
    """What :class:`LocalViews` reads of an env: its public per-robot view and the common knowledge, nothing
    private (every ``MrcommParallelEnv`` is one)."""

    ENV_ID: str
    LOCAL_VIEW: Mapping[str, str]
    possible_agents: list[str]
    agents: list[str]
    n_agents: int
    cfg: Mapping[str, Any]
    step_count: int

    @property
    def state_version(self) -> int: ...

    def per_robot_view(self) -> dict[str, Any]: ...

    def action_space(self, agent: str) -> spaces.Space: ...

    def observation_space(self, agent: str) -> spaces.Space: ...


def _read_only(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        view = value.view()
        view.flags.writeable = False
        return view
    return value


class LocalViews:
    """Per-robot knowledge of a live env, read-only.

    ``views.team(name)`` is an array whose row i is robot i's own copy of ``name`` (a policy that computes
    row i of its output from row i alone is decentralised); ``views[agent]`` maps every field to that
    robot's row. Common knowledge: the agent names, the spaces, the env's arguments (``params``) and the
    shared step clock (``step``). Each access reads the env's current state; nothing can be written back.
    """

    def __init__(self, env: PerRobotSource):
        self._env = env
        self.possible_agents: tuple[str, ...] = tuple(env.possible_agents)
        self.n_agents: int = env.n_agents
        self.params: Mapping[str, Any] = MappingProxyType(dict(env.cfg))
        self.fields: Mapping[str, str] = MappingProxyType(dict(env.LOCAL_VIEW))
        first = self.possible_agents[0]
        self.action_space = env.action_space(first)
        self.observation_space = env.observation_space(first)
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self._cache: tuple[int, dict[str, Any]] | None = None

    def _fields(self) -> dict[str, Any]:
        """The env's local-view fields, computed once per env step however many fields a policy reads."""
        version = self._env.state_version
        if self._cache is None or self._cache[0] != version:
            self._cache = (version, self._env.per_robot_view())
        return self._cache[1]

    @property
    def agents(self) -> list[str]:
        """The agents alive now."""
        return list(self._env.agents)

    @property
    def step(self) -> int:
        """The shared step clock: env steps since reset."""
        return self._env.step_count

    def index(self, agent: str) -> int:
        """The robot's own id (its position in ``possible_agents``)."""
        return self._index[agent]

    def team(self, name: str) -> Any:
        """Field ``name`` for every robot at once; row i is what robot i knows."""
        if name not in self.fields:
            raise ValueError(f"unknown local-view field {name!r}; {self._env.ENV_ID} offers: {', '.join(self.fields)}")
        return _read_only(self._fields()[name])

    def __getitem__(self, agent: str) -> Mapping[str, Any]:
        if agent not in self._index:
            raise ValueError(
                f"unknown agent {agent!r}; valid agents are {self.possible_agents[0]} … {self.possible_agents[-1]}"
            )
        i = self._index[agent]
        return MappingProxyType({k: _read_only(np.asarray(v)[i]) for k, v in self._fields().items()})


class Policy:
    """A team policy: ``act`` returns one action per live agent.

    Subclasses declare ``name``, optional ``PARAMS`` (validated keyword parameters), when they read
    more than each robot's own local view ``GLOBAL_KNOWLEDGE``, and when the rule is one the env's paper
    describes ``FROM_PAPER``.
    """

    name: ClassVar[str] = "policy"
    PARAMS: ClassVar[dict[str, Param]] = {}
    #: empty when the policy reads only observations and each robot's own local view; otherwise a sentence
    #: naming the global knowledge it uses (listed in the docs beside the policy)
    GLOBAL_KNOWLEDGE: ClassVar[str] = ""
    #: where the env's paper describes this rule ("Algorithm 1, §3.2"); empty for a rule that is not the paper's
    #: (ours, or a reference such as ``random``). docs/learning.md measures learned policies against the best
    #: rule of each kind, so a rule of ours never passes for the paper's
    FROM_PAPER: ClassVar[str] = ""

    def __init__(self, **params: Any):
        self.params = validate_config(self.PARAMS, params, owner=f"policy '{self.name}'")
        self.rng = np.random.default_rng()

    def reset(self, views: LocalViews, seed: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, observations: dict[str, np.ndarray], views: LocalViews) -> dict[str, Any]:
        raise NotImplementedError(f"{type(self).__name__} must implement act(observations, views)")
