"""M copies of one environment stepped as arrays with a leading copy axis (``BatchedEnv``).

A batch of M copies of an N-agent env takes actions ``(M, N, *action_shape)`` and returns observations
``(M, N, *obs_shape)``, rewards ``(M, N)``, ``terminated`` and ``truncated`` ``(M,)`` (all agents of a copy
end together in every mrcomm env) and the infos as columns, key → ``(M, N)`` float64. It is what the
training VecEnv (``agents/vecenv.py``) and ``mrcomm bench --batched`` step.

**Episodes.** A copy whose episode ends resets on its own in the same call, as SB3's VecEnvs do: the
returned observations of that copy are the first of its next episode, while ``final_observations[i]`` holds
the observation its last step returned, ``final_metrics[i]`` the metrics of the episode that ended and
``reset_infos[i]`` the info columns of the new episode. ``truncated`` is never set together with
``terminated`` (the time limit only counts when the episode did not end by itself), so
``TimeLimit.truncated`` is ``truncated`` as it stands.

**Seeds.** ``reset(seed=s)`` seeds copy i with ``s + i`` (SB3's convention; a sequence gives one seed per
copy); an automatic reset continues the copy's own random stream. Copy i of a batch seeded s is therefore
the single env seeded ``s + i``, episode after episode, byte for byte (``tests/core/test_batched.py``).

**Two ways to step.** By default each copy runs the env's own ``reset_arrays``/``step_arrays``, which are
its ``reset``/``step`` without the per-agent dictionaries: M Python objects stepped in turn. An env class
whose world is also written with a copy axis says so with ``copy_axis_world(cfg)`` (ChannelAssociation's
scenes on bit sets, ``channel_association/copy_axis.py``; MultiHop's grids and fields, ``multihop/copy_axis.py``;
MapSync's links without a bit budget, ``mapsync/copy_axis.py``); the batch then steps all copies as arrays and uses
the env objects only to reset a copy (its own ``reset_arrays``, from its own generator) and to read a copy's
metrics (the world writes the copy's state back first: :meth:`BatchedEnv.sync_copies`); a world with
``reset_copies(copies)`` begins ended copies' next episodes itself, with the env's draws, and one with
``final_metrics(copies)`` computes the env's metrics of ended episodes on its rows (ChannelAssociation's
neighbourhoods and fields: where nothing moves, their episodes end every few steps). Both ways give the same
numbers; the tests compare each copy with the single env over whole episodes.

**Memory.** The batch refuses at construction, naming ``n_copies``, a batch whose copies together need
more than the env's memory budget by its own estimate (``batch_memory_estimate``: one env's peak, plus each
further copy's own state; the working memory of a step is needed once, as the copies step in turn).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from numbers import Integral
from typing import Any

import numpy as np
from gymnasium import spaces

from mrcomm_env.core.base import MrcommParallelEnv
from mrcomm_env.core.memory import BUDGET_ARGUMENT, GIB


@dataclass
class BatchStep:
    """What one :meth:`BatchedEnv.step` returns (arrays have a leading copy axis of length M)."""

    #: ``(M, N, *obs_shape)``: what each agent acts on next (a copy that ended: its next episode's first)
    observations: np.ndarray
    #: ``(M, N)`` float64
    rewards: np.ndarray
    #: ``(M,)`` bool: the copy's episode ended by itself
    terminated: np.ndarray
    #: ``(M,)`` bool: the copy's episode hit ``max_cycles`` without ending by itself
    truncated: np.ndarray
    #: key → ``(M, N)`` float64: this step's infos (a copy that ended: its final step's)
    infos: dict[str, np.ndarray]
    #: copy index → ``(N, *obs_shape)``: the observation the final step of an episode that ended returned
    final_observations: dict[int, np.ndarray] = field(default_factory=dict)
    #: copy index → the ended episode's metrics (``env.metrics()`` before the automatic reset)
    final_metrics: dict[int, dict[str, float]] = field(default_factory=dict)
    #: copy index → key → ``(N,)``: the reset infos of the episode that began in place of the ended one
    reset_infos: dict[int, dict[str, np.ndarray]] = field(default_factory=dict)

    @property
    def ended(self) -> np.ndarray:
        """``(M,)`` bool: copies whose episode ended at this step (and were reset)."""
        return self.terminated | self.truncated


class BatchedEnv:
    """M copies of one mrcomm environment as arrays with a leading copy axis (see the module docstring).

    :param make_copy: returns a new env (a ``MrcommParallelEnv``) per call; every copy has the same arguments.
    :param n_copies: M ≥ 1.
    :param copy_axis: step two or more copies as one array world when the env has one (``copy_axis_world``);
        False steps the env objects in turn (what the benchmarks compare it with).
    :param copy: return the observations as a new array at every reset and step (gymnasium's ``SyncVectorEnv``
        ``copy``); False returns the batch's own buffer, valid until the next ``step`` or ``reset``, which saves
        copying it (a thousand 100-robot MultiHop copies observe 200 MB per step) for a caller that copies what it
        keeps anyway, as the training VecEnv does.
    :raises ValueError: ``n_copies`` not a positive integer, a constructor that returns one instance twice or
        an env of another kind, or copies that together need more memory than the budget.
    """

    def __init__(
        self, make_copy: Callable[[], MrcommParallelEnv], n_copies: int, copy_axis: bool = True, copy: bool = True
    ):
        if isinstance(n_copies, bool) or not isinstance(n_copies, Integral) or n_copies < 1:
            raise ValueError(f"argument 'n_copies' must be an integer ≥ 1, got {n_copies!r}")
        first = make_copy()
        if not isinstance(first, MrcommParallelEnv):
            raise ValueError(
                f"argument 'make_copy' must build an mrcomm environment (MrcommParallelEnv), got {type(first).__name__}"
            )
        _check_batch_memory(first, int(n_copies))
        self._adopt([first] + [make_copy() for _ in range(int(n_copies) - 1)], copy_axis, copy)

    @classmethod
    def of(cls, envs: Sequence[Any], argument: str = "envs", copy_axis: bool = True, copy: bool = True) -> BatchedEnv:
        """A batch of envs built elsewhere (the training VecEnv's copies), which must be :func:`copies_of_one_env`;
        a refusal over the memory budget names ``argument``."""
        if not copies_of_one_env(envs):
            raise ValueError(
                f"argument '{argument}' must hold copies of one mrcomm environment: the same class and arguments"
            )
        _check_batch_memory(envs[0], len(envs), argument)
        batch = cls.__new__(cls)
        batch._adopt(list(envs), copy_axis, copy)
        return batch

    @staticmethod
    def check_memory(env: MrcommParallelEnv, n_copies: int, argument: str = "n_copies") -> None:
        """Refuse, naming ``argument``, ``n_copies`` copies of ``env`` that together need more than its memory budget
        (what the constructor checks; callers that build a batch later check before any work)."""
        _check_batch_memory(env, int(n_copies), argument)

    def _adopt(self, envs: list[MrcommParallelEnv], copy_axis: bool, copy: bool) -> None:
        first = envs[0]
        self.copy = bool(copy)
        self.envs: list[MrcommParallelEnv] = envs
        if len({id(env) for env in self.envs}) != len(self.envs):
            raise ValueError("argument 'make_copy' must build a new environment per call; it returned one twice")
        self.n_copies = len(self.envs)
        self.n_agents = first.n_agents
        self.possible_agents = list(first.possible_agents)
        #: every agent's spaces (the same for all: parameter sharing)
        self.observation_space: spaces.Space = first.observation_space(self.possible_agents[0])
        self.action_space: spaces.Space = first.action_space(self.possible_agents[0])
        self._action_shape = (self.n_copies, self.n_agents, *(self.action_space.shape or ()))
        self._observations: np.ndarray | None = None
        # one copy steps its env object: a world of one copy pays its array set-up for nothing (½ the speed)
        use_world = copy_axis and self.n_copies > 1 and first.render_mode is None
        world = type(first).copy_axis_world(first.cfg) if use_world else None
        #: the copy-axis world stepping every copy at once, or None (the copies step in turn)
        self.world: Any = world(self.envs) if world is not None else None

    # ----------------------------------------------------------------- reset and step
    def reset(
        self, seed: int | Sequence[int | None] | None = None, options: dict | Sequence[dict | None] | None = None
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Reset every copy: observations ``(M, N, *obs_shape)`` and info columns key → ``(M, N)``.

        ``seed``: None (each copy continues its stream), s (copy i gets s + i) or one seed (or None) per copy.
        ``options``: one dict for every copy or one per copy.
        """
        seeds = copy_seeds(seed, self.n_copies)
        per_copy_options = copy_options(options, self.n_copies)
        observations, infos = [], []
        for env, copy_seed, options_of_copy in zip(self.envs, seeds, per_copy_options):
            obs, info = env.reset_arrays(seed=copy_seed, options=options_of_copy)
            observations.append(obs)
            infos.append(info)
        if self.world is not None:
            for i in range(self.n_copies):
                self.world.adopt(i)
        self._observations = np.stack(observations)
        return self._returned(self._observations), _stack_columns(infos)

    def step(self, actions: np.ndarray) -> BatchStep:
        """Step every copy with ``actions`` ``(M, N, *action_shape)``; copies that end are reset (see BatchStep)."""
        return self._step_copies(checked_actions(actions, self._action_shape, self._observations is not None))

    def _step_copies(self, actions: np.ndarray) -> BatchStep:
        if self.world is not None:
            return self._step_world(actions)
        m = self.n_copies
        observations = self._observations
        assert observations is not None
        rewards = np.empty((m, self.n_agents), dtype=np.float64)
        terminated = np.zeros(m, dtype=bool)
        truncated = np.zeros(m, dtype=bool)
        infos: dict[str, np.ndarray] = {}
        result = BatchStep(observations, rewards, terminated, truncated, infos)
        for i, env in enumerate(self.envs):
            obs, rewards[i], terminated[i], truncated[i] = env.step_arrays_without_infos(actions[i])
            # step_arrays's info columns, copied straight into the batch's (M, N) columns (every copy has the
            # same keys): no per-copy copies to stack afterwards
            keys, columns = env.info_columns()
            if not infos:
                infos.update((key, np.empty((m, self.n_agents))) for key in keys)
            for key, column in zip(keys, columns):
                infos[key][i] = column
            if terminated[i] or truncated[i]:
                result.final_observations[i] = obs.copy()  # the env may reuse its buffer at reset
                result.final_metrics[i] = env.metrics()
                obs, result.reset_infos[i] = env.reset_arrays()
            observations[i] = obs
        result.observations = self._returned(observations)
        return result

    def _step_world(self, actions: np.ndarray) -> BatchStep:
        world = self.world
        observations, rewards, terminated, truncated, infos = world.step(actions)
        result = BatchStep(observations, rewards, terminated, truncated, infos)
        ended = np.flatnonzero(terminated | truncated).tolist()
        for i in ended:
            result.final_observations[i] = observations[i].copy()
        final_metrics = getattr(world, "final_metrics", None)
        if ended and final_metrics is not None:  # the env's metrics, computed on the world's rows
            result.final_metrics.update(zip(ended, final_metrics(ended)))
        else:
            for i in ended:
                world.store(i)  # the env holds the ended episode: its metrics are the env's own
                result.final_metrics[i] = self.envs[i].metrics()
        reset_copies = getattr(world, "reset_copies", None)
        if ended and reset_copies is not None:  # the world begins the next episodes itself, as the envs would
            fresh, reset_infos = reset_copies(ended)
            observations[ended] = fresh[ended]
            result.reset_infos.update(zip(ended, reset_infos))
        else:
            for i in ended:
                observations[i], result.reset_infos[i] = self.envs[i].reset_arrays()
                world.adopt(i)
        self._observations = observations
        result.observations = self._returned(observations)
        return result

    def _returned(self, observations: np.ndarray) -> np.ndarray:
        return observations.copy() if self.copy else observations

    def restart(self, copies: Sequence[int]) -> dict[int, dict[str, np.ndarray]]:
        """Begin a new episode of each copy in ``copies`` only, each continuing its own random stream (what an
        automatic reset does), while the other copies keep theirs: copy index → the new episode's info columns
        (key → ``(N,)``). Their first observations are in :attr:`observations`."""
        if self._observations is None:
            raise RuntimeError("restart() called before reset(); call reset() first")
        reset_infos = {}
        for i in copies:
            if self.world is not None:
                self.world.store(i)  # the env object takes the copy's state, its generator's included, from the world
            self._observations[i], reset_infos[i] = self.envs[i].reset_arrays()
            if self.world is not None:
                self.world.adopt(i)
        return reset_infos

    @property
    def observations(self) -> np.ndarray:
        """``(M, N, *obs_shape)``: what every agent of every copy acts on next (the batch's own buffer: read it, or copy
        what you keep; the next ``step``, ``reset`` or ``restart`` overwrites it)."""
        if self._observations is None:
            raise RuntimeError("observations read before reset(); call reset() first")
        return self._observations

    def render_copy(self, index: int = 0) -> np.ndarray:
        """Copy ``index`` drawn as ``render()`` draws in ``rgb_array`` mode (``(H, W, 3)`` uint8): a batch builds its
        copies without rendering, so that every copy steps in the copy-axis world."""
        self.sync_copies([index])
        return self.envs[index].rgb_frame()

    # ----------------------------------------------------------------- the env objects of a copy-axis world
    def sync_copies(self, indices: Sequence[int] | None = None) -> None:
        """Write the copy-axis world's state into the env objects (before reading them: attributes, rendering,
        local views), of every copy or of the copies ``indices``. Without a world the env objects are the state,
        and this does nothing."""
        if self.world is not None and self._observations is not None:
            for i in range(self.n_copies) if indices is None else indices:
                self.world.store(i)

    def reload_copies(self) -> None:
        """Take the env objects' state back into the copy-axis world (after changing them from outside: an
        ``env_method`` or ``set_attr`` of the training VecEnv). Without a world this does nothing."""
        if self.world is not None and self._observations is not None:
            for i in range(self.n_copies):
                self.world.adopt(i)

    # ----------------------------------------------------------------- per-copy readings
    def bits_sent(self) -> np.ndarray:
        """``(M,)``: bits every robot of each copy has sent since the copy's last reset, summed."""
        if self.world is not None and self._observations is not None:
            return np.asarray(self.world.bits_sent(), dtype=np.float64)
        return np.array([env.bits_sent() for env in self.envs], dtype=np.float64)

    def metrics(self) -> list[dict[str, float]]:
        """Each copy's metrics of its current episode so far."""
        self.sync_copies()
        return [env.metrics() for env in self.envs]

    def close(self) -> None:
        for env in self.envs:
            env.close()


def copy_seeds(seed: int | Sequence[int | None] | None, n_copies: int) -> list[int | None]:
    """``reset``'s ``seed`` as one seed per copy: None for each (every copy continues its stream), s + i for copy i
    of an integer s, or the sequence itself (one per copy)."""
    if seed is None:
        return [None] * n_copies
    if isinstance(seed, Integral) and not isinstance(seed, bool):
        if seed < 0:
            raise ValueError(f"argument 'seed' must be None, an integer ≥ 0 or one per copy, got {seed!r}")
        return [int(seed) + i for i in range(n_copies)]
    seeds = list(seed)  # type: ignore[arg-type]
    if len(seeds) != n_copies:
        raise ValueError(f"argument 'seed' must hold one seed per copy ({n_copies}), got {len(seeds)}")
    return seeds


def copy_options(options: dict | Sequence[dict | None] | None, n_copies: int) -> list[dict | None]:
    """``reset``'s ``options`` as one dict (or None) per copy."""
    if options is None or isinstance(options, dict):
        return [options] * n_copies
    per_copy = list(options)
    if len(per_copy) != n_copies:
        raise ValueError(f"argument 'options' must be a dict or one dict per copy ({n_copies}), got {len(per_copy)}")
    return per_copy


def checked_actions(actions: Any, shape: tuple[int, ...], started: bool) -> np.ndarray:
    """``actions`` as an array of ``shape`` (copies, agents, *action shape), after a reset (``started``)."""
    if not started:
        raise RuntimeError("step() called before reset(); call reset() first")
    actions = np.asarray(actions)
    if actions.shape != shape:
        raise ValueError(
            f"argument 'actions' must have shape (copies, agents, *action shape) = {shape}, got {actions.shape}"
        )
    return actions


def sample_actions(space: spaces.Space, rng: np.random.Generator, leading: tuple[int, ...]) -> np.ndarray:
    """Uniformly random actions of ``space`` with the leading shape ``leading`` (e.g. ``(M, N)``), drawn from
    ``rng`` in one call: what the benchmarks and tests step a batch with."""
    if isinstance(space, spaces.Discrete):
        return rng.integers(int(space.start), int(space.start) + int(space.n), size=leading)
    if isinstance(space, spaces.MultiBinary):
        return rng.integers(0, 2, size=(*leading, *space.shape), dtype=np.int8)
    if isinstance(space, spaces.MultiDiscrete):
        return rng.integers(0, space.nvec, size=(*leading, *space.shape))
    if isinstance(space, spaces.Box) and space.is_bounded():
        return rng.uniform(space.low, space.high, size=(*leading, *space.shape)).astype(space.dtype)
    raise ValueError(f"argument 'space' must be Discrete, MultiBinary, MultiDiscrete or a bounded Box, got {space}")


def copies_of_one_env(envs: Sequence[Any]) -> bool:
    """Whether ``envs`` are unwrapped mrcomm envs of one class with the same arguments (what a batch steps)."""
    return (
        len(envs) > 0
        and isinstance(envs[0], MrcommParallelEnv)
        and all(type(env) is type(envs[0]) and env.cfg == envs[0].cfg for env in envs)
    )


def _stack_columns(per_copy: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Info columns of every copy (key → (N,), each a fresh array) as key → (M, N): every copy has the same keys."""
    if len(per_copy) == 1:  # one copy: its fresh columns, viewed with a copy axis
        return {key: column[None] for key, column in per_copy[0].items()}
    return {key: np.stack([columns[key] for columns in per_copy]) for key in per_copy[0]}


def _check_batch_memory(env: MrcommParallelEnv, n_copies: int, argument: str = "n_copies") -> None:
    """Refuse, naming ``argument``, ``n_copies`` copies that together need more than one env's memory budget by the
    env's :meth:`~MrcommParallelEnv.batch_memory_estimate`."""
    budget = float(env.cfg[BUDGET_ARGUMENT])
    need = float(env.batch_memory_estimate(env.cfg, n_copies))
    if need > budget * GIB:
        raise ValueError(
            f"{env.ENV_ID}: argument '{argument}' ({n_copies} copies) needs an estimated {need / GIB:.3g} GiB, over the "
            f"memory budget of {budget:g} GiB; use fewer copies, or raise the budget on purpose with '{BUDGET_ARGUMENT}'"
        )
