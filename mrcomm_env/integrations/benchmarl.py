"""BenchMARL: the task family ``mrcomm`` — one task per registered env, run by ``benchmarl.experiment.Experiment``.

    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models import MlpConfig
    from mrcomm_env.integrations.benchmarl import MrcommTask

    task = MrcommTask.MAPSYNC.get_from_yaml()          # or .get_task({"n_robots": 3, "max_cycles": 100})
    Experiment(task=task, algorithm_config=MappoConfig.get_from_yaml(), model_config=MlpConfig.get_from_yaml(),
               critic_model_config=MlpConfig.get_from_yaml(), seed=0, config=ExperimentConfig.get_from_yaml()).run()

A task's config holds the env's own arguments; the yaml files in ``benchmarl_conf/`` (one per task) give the
defaults. BenchMARL's ``*_n_envs_per_worker`` copies of a task run as one batched TorchRL env
(``torchrl.make_batched_env``, ``batch_size=[n_envs]``), as VMAS tasks do, not as one wrapper per copy in a
``SerialEnv``; ``MrcommSerialClass`` keeps that older path, which ``mrcomm_env.experiments.benchmarl_bench``
times beside the batched one. All robots form one group ``"robot"``; MAPPO's critic reads the env's global
``state()``; the action mask (RendezvousMapping-v0) is handed to BenchMARL, whose policies then sample feasible
actions only.

BenchMARL 1.5 needs torchrl < 0.12: install the ``benchmarl`` extra in its own environment, not beside ``torchrl``.
"""

from __future__ import annotations

from pathlib import Path

from mrcomm_env.integrations import require
from mrcomm_env.integrations.torchrl import make_batched_env, make_env
from mrcomm_env.registry import ENTRIES, canonical_id, make

EXTRA = "benchmarl"
CONF_DIR = Path(__file__).with_name("benchmarl_conf")

_common = require("benchmarl.environments.common", EXTRA)
_spaces = require("gymnasium.spaces", EXTRA)
_specs = require("torchrl.data", EXTRA)


def task_name(env_id: str) -> str:
    """BenchMARL's name of the task for ``env_id``: the env's shim module without its version, upper case."""
    return ENTRIES[env_id].env.rsplit(".", 1)[1].rsplit("_v", 1)[0].upper()


#: task enum name → env id, e.g. ``"MAPSYNC"`` → ``"mrcomm/MapSync-v0"``
ENV_ID_OF_TASK = {task_name(env_id): env_id for env_id in ENTRIES}


class MrcommClass(_common.TaskClass):
    """How BenchMARL builds one of our envs and reads its specs (see ``benchmarl.environments.common``)."""

    def __init__(self, name: str, config: dict | None):
        super().__init__(name, config)

        # build the env once, now: a bad argument fails here with the env's own ValueError, not mid-experiment,
        # and the action space may depend on the config (MultiHop-v0's layout)
        env = make(self.env_id, **self.config)
        self._max_cycles = int(env.cfg["max_cycles"])
        self._action_space = env.action_space(env.possible_agents[0])
        if not isinstance(self._action_space, (_spaces.Discrete, _spaces.Box)):
            raise ValueError(
                f"argument 'config' of task {name}: {self.env_id} then acts in {self._action_space}, but BenchMARL's "
                "algorithms need Discrete or Box actions (see benchmarl_conf/multihop.yaml: layout: absolute)"
            )

    @property
    def env_id(self) -> str:
        return ENV_ID_OF_TASK[self.name]

    def get_env_fun(self, num_envs, continuous_actions, seed, device):
        config = dict(self.config)
        env_id = self.env_id
        # num_envs copies as one env with batch_size=[num_envs]: BenchMARL then steps them in one call (as VMAS);
        # copy i of the seed s is the PettingZoo env seeded s + i
        return lambda: make_batched_env(env_id, num_envs, device=device, seed=seed, **config)

    def supports_continuous_actions(self) -> bool:
        return isinstance(self._action_space, _spaces.Box)

    def supports_discrete_actions(self) -> bool:
        return isinstance(self._action_space, _spaces.Discrete)

    def has_state(self) -> bool:
        return True  # every env has state() and state_space (docs/architecture.md)

    def has_render(self, env) -> bool:
        return True  # copy 0 drawn as an RGB array (the batched env's render()): evaluation videos when asked for

    def max_steps(self, env) -> int:
        return self._max_cycles

    def group_map(self, env):
        return env.group_map

    # BenchMARL reads the specs of one copy: a batched env's without its copy axis (``*_unbatched``, as for VMAS)
    def _group_entries(self, env, keep: str):
        spec = env.full_observation_spec_unbatched.clone()
        for group in self.group_map(env):
            for key in list(spec[group].keys()):
                if key != keep:
                    del spec[group][key]
            if spec[group].is_empty():
                del spec[group]
        if "state" in spec.keys():
            del spec["state"]
        return spec

    def observation_spec(self, env):
        return self._group_entries(env, "observation")

    def info_spec(self, env):
        return self._group_entries(env, "info")

    def action_mask_spec(self, env):
        spec = self._group_entries(env, "action_mask")
        return None if spec.is_empty() else spec

    def state_spec(self, env):
        return _specs.Composite({"state": env.full_observation_spec_unbatched["state"].clone()})

    def action_spec(self, env):
        return env.full_action_spec_unbatched

    @staticmethod
    def env_name() -> str:
        return "mrcomm"


class MrcommSerialClass(MrcommClass):
    """A task whose copies are one TorchRL ``PettingZooWrapper`` each, which BenchMARL runs in a ``SerialEnv``:
    the path before the batched env, kept so that the collection bench can time both with one config."""

    def get_env_fun(self, num_envs, continuous_actions, seed, device):
        config = dict(self.config)
        env_id = self.env_id
        return lambda: make_env(env_id, device=device, seed=seed, render_mode="rgb_array", **config)


class _MrcommTasks(_common.Task):
    """What every mrcomm task can do; the members (one per registered env) are made from the registry below."""

    @staticmethod
    def associated_class():
        return MrcommClass

    def get_from_yaml(self, path: str | None = None):
        # our yaml files live in this package, not in benchmarl/conf/task; an env without one (a newly registered
        # env) runs with its own defaults
        if path is None:
            path = str(CONF_DIR / f"{self.name.lower()}.yaml")
            if not Path(path).exists():
                return self.get_task(config={})
        return super().get_from_yaml(path)

    @classmethod
    def from_env_id(cls, env_id: str) -> _MrcommTasks:
        """``MrcommTask.from_env_id("MapSync-v0")`` → ``MrcommTask.MAPSYNC``; unknown ids raise ``ValueError``."""

        return cls.__members__[task_name(canonical_id(env_id))]


#: The mrcomm tasks, one per registered env (``ENV_ID_OF_TASK``), e.g. ``MrcommTask.MAPSYNC``; configs from
#: ``benchmarl_conf/<task>.yaml``. Derived from the registry, so a newly registered env is a task with no edit here.
MrcommTask = _MrcommTasks(
    "MrcommTask", [(name, None) for name in ENV_ID_OF_TASK], module=__name__, qualname="MrcommTask"
)
