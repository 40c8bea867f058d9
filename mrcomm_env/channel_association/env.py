"""ChannelAssociation-v0: matching wireless IDs to visual IDs (Ivanov & Shell, "Hark! Who goes there?").

| | |
| --- | --- |
| Agents | `neighborhood`: w + 1 (`robot_0` observes, `robot_1 … robot_w` are its neighbours); `field`: `n_robots` |
| Actions | `Discrete(2)`: 1 = emit a message pair (light on + wireless broadcast of the own ID), 0 = stay silent |
| Observations | `Box(0, 1, (2⌈log2 N⌉ + 11,), float32)`: own ID bits rotated left by the clock phase (the first is the bit a blink code sends now), observer flag, step/max_cycles, last 4 emissions (newest first), own i-state: fraction matched, ambiguity (edges − v)/edges, unresolved u/(u+8), new IDs this step n/(n+4); then the clock phase, one-hot of step mod (⌈log2 N⌉ + 1), which a blink code needs |
| Arguments | `scene`, `w`, `v`, `n_robots`, `separation`, `mobile_fraction`, `speed`, `wireless_range`, `visual_range`, `drop_time`, `miss_probability`, `miss_tolerance`, `max_cycles`, `emission_cost` |

Every robot has a global wireless ID (its index) and sees its neighbours only as anonymous blobs to
which it gives its *own* local visual labels. Emitting a message pair — light and wireless at once —
lets observers eliminate impossible (wireless, visual) pairs: an edge of the i-state survives only if
both IDs had the same activity (Algorithm 1). The environment runs each robot's filter
(:mod:`mrcomm_env.channel_association.filters`); the agents only decide *when to emit*. The paper's
decision — a fair coin every step — is the baseline `coin_flip`.

Scenes
* `neighborhood` (§4, Figs 5–9): one observer with `w` wireless and `v` ≤ `w` visual IDs in range, all
  static, neighbourhood size known (the i-state starts as the all-ones w×v matrix). The episode
  terminates when the i-state is final (only true edges remain, `completion_time`).
* `field` (§5): stationary robots on a grid with spacing `separation`, each perturbed uniformly within
  half a spacing; a fraction `mobile_fraction` starts at uniform positions with uniform headings and
  moves at `speed`, bouncing off the boundary. Links are disks of radius `wireless_range` and
  `visual_range`. With no mobile robot the scene is stationary (Algorithm 1 with known neighbourhoods,
  terminates when every observer is final). With mobile robots every robot runs Algorithm 2's list
  operations (new/lost visual IDs, `drop_time` for silent wireless IDs, re-adding); a wireless range
  larger than the visual range adds §5.2's extra edges (new visual × old unassociated active wireless).
  Metrics are then measured on the mobile robots, as in §5.4.

Noise (§6.3): `miss_probability` drops each wireless reception and each light sighting independently.
`miss_tolerance` k eliminates an edge only after more than k disagreements; empty visual IDs are
re-opened (`conflicts`), and wrong unique matches are reported by the ground-truth metric
`fraction_wrong` instead of passing silently.

Reward (team): −(1 − mean fraction matched over every robot's i-state), minus `emission_cost` × the mean number of
emissions per robot this step: every step with unmatched visual IDs costs, so an episode's return counts
how long association took (stationary scenes end when every i-state is final). Units: robot diameters and time steps. A message pair costs
⌈log2 N⌉ + 1 bits (Assumption 2: the wireless ID plus one light bit), charged to `bits_sent`.

Implementation. Populations up to 64 robots keep one ``uint64`` candidate set per (observer, visual ID)
(:class:`BitsetFilter`; the literal w×v matrix :class:`DenseFilter` when `miss_tolerance` > 0); larger
fields use a k-d tree (stationary pairs found once per episode, mobile robots queried each step) and
an edge list (:class:`SparseFilter`). The tests check all three agree step by step. The filters share
one interface (:class:`~.filters.AssociationFilter`); a scene strategy (:mod:`.scenes`: neighbourhood,
dense field, sparse field) owns the world, the sensing and the filter, so the env never branches on
either. Fields larger than 64 robots are checked at construction against an i-state budget
(:mod:`.limits`: about N·k_w·k_v edges for k_w, k_v neighbours in range); beyond it the constructor
raises ``ValueError``. The documented maximum, 10,000 robots at the default density (≈ 50 neighbours
each), takes 1–3 s per step and 0.6 GiB peak with coin flips; if every robot emits in the first step,
that step creates ≈ 2.5·10⁷ edges (11 s, 2 GiB). Stationary, the reset builds them (3–5 s, 1.3 GiB).
A million robots at that density would start with 2.5·10⁹ edges: the range stops at 10,000. A step recomputes
only the mobile robots' ranges, and the per-robot statistics only when the i-states changed. `drop_time`
defaults to 20: the paper gives no value; a robot in range stays silent 20 steps with probability 2⁻²⁰.
`completion_time` is −1 until every observer is final and always in mobile scenes.
"""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces
from matplotlib.patches import Circle

from mrcomm_env.channel_association.copy_axis import NeighborhoodBatch, SlotFieldBatch
from mrcomm_env.channel_association.filters import BITSET_MAX_W
from mrcomm_env.channel_association.limits import check_field_footprint, documented_maxima
from mrcomm_env.channel_association.observation import HISTORY, push_emission, write_istate
from mrcomm_env.channel_association.scenes import (
    DenseFieldScene,
    NeighborhoodScene,
    Scene,
    SparseFieldScene,
    layout_field,
)
from mrcomm_env.channel_association.spec import (  # noqa: F401 — the limits are part of this module's API
    MIN_LENGTH,
    ChannelAssociationSpec,
)
from mrcomm_env.core import render as rendering
from mrcomm_env.core.base import MrcommParallelEnv
from mrcomm_env.core.comm import BitLedger

__all__ = ["ChannelAssociationEnv", "layout_field"]


class ChannelAssociationEnv(ChannelAssociationSpec, MrcommParallelEnv):
    ENV_ID = "mrcomm/ChannelAssociation-v0"
    DESCRIPTION = "Robots blink and broadcast to associate neighbours' wireless IDs with their own visual labels."
    metadata = {"name": "channel_association_v0", "render_modes": ["rgb_array", "human"], "render_fps": 10}

    @classmethod
    def copy_axis_world(cls, cfg):
        """Scenes on bit sets (``miss_tolerance`` 0, at most 64 wireless IDs per observer), with either reward, step
        M copies as one batch of arrays (:mod:`.copy_axis`): a neighbourhood, or a field of at most ``DENSE_MAX_N``
        robots. Other configurations step their copies in turn."""
        if cfg.miss_tolerance != 0:
            return None
        if cfg.scene == "neighborhood":
            return NeighborhoodBatch if cfg.w <= BITSET_MAX_W else None
        return SlotFieldBatch if cfg.n_robots <= cls.DENSE_MAX_N else None

    # ------------------------------------------------------------------ setup
    def _setup(self) -> None:
        c = self.cfg
        if c.scene == "neighborhood":
            if c.v > c.w:
                raise ValueError(f"argument 'v' must be ≤ w = {c.w} (visual IDs are a subset), got {c.v}")
            self.n_agents = c.w + 1
        else:
            if c.visual_range > c.wireless_range:
                raise ValueError(
                    f"argument 'visual_range' must be ≤ wireless_range = {c.wireless_range:g} "
                    f"(Property 2: channel inclusion), got {c.visual_range:g}"
                )
            self.n_agents = c.n_robots
            if c.n_robots > self.DENSE_MAX_N:  # the edge-list backend: memory grows with neighbours
                check_field_footprint(c)
        n = self.n_agents
        self._id_bits = max(1, int(math.ceil(math.log2(n))))
        self._msg_bits = self._id_bits + 1
        self._msg_bits_f = float(self._msg_bits)
        ids = np.arange(n)
        self._id_code = ((ids[:, None] >> np.arange(self._id_bits)[None, :]) & 1).astype(np.float32)
        self._clock = self._id_bits + 1  # the phase a blink code of ⌈log2 N⌉ bits plus a beacon cycles through
        # (clock, N, B): at phase p the ID bits rotated left by p, so that column 0 holds bit p; the beacon phase
        # p = B is a full turn (the plain ID), and the phase one-hot tells it apart
        self._clock_codes = np.stack([np.roll(self._id_code, -p, axis=1) for p in range(self._clock)])
        self._obs_dim = self._id_bits + 1 + HISTORY + 5 + self._clock
        self._phase_col = self._obs_dim - self._clock
        self._obs_space = spaces.Box(0.0, 1.0, shape=(self._obs_dim,), dtype=np.float32)
        self._act_space = spaces.Discrete(2)
        self.ledger = BitLedger(n)
        self._max_cycles, self._cost = c.max_cycles, c.emission_cost  # plain attributes: hot path
        # the scene strategy: world, sensing, filter backend and ground truth (the only place that knows
        # whether this is a neighbourhood or a field, and which filter keeps the i-states)
        if c.scene == "neighborhood":
            self.scene: Scene = NeighborhoodScene(c, n)
        elif n <= self.DENSE_MAX_N:  # slot-per-robot filters need (N, N) helpers
            self.scene = DenseFieldScene(c, n)
        else:
            self.scene = SparseFieldScene(c, n)
        observer = self.scene.observer.astype(np.float32)
        # observation = [own ID bits (rotated by the phase in _observe), observer flag | dynamic: step, 4 emissions, 4 i-state stats]
        self._static_obs = np.concatenate((self._id_code, observer[:, None]), axis=1)
        self._n_static = self._static_obs.shape[1]
        k = np.arange(2 * n + 2, dtype=np.float64)  # counts are at most 2N (new W + new V IDs)
        self._squash8, self._squash4 = k / (k + 8.0), k / (k + 4.0)

    # ------------------------------------------------------------------ episode
    def _reset_world(self) -> None:
        n = self.n_agents
        self.ledger.reset()
        # the observation rows: the static part is written once per episode, the dynamic part (columns
        # _n_static:) in place; that part is sliced where used, not kept as a view, so a pickled copy
        # of the env stays consistent
        self._obs = np.zeros((n, self._obs_dim), dtype=np.float32)
        self._obs[:, : self._n_static] = self._static_obs
        self._stats_key = None  # i-state statistics not yet computed
        self._emit = np.zeros(n, dtype=bool)
        self._completion = -1
        self.scene.reset(self.np_random)
        self._refresh()

    # the scene's state, read by tests, rendering and the reproduction
    @property
    def filter(self):
        return self.scene.filter

    @property
    def backend(self) -> str:
        """Which filter keeps the i-states: ``bitset``, ``dense`` or ``sparse``."""
        return self.scene.backend

    @property
    def mobile(self) -> bool:
        return self.scene.mobile

    @property
    def positions(self) -> np.ndarray:
        return self.scene.positions

    @property
    def moving(self) -> np.ndarray:
        return self.scene.moving

    @property
    def observer(self) -> np.ndarray:
        return self.scene.observer

    @property
    def measured(self) -> np.ndarray:
        return self.scene.measured

    @property
    def vel(self) -> np.ndarray:
        return self.scene.vel

    @property
    def size(self) -> np.ndarray:
        return self.scene.size

    @property
    def vis_robot(self) -> np.ndarray:
        """The robot behind each visual slot of the filter: the neighbourhood's own labelling, or every robot in
        index order in a field, where slots are robots."""
        if isinstance(self.scene, NeighborhoodScene):
            return self.scene.vis_robot
        return np.arange(self.n_agents)

    @property
    def _n_stat(self) -> int:
        """Stationary robots come first, the mobile ones after them."""
        return self.scene.n_stat

    # ------------------------------------------------------------------ its copy-axis world (copy_axis.py)
    def world_constants(self) -> dict:
        """The constants of the observation and the reward, the same in every copy of one configuration, that the
        copy-axis world computes with: message bits, the ID code's bits and its clock, the static columns, the
        squashing tables and the observation's width."""
        return {
            "msg_bits": self._msg_bits_f,
            "id_bits": self._id_bits,
            "n_static": self._n_static,
            "clock": self._clock,
            "phase_col": self._phase_col,
            "clock_codes": self._clock_codes,
            "squash8": self._squash8,
            "squash4": self._squash4,
            "static_obs": self._static_obs,
            "obs_dim": self._obs_dim,
        }

    def episode_arrays(self) -> tuple:
        """(observation ``(N, D)``, last emissions ``(N,)``, completion step or −1, per-robot i-state statistics) of
        the episode as it stands: the env's own arrays, which a copy-axis world copies into its rows at a reset."""
        return self._obs, self._emit, self._completion, self._stats

    def load_episode(self, obs, emit, completion: int, stats: tuple, frac, team_score: float, began: bool) -> None:
        """Take over an episode's state from a copy-axis world that stepped it (and began it, with ``began``), as
        if this env had: the arguments are :meth:`episode_arrays`' plus the matched fractions and the team's
        score. The caller writes the step count and the ledger, and ends the episode where it ended."""
        if began:  # what reset() would have set
            self.agents = list(self.possible_agents)
            self._live = dict.fromkeys(self.agents)
        self._obs, self._emit, self._completion, self._stats = obs, emit, int(completion), stats
        self._frac, self._team_score = frac, float(team_score)
        self._stats_key = None  # the statistics came from outside: recompute them when the filter next changes
        self._state_version += 1

    # ------------------------------------------------------------------ step
    def _step_world(self, actions: list) -> float | np.ndarray:
        n = self.n_agents
        emit = np.array(actions, dtype=bool)
        self._emit = emit
        push_emission(self._obs[:, self._n_static :], emit)
        n_emit = int(np.count_nonzero(emit))
        self.ledger.record(emit * self._msg_bits_f, n_emit)
        self.scene.step(emit, n_emit)
        self._refresh()
        if self.cfg.reward_mode == "individual":  # each robot: the observers that have singled it out
            singled, seen = self.scene.singled_out()
            reward = np.where(seen > 0, singled / np.maximum(seen, 1), 1.0) - 1.0 - self._cost * emit
        else:
            reward = self._team_score - 1.0 - self._cost * n_emit / n
        if self._completion < 0 and not self.scene.mobile and not self._stats[3].any():
            self._completion = self.step_count + 1
        return reward

    def _terminated(self) -> bool:
        return self._completion >= 0

    # ------------------------------------------------------------------ per-robot statistics
    def _refresh(self) -> None:
        """Cache (matched, visual IDs, edges, unresolved, new IDs) per robot and the fractions matched."""
        f = self.scene.filter
        # most steps change no statistic (everything matched): filters that can tell skip the work
        key = f.stats_key()
        if key is not None:
            if key == self._stats_key:
                return
            self._stats_key = key
        matched, nv, ne, unres, new = self.scene.robot_stats(*f.stats(), f.new_ids)
        self._frac = matched / np.maximum(nv, 1)
        self._team_score = self.scene.team_score(self._frac)
        self._stats = (matched, nv, ne, unres, new)
        write_istate(self._obs[:, self._n_static :], self._frac, nv, ne, unres, new, self._squash8, self._squash4)

    def _observe(self) -> np.ndarray:
        obs = self._obs
        phase = self.step_count % self._clock
        # the own ID read from the bit the clock points at (rev 3): column 0 is the bit a blink code sends now
        obs[:, : self._id_bits] = self._clock_codes[phase]
        obs[:, self._n_static] = min(self.step_count / self._max_cycles, 1.0)
        obs[:, self._phase_col :] = 0.0
        obs[:, self._phase_col + self.step_count % self._clock] = 1.0
        return obs.copy()  # the caller's rows must not change later

    def _local_view(self) -> dict:
        matched, nv, ne, unres, _ = self._stats
        return {"matched": matched, "visual_ids": nv, "edges": ne, "unresolved": unres}

    def _agent_infos(self):
        return {"bits_sent": self.ledger.step_bits}

    # ------------------------------------------------------------------ ground truth and metrics
    def action_label(self, action) -> str:
        """1 emits (a blink with its wireless message, Algorithm 1's emission), 0 stays dark and silent."""
        return "emit" if int(action) else "silent"

    def decision_context(self) -> list[str]:
        """The clock phase every robot observes (step mod ⌈log2 N⌉ + 1): the step at which a blink code sends its
        ID's bit p, or the beacon step of a full turn. Split by it, a code's emissions show which bits it sends."""
        phase = self.step_count % self._clock
        context = "beacon phase" if phase == self._id_bits else f"bit phase {phase}"
        return [context] * self.n_agents

    def _metrics(self) -> dict[str, float]:
        matched, nv, ne = self._stats[:3]
        sel = self.measured & (nv > 0)
        frac = float((matched[sel] / nv[sel]).mean()) if sel.any() else 0.0
        true = self.scene.true_edges()
        ratio = float((ne[sel] / np.maximum(true[sel], 1)).mean()) if sel.any() else 1.0
        wrong, total = self.scene.wrong_matches()
        return {
            "completion_time": float(self._completion),
            "fraction_matched": frac,
            "edge_ratio": ratio,
            "fraction_wrong": wrong / total if total else 0.0,
            "conflicts": float(self.filter.conflicts),
            "messages_sent": float(self.ledger.messages),
            "bits_sent": float(self.ledger.total_bits.sum()),
        }

    def tracked_robots(self) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """Per observer, the robots behind the wireless IDs and behind the visual IDs its i-state links now (ground
        truth, for bounds and tests): ``(observer, wireless robots, visual robots)``. On a perfect channel an edge
        survives exactly while the two IDs' activities agree (Algorithm 1, lines 15–16), so the observer's i-state
        is final once every visual robot's emission history differs from that of every other wireless robot."""
        observer, h, s = self.filter.edges()
        wireless, visual = self.scene.wireless_robot(h), self.scene.visual_robot(s)
        return [
            (int(o), np.unique(wireless[observer == o]), np.unique(visual[observer == o])) for o in np.unique(observer)
        ]

    def associations(self, agent: str) -> dict[int, list[int]]:
        """What ``agent`` knows: its own visual label → candidate wireless IDs (one entry = matched)."""
        return self.scene.associations(self._index_of(agent))

    # ------------------------------------------------------------------ rendering
    def _render(self, ax) -> None:
        pos = self.positions
        f = self._frac
        ax.scatter(pos[:, 0], pos[:, 1], c=f, cmap="viridis", vmin=0, vmax=1, s=14)
        ax.scatter(pos[self.moving, 0], pos[self.moving, 1], facecolors="none", edgecolors="red", s=40)
        lit = self._emit
        ax.scatter(pos[lit, 0], pos[lit, 1], marker="*", color="gold", s=30)
        # the radio is a broadcast heard by every robot (no link of its own): each transmitter's bits this step
        for i in np.flatnonzero(lit)[: rendering.MAX_LINK_LABELS]:
            ax.annotate(
                rendering.format_bits(self.ledger.step_bits[i]),
                pos[i],
                xytext=(3, 3),
                textcoords="offset points",
                fontsize=6,
                color="tab:brown",
            )
        r = self.scene.render_radius
        ax.add_patch(Circle(pos[0], r, fill=False, color="tab:blue"))
        ax.set_aspect("equal")
        ax.set_title(f"{self.ENV_ID} step {self.step_count}  matched {self._team_score:.2f}")


# the documented maxima live beside the memory model that sets them (``limits.py``); read once the class exists
ChannelAssociationEnv.LIMIT_CONFIGS = documented_maxima(ChannelAssociationEnv.PARAMS, ChannelAssociationEnv.DENSE_MAX_N)
