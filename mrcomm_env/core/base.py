"""The parallel environment every mrcomm environment derives from.

It owns what is the same everywhere: argument validation, seeding, agent names, the shared (cached)
spaces, action validation, ``max_cycles`` truncation, infos with identical keys at reset and at every
step, the global ``state()``, the policies' read-only local views, and rendering. A subclass supplies
only its paper's world; see ``docs/architecture.md``.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping
from numbers import Integral
from typing import Any, ClassVar

import numpy as np
from gymnasium import logger, spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from mrcomm_env.core import render as _render
from mrcomm_env.core.config import Config, Param, validate_config
from mrcomm_env.core.memory import BUDGET_ARGUMENT, MEMORY_BUDGET_PARAM, check_memory_budget
from mrcomm_env.core.policy import LocalViews

#: the Python objects of one more copy in a batch, beyond its arrays: at most 64 KiB for every default env (1,024
#: copies of ChannelAssociation-v0 hold 29 MB, of which 14 MB are its filters' arrays; ``mrcomm bench --batched``)
COPY_OVERHEAD_BYTES = 64.0 * 2**10

#: the horizon argument was called ``max_steps`` before PettingZoo's name ``max_cycles`` was adopted
DEPRECATED_HORIZON = "max_steps"

#: info columns ``action_mask_0 … action_mask_{K-1}`` carry each agent's feasible actions (envs with
#: ``action_masks()``): infos stay plain numbers (docs/architecture.md), and every adapter reads the mask from them
MASK_INFO_PREFIX = "action_mask_"


def mask_info_keys(info_keys) -> list[str]:
    """The info columns holding action masks, in action order (``action_mask_0``, ``action_mask_1``, …)."""
    keys = [k for k in info_keys if k.startswith(MASK_INFO_PREFIX) and k[len(MASK_INFO_PREFIX) :].isdigit()]
    return sorted(keys, key=lambda k: int(k[len(MASK_INFO_PREFIX) :]))


class EnvSpec:
    """What an environment declares, apart from its behaviour: its arguments, metrics, infos and local view, its
    documented configurations and limits, its memory model and which configurations step as a copy-axis world.
    Each env keeps its own in ``<env>/spec.py`` as a subclass of this, which the env class inherits before
    :class:`MrcommParallelEnv`; ``mrcomm docs`` and the conformance checks read them through the env class."""

    PARAMS: ClassVar[dict[str, Param]] = {}
    METRICS: ClassVar[dict[str, str]] = {}
    #: metrics that are a time until something happens, reported as −1 or NaN while it has not: an evaluation
    #: that averages episodes counts such an episode at its length (the comparisons' "unfinished" value)
    UNREACHED_TIMES: ClassVar[tuple[str, ...]] = ()
    INFO_KEYS: ClassVar[dict[str, str]] = {}
    #: per-robot knowledge a policy may read through ``local_views()``: field name → description. Row i of
    #: every field returned by ``_local_view()`` is what robot i itself knows.
    LOCAL_VIEW: ClassVar[dict[str, str]] = {}
    DOCUMENTED_CONFIGS: ClassVar[dict[str, dict[str, Any]]] = {"default": {}}
    #: configurations at the documented maxima of ``PARAMS`` (run by ``tests/core/test_limits.py`` and measured by
    #: ``mrcomm bench --limits``): every range is a promise
    LIMIT_CONFIGS: ClassVar[dict[str, dict[str, Any]]] = {}
    VERSION_HISTORY: ClassVar[list[tuple[str, str]]] = []
    #: the peak-memory estimate of :meth:`memory_estimate` written out for the env page (names are arguments)
    MEMORY_FORMULA: ClassVar[str] = ""
    #: the arguments the estimate grows with: the ones a refusal names
    MEMORY_ARGS: ClassVar[tuple[str, ...]] = ()
    #: the constant part of :meth:`memory_estimate` (bytes): a step's working memory and the like, which the copies of
    #: a batch, stepped in turn, need once (:meth:`batch_memory_estimate`)
    MEMORY_SHARED: ClassVar[float] = 0.0
    #: three configurations of growing size at which ``tests/core/test_memory.py`` measures the peak against the
    #: estimate (each must need well above the interpreter's noise, tens of MB, and fit the default budget)
    MEMORY_PROBES: ClassVar[dict[str, dict[str, Any]]] = {}

    @classmethod
    def memory_estimate(cls, cfg: Config) -> float:
        """Estimated peak memory in bytes of one instance with the validated arguments ``cfg``: construction, reset
        and steps, the interpreter excluded (``MEMORY_FORMULA`` says it in words). Construction refuses arguments
        whose estimate is over ``memory_budget_gib``. Must not fail on any valid ``cfg`` (compute in floats)."""
        raise NotImplementedError(f"{cls.__name__} must state its peak memory (memory_estimate, MEMORY_FORMULA)")

    @classmethod
    def batch_memory_estimate(cls, cfg: Config, n_copies: int) -> float:
        """Estimated peak memory in bytes of ``n_copies`` instances stepped in turn (a ``BatchedEnv``): one instance,
        plus for every further copy its own state (the estimate without ``MEMORY_SHARED``) and the Python objects of
        an instance (:data:`COPY_OVERHEAD_BYTES`, measured)."""
        one = float(cls.memory_estimate(cfg))
        return one + (n_copies - 1) * (max(one - cls.MEMORY_SHARED, 0.0) + COPY_OVERHEAD_BYTES)

    @classmethod
    def copy_axis_world(cls, cfg: Config) -> Callable[[list[Any]], Any] | None:
        """The class that steps M copies with these arguments as arrays with a leading copy axis, or None (a
        :class:`~mrcomm_env.core.batched.BatchedEnv` then steps the copies in turn). It is built from the M reset
        env copies and has ``adopt(i)`` (take copy i's freshly reset episode), ``store(i)`` (write copy i's state
        back into its env), ``step(actions)`` (``step_arrays`` of every copy, without resets) and ``bits_sent()``;
        optionally ``reset_copies(copies)`` and ``final_metrics(copies)``, to begin ended copies' next episodes and
        compute the ended ones' metrics without the env objects."""
        return None


class MrcommParallelEnv(EnvSpec, ParallelEnv):
    ENV_ID: ClassVar[str] = ""
    DESCRIPTION: ClassVar[str] = ""
    #: what one env step stands for in the paper's own time unit, for the benchmark: an env whose step is a
    #: whole TDMA frame sets ("slot", True) so that speed is also reported per slot (N slots per step)
    STEP_UNIT: ClassVar[tuple[str, bool]] = ("step", False)
    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array", "human"], "render_fps": 10}
    # set by _setup()
    n_agents: int
    #: every env accounts its bits in one BitLedger (set by _reset_world)
    ledger: Any
    _obs_space: spaces.Space
    _act_space: spaces.Space
    # the info columns of the last _agent_infos() object, as float64 arrays and (lazily) as per-agent rows
    _info_arrays: tuple[list[str], list[np.ndarray]]
    _info_rows: list[tuple[float, ...]] | None

    def __init_subclass__(cls, **kwargs: Any):
        super().__init_subclass__(**kwargs)
        # every environment takes the memory budget (core/memory.py), declared once here; PARAMS may come from a
        # spec class the env inherits (``<env>/spec.py``), so it is read through the class, not its own __dict__
        if BUDGET_ARGUMENT not in cls.PARAMS:
            cls.PARAMS = {**cls.PARAMS, BUDGET_ARGUMENT: MEMORY_BUDGET_PARAM}

    def __init__(self, render_mode: str | None = None, **kwargs: Any):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"argument 'render_mode' must be one of {self.metadata['render_modes']} or None, got {render_mode!r}"
            )
        self.render_mode = render_mode
        if DEPRECATED_HORIZON in kwargs:
            if "max_cycles" in kwargs:
                raise ValueError(f"pass the horizon as 'max_cycles' only ('{DEPRECATED_HORIZON}' is its old name)")
            warnings.warn(
                f"argument '{DEPRECATED_HORIZON}' is deprecated; use 'max_cycles' (PettingZoo's name)",
                DeprecationWarning,
                stacklevel=2,
            )
            kwargs["max_cycles"] = kwargs.pop(DEPRECATED_HORIZON)
        owner = self.ENV_ID or type(self).__name__
        self.cfg: Config = validate_config(self.PARAMS, kwargs, owner=owner)
        check_memory_budget(owner, self.memory_estimate(self.cfg), self.cfg, self.MEMORY_ARGS)
        self._setup()
        self.possible_agents = [f"robot_{i}" for i in range(self.n_agents)]
        self.agents: list[str] = []
        self._agent_index = {a: i for i, a in enumerate(self.possible_agents)}
        self.np_random, self.np_random_seed = seeding.np_random(None)
        self.step_count = 0
        self._state_version = 0  # bumped by every reset and step: what a policy's local view caches on
        self._figure = None
        self._check_action = _action_checker(self._act_space)

    # ----------------------------------------------------------------- subclass interface
    def _setup(self) -> None:
        raise NotImplementedError

    def _reset_world(self) -> None:
        raise NotImplementedError

    def _step_world(self, actions) -> float | np.ndarray:
        """``actions``: a list of ints (Discrete) or an ``(N, *shape)`` array (Box), in agent order."""
        raise NotImplementedError

    def _observe(self) -> np.ndarray:
        raise NotImplementedError

    def _agent_infos(self) -> dict[str, Any]:
        """Info key → N numbers. Returning the very same dict object as at the previous call says that nothing
        in it changed: the per-agent rows are then reused instead of converted again."""
        raise NotImplementedError

    def _terminated(self) -> bool:
        return False

    def _local_view(self) -> dict[str, Any]:
        """Field → array whose row i is what robot i knows (keys as in ``LOCAL_VIEW``)."""
        return {}

    def observation_layout(self) -> dict[str, int] | None:
        """For observations that list candidates: ``{"candidates": K, "features": F, "globals": G,
        "extra_actions": E}`` (K blocks of F features, then G of the robot itself; E actions beyond one per
        candidate). None for a flat observation. Learned policies may use it to share weights across
        candidates (``agents/policies.py``)."""
        return None

    @classmethod
    def state_is_joint_observation(cls) -> bool:
        """Whether ``state()`` is every robot's observation concatenated in agent order (the default): batched
        trainers and adapters then build the state from the observations they already hold."""
        return cls._state is MrcommParallelEnv._state

    def _state(self) -> np.ndarray:
        """The global state for centralised critics; by default every robot's observation, concatenated."""
        return self._observe().reshape(-1)

    def _metrics(self) -> dict[str, float]:
        raise NotImplementedError

    def _render(self, ax) -> None:
        ax.text(0.5, 0.5, f"{self.ENV_ID}\nstep {self.step_count}", ha="center", va="center")

    def substeps_per_step(self) -> int:
        """How many of ``STEP_UNIT`` one env step holds (1, or N when a step is one slot per agent)."""
        return self.n_agents if self.STEP_UNIT[1] else 1

    # ----------------------------------------------------------------- PettingZoo API
    def observation_space(self, agent: str) -> spaces.Space:
        self._index_of(agent)
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Space:
        self._index_of(agent)
        return self._act_space

    def action_label(self, action) -> str:
        """A short name for what one agent's ``action`` does, for tables of what a policy chose (``mrcomm
        actions``): the index of a discrete action and the number of items a multi-binary one selects, unless the
        env names its actions."""
        space = self._act_space
        if isinstance(space, spaces.Discrete):
            return str(int(action))
        if isinstance(space, spaces.MultiBinary):
            return f"{int(np.count_nonzero(np.asarray(action) > 0.5))} selected"
        return "continuous"

    def action_measures(self, agent: str, action) -> dict[str, np.ndarray]:
        """Numbers that the items of one agent's ``action`` carry in the current state (measure → one value per
        item; bool values are counted as shares), which ``mrcomm actions`` averages over all items a policy chose,
        e.g. the age of each estimate a slot would relay; empty where the env names none. Read between
        ``reset``/``step`` calls, before ``action`` is stepped, so that a rule's action is measured at the same
        state as the policy's."""
        return {}

    def decision_context(self) -> list[str] | None:
        """Each robot's situation now, in a few words, by which ``mrcomm actions`` splits what a policy chose (e.g.
        whether a sync would carry news); None where the env names none. Read between ``reset``/``step`` calls."""
        return None

    @property
    def state_space(self) -> spaces.Space:
        space = self.__dict__.get("_state_space")
        if space is None:
            obs = self._obs_space
            space = self._state_space = spaces.Box(
                np.repeat(obs.low[None], self.n_agents, 0).ravel(),
                np.repeat(obs.high[None], self.n_agents, 0).ravel(),
                dtype=obs.dtype,
            )
        return space

    def state(self) -> np.ndarray:
        """The global state (``state_space``), as PettingZoo's ``state()`` for MAPPO-style centralised critics."""
        self._require_reset("state")
        return np.asarray(self._state(), dtype=self.state_space.dtype)

    def metrics(self) -> dict[str, float]:
        """The paper's metrics of the episode so far (``METRICS`` says what each means); after ``reset()``."""
        self._require_reset("metrics")
        return self._metrics()

    def counted_time(self, name: str, value: float) -> float:
        """Metric ``name``'s ``value`` as an evaluation averages it over episodes: a time among ``UNREACHED_TIMES``
        that was not reached (−1 or nan) counts as the episode's length, so that never reaching it is neither
        mistaken for reaching it at once nor left out of the average."""
        if name in self.UNREACHED_TIMES and not value >= 0:
            return float(self.step_count)
        return value

    def bits_sent(self) -> float:
        """Bits every robot has sent since ``reset()``, summed (the env's ``BitLedger``; what recordings show)."""
        self._require_reset("bits_sent")
        return float(self.ledger.total_bits.sum())

    def _require_reset(self, method: str) -> None:
        # the world exists only after the first reset: say so, as step() does, instead of an AttributeError
        if self._state_version == 0:
            raise RuntimeError(f"{method}() called before reset(); call reset() first")

    @property
    def state_version(self) -> int:
        """Bumped by every reset and step: a cache of anything computed from the state may key on it."""
        return self._state_version

    def per_robot_view(self) -> dict[str, Any]:
        """What each robot knows locally: ``LOCAL_VIEW`` field → array whose row i is robot i's own knowledge
        (documented on the env's page). Policies read it through :meth:`local_views`."""
        return self._local_view()

    def local_views(self) -> LocalViews:
        """Read-only per-robot knowledge for policies (see ``mrcomm_env.core.policy``)."""
        return LocalViews(self)

    def local_view(self, agent: str):
        """What ``agent``'s own robot knows: a read-only mapping of the ``LOCAL_VIEW`` fields."""
        return self.local_views()[agent]

    def reset(self, seed: int | None = None, options: dict | None = None):
        self._begin_episode(seed)
        if self.render_mode == "human":
            self.render()
        return self._observations(), self._infos()

    def reset_arrays(
        self, seed: int | None = None, options: dict | None = None
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """:meth:`reset` as arrays, the same code without the per-agent dictionaries: the observations
        ``(N, *obs_shape)`` in agent order and the infos as columns, key → ``(N,)`` float64. What
        :class:`~mrcomm_env.core.batched.BatchedEnv` steps."""
        self._begin_episode(seed)
        if self.render_mode == "human":
            self.render()
        return self._observe(), self._info_columns_array()

    def _begin_episode(self, seed: int | None) -> None:
        if seed is not None:
            if isinstance(seed, bool) or not isinstance(seed, Integral) or seed < 0:
                raise ValueError(f"argument 'seed' must be None or an integer ≥ 0, got {seed!r}")
            self.np_random, self.np_random_seed = seeding.np_random(int(seed))
        self.agents = list(self.possible_agents)
        self._state_version += 1
        self._live = dict.fromkeys(self.agents)  # key view compared with each step's actions in C
        self.step_count = 0
        self._reset_world()

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            self._require_reset("step")
            raise RuntimeError("step() called on a finished episode; call reset() first")
        if type(actions) is not dict and not isinstance(actions, Mapping):
            raise ValueError(
                f"argument 'actions' must be a dict keyed by agent ({self.agents[0]} … {self.agents[-1]}), "
                f"got {type(actions).__name__}"
            )
        if actions.keys() != self._live.keys():
            unknown = sorted(set(actions) - set(self.agents))
            missing = sorted(set(self.agents) - set(actions))
            raise ValueError(
                f"argument 'actions' must hold one action for each agent {self.agents[0]} … {self.agents[-1]}; "
                f"unknown: {unknown[:5]}, missing: {missing[:5]}"
            )
        agents = self.agents
        rewards, terminated, truncated = self._advance([actions[agent] for agent in agents])
        observations = self._observations(agents)
        infos = self._infos(agents)
        if isinstance(rewards, (float, int, np.number)):
            reward_dict = dict.fromkeys(agents, float(rewards))
        else:
            reward_dict = dict(zip(agents, np.asarray(rewards, dtype=np.float64).tolist()))
        term_dict = dict.fromkeys(agents, terminated)
        trunc_dict = dict.fromkeys(agents, truncated)
        if self.render_mode == "human":  # gymnasium's convention: human mode draws every step by itself
            self.render()
        return observations, reward_dict, term_dict, trunc_dict, infos

    def step_arrays(self, actions) -> tuple[np.ndarray, np.ndarray, bool, bool, dict[str, np.ndarray]]:
        """:meth:`step` as arrays, the same code without the per-agent dictionaries.

        ``actions``: one action per agent in agent order (a sequence, or an array whose first axis is the
        agent). Returns the observations ``(N, *obs_shape)``, the rewards ``(N,)`` float64, ``terminated``,
        ``truncated`` (as :meth:`step` reports them for every agent: all agents end together) and the infos as
        columns, key → ``(N,)`` float64. Bad actions raise the same ``ValueError`` as :meth:`step`.
        """
        observations, reward_array, terminated, truncated = self.step_arrays_without_infos(actions)
        return observations, reward_array, terminated, truncated, self._info_columns_array()

    def step_arrays_without_infos(self, actions) -> tuple[np.ndarray, np.ndarray, bool, bool]:
        """:meth:`step_arrays` without the infos, which the caller reads with ``info_columns()`` (a batch copies
        them straight into its own columns)."""
        if not self.agents:
            self._require_reset("step_arrays")
            raise RuntimeError("step_arrays() called on a finished episode; call reset_arrays() first")
        if isinstance(actions, np.ndarray):
            if actions.shape[:1] != (self.n_agents,):
                raise ValueError(
                    f"argument 'actions' must hold one action per agent ({self.n_agents}) in agent order, "
                    f"got shape {actions.shape}"
                )
            # plain ints for a Discrete space: the action checker's fast path, as step() receives them
            actions = actions.tolist() if isinstance(self._act_space, spaces.Discrete) else list(actions)
        elif len(actions) != self.n_agents:
            raise ValueError(
                f"argument 'actions' must hold one action per agent ({self.n_agents}) in agent order, "
                f"got {len(actions)}"
            )
        rewards, terminated, truncated = self._advance(list(actions))
        if isinstance(rewards, (float, int, np.number)):
            reward_array = np.full(self.n_agents, float(rewards))
        else:
            reward_array = np.array(rewards, dtype=np.float64)
        observations = self._observe()
        if self.render_mode == "human":
            self.render()
        return observations, reward_array, terminated, truncated

    def _advance(self, actions: list) -> tuple[Any, bool, bool]:
        """One step of the world on validated ``actions`` (agent order): the world's rewards, ``terminated``
        and ``truncated`` (never both: termination wins). Ends the episode (``agents`` empty) when either."""
        acts = self._check_action(self.agents, actions)
        rewards = self._step_world(acts)
        self._state_version += 1
        self.step_count += 1
        truncated = self.step_count >= self.cfg["max_cycles"]
        terminated = bool(self._terminated())
        if terminated or truncated:
            self.agents = []
        return rewards, terminated, truncated and not terminated

    def render(self):
        if self.render_mode is None:
            logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None

        if self.render_mode == "rgb_array":
            return self.rgb_frame()
        if not _render.has_display():
            _render.warn_no_display()
            return None
        self._figure = _render.show_human(self._render, self._figure, self.metadata.get("render_fps", 10))
        return None

    def rgb_frame(self) -> np.ndarray:
        """The frame ``render()`` returns in ``rgb_array`` mode, ``(H, W, 3)`` uint8, whatever ``render_mode`` is:
        a batch of copies built without rendering draws one of them with it (``BatchedEnv.render_copy``)."""
        return _render.to_rgb_array(self._render)

    def close(self) -> None:
        if self._figure is not None:
            _render.close(self._figure)
            self._figure = None

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_figure"] = None
        state["_check_action"] = None
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._check_action = _action_checker(self._act_space)

    # ----------------------------------------------------------------- helpers
    def _index_of(self, agent: str) -> int:
        try:
            return self._agent_index[agent]
        except (KeyError, TypeError):
            raise ValueError(f"unknown agent {agent!r}; valid agents are robot_0 … robot_{self.n_agents - 1}") from None

    def _observations(self, agents: list[str] | None = None) -> dict[str, np.ndarray]:
        obs = self._observe()
        return dict(zip(self.agents if agents is None else agents, obs))

    def info_columns(self) -> tuple[list[str], list[np.ndarray]]:
        """The info keys and their float64 columns (N,), converted once per new ``_agent_infos()`` object. The
        columns are the env's own, valid until its next step: a batch copies them into its (M, N) columns."""
        columns = self._agent_infos()
        # the last columns are kept referenced, so an unchanged object (see _agent_infos) is the same one
        if columns is not self.__dict__.get("_info_source"):
            keys = list(columns)
            arrays = [np.asarray(columns[k], dtype=np.float64) for k in keys]
            self._info_source, self._info_arrays, self._info_rows = columns, (keys, arrays), None
        return self._info_arrays

    def _info_columns_array(self) -> dict[str, np.ndarray]:
        keys, arrays = self.info_columns()
        return {key: column.copy() for key, column in zip(keys, arrays)}

    def _infos(self, agents: list[str] | None = None) -> dict[str, dict[str, float]]:
        keys, arrays = self.info_columns()
        if self._info_rows is None:
            self._info_rows = list(zip(*[column.tolist() for column in arrays]))
        # fresh dicts every step: wrappers (SB3's VecEnv, SuperSuit) add keys to the infos they receive
        return {a: dict(zip(keys, row)) for a, row in zip(self.agents if agents is None else agents, self._info_rows)}


def _is_int_action(action: Any) -> bool:
    """gymnasium's ``Discrete.contains`` rule: a Python int or a numpy integer scalar; not a float like 1.0."""
    if isinstance(action, int):
        return True
    return isinstance(action, (np.generic, np.ndarray)) and action.shape == () and action.dtype.kind in "iu"


def _action_checker(space: spaces.Space):
    """A validator for all agents' actions at once; raises ``ValueError`` naming the agent and the allowed set.

    Checks are vectorised over agents (a per-agent check cost a third of a 100-robot step); only when the
    batch fails is each agent checked alone, so the error names the right one.
    """
    if isinstance(space, spaces.Discrete):
        return _discrete_checker(space)
    if isinstance(space, spaces.Box):
        return _box_checker(space)
    if isinstance(space, spaces.MultiBinary):
        return _multibinary_checker(space)

    def check(agents, actions):
        for agent, action in zip(agents, actions):
            if not space.contains(action):
                raise ValueError(f"action of {agent} must lie in {space}, got {action!r}")
        return list(actions)

    return check


def _discrete_checker(space: spaces.Discrete):
    lo, n = int(space.start), int(space.n)

    def fail(agent, action):
        raise ValueError(f"action of {agent} must be an integer in [{lo}, {lo + n - 1}], got {action!r}")

    def check(agents, actions):
        if all(type(a) is int for a in actions) and lo <= min(actions) and max(actions) < lo + n:
            return actions  # plain ints, the common case: no numpy round trip
        for agent, action in zip(agents, actions):
            if not _is_int_action(action) or not lo <= int(action) < lo + n:
                fail(agent, action)
        return [int(a) for a in actions]

    return check


def _box_checker(space: spaces.Box):
    low, high, shape = space.low, space.high, space.shape

    def check_one(agent, action):
        raw = np.asarray(action) if not isinstance(action, (str, bytes)) else None
        if raw is None or raw.dtype.kind not in "iuf" or raw.shape != shape:
            what = "not a real array" if raw is None or raw.dtype.kind not in "iuf" else f"shape {raw.shape}"
            raise ValueError(f"action of {agent} must be a real array of shape {shape} ({what}), got {action!r}")
        arr = raw.astype(space.dtype)
        if not (np.isfinite(arr) & (arr >= low) & (arr <= high)).all():
            raise ValueError(
                f"action of {agent} must be finite and within [{float(np.min(low)):g}, {float(np.max(high)):g}], "
                f"got {action!r}"
            )

    def check(agents, actions):
        try:
            raw = np.asarray(actions)
        except ValueError:  # ragged: numpy cannot stack it; find the agent below
            raw = None
        if raw is not None and raw.dtype.kind in "iuf" and raw.shape == (len(agents), *shape):
            arr = raw.astype(space.dtype, copy=False)
            if (np.isfinite(arr) & (arr >= low) & (arr <= high)).all():
                return arr
        for agent, action in zip(agents, actions):
            check_one(agent, action)
        raise AssertionError("unreachable: a batch that fails has a failing agent")  # pragma: no cover

    return check


def _multibinary_checker(space: spaces.MultiBinary):
    shape = space.shape

    def check_bits(agent, action):
        raw = np.asarray(action) if not isinstance(action, (str, bytes)) else None
        if raw is None or raw.dtype.kind not in "iubf" or raw.shape != shape or not np.isin(raw, (0, 1)).all():
            raise ValueError(f"action of {agent} must be an array of 0s and 1s of shape {shape}, got {action!r}")

    def check(agents, actions):
        try:
            raw = np.asarray(actions)
        except ValueError:  # ragged
            raw = None
        # gymnasium's MultiBinary.contains takes any real array of exact 0s and 1s (SB3 sends float32)
        if raw is not None and raw.dtype.kind in "iubf" and raw.shape == (len(agents), *shape):
            if ((raw == 0) | (raw == 1)).all():
                return raw.astype(np.int8, copy=False)
        for agent, action in zip(agents, actions):
            check_bits(agent, action)
        raise AssertionError("unreachable: a batch that fails has a failing agent")  # pragma: no cover

    return check
