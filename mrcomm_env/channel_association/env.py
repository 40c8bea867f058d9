"""ChannelAssociation-v0: matching wireless IDs to visual IDs (Ivanov & Shell, "Hark! Who goes there?").

| | |
| --- | --- |
| Agents | `neighborhood`: w + 1 (`robot_0` observes, `robot_1 … robot_w` are its neighbours); `field`: `n_robots` |
| Actions | `Discrete(2)`: 1 = emit a message pair (light on + wireless broadcast of the own ID), 0 = stay silent |
| Observations | `Box(0, 1, (⌈log2 N⌉ + 10,), float32)`: own ID bits, observer flag, step/max_cycles, last 4 emissions (newest first), own i-state: fraction matched, ambiguity (edges − v)/edges, unresolved u/(u+8), new IDs this step n/(n+4) |
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

Reward (team): increase of the mean fraction matched over observers, minus `emission_cost` × the mean
number of emissions per robot this step. Units: robot diameters and time steps. A message pair costs
⌈log2 N⌉ + 1 bits (Assumption 2: the wireless ID plus one light bit), charged to `bits_sent`.

Implementation. Populations up to 64 robots keep one ``uint64`` candidate set per (observer, visual ID)
(:class:`BitsetFilter`; the literal w×v matrix :class:`DenseFilter` when `miss_tolerance` > 0); larger
fields use a k-d tree (stationary pairs found once per episode, mobile robots queried each step) and
an edge list (:class:`SparseFilter`). The tests check all three agree step by step. A step recomputes
only the mobile robots' ranges, and the per-robot statistics only when the i-states changed. `drop_time`
defaults to 20: the paper gives no value; a robot in range stays silent 20 steps with probability 2⁻²⁰.
`completion_time` is −1 until every observer is final and always in mobile scenes.
"""

from __future__ import annotations

import math
from itertools import chain

import numpy as np
from gymnasium import spaces
from scipy.spatial import cKDTree

from mrcomm_env.channel_association.filters import _POW2, BitsetFilter, DenseFilter, SparseFilter
from mrcomm_env.core.base import MrcommParallelEnv
from mrcomm_env.core.comm import BitLedger, disk_pairs
from mrcomm_env.core.config import Choice, Int, Param, Real

HISTORY = 4  # own past emissions in the observation


def layout_field(rng: np.random.Generator, n: int, separation: float, mobile_fraction: float):
    """§5.4: grid robots (perturbed within half a spacing) plus uniformly placed mobile robots.

    The arena is the ⌈√n⌉-column grid of spacing ``separation``; stationary robots take randomly chosen
    cells so the density (1/separation²) is the same for any mix. Returns positions, mobile mask, size.
    """
    n_mob = int(round(mobile_fraction * n))
    cols = int(math.ceil(math.sqrt(n)))
    rows = int(math.ceil(n / cols))
    size = np.array([cols * separation, rows * separation])
    cells = rng.permutation(cols * rows)[: n - n_mob]
    grid = np.stack((cells % cols, cells // cols), axis=1).astype(np.float64)
    stat = (grid + 0.5) * separation + rng.uniform(-0.5, 0.5, size=grid.shape) * separation
    mob = rng.uniform(0.0, 1.0, size=(n_mob, 2)) * size
    pos = np.concatenate((stat, mob))
    mobile = np.zeros(n, dtype=bool)
    mobile[n - n_mob:] = True
    return pos, mobile, size


class ChannelAssociationEnv(MrcommParallelEnv):
    ENV_ID = "mrcomm/ChannelAssociation-v0"
    DESCRIPTION = "Robots blink and broadcast to associate neighbours' wireless IDs with their own visual labels."
    metadata = {"name": "channel_association_v0", "render_modes": ["rgb_array", "human"], "render_fps": 10}

    PARAMS = {
        "scene": Param("field", "`neighborhood` (one observer, §4) or `field` (grid + mobile robots, §5)",
                       Choice(("neighborhood", "field"))),
        "w": Param(8, "neighborhood: wireless IDs in the observer's range", Int(1, 512, fuzz=(6, 12))),
        "v": Param(6, "neighborhood: visual IDs in range (v ≤ w)", Int(1, 512, fuzz=(1, 6))),
        "n_robots": Param(12, "field: number of robots (the default 4×3 field is small on purpose: cheap; see DOCUMENTED_CONFIGS)",
                           Int(2, 1_000_000, fuzz=(2, 40))),
        "separation": Param(4.0, "field: grid spacing of stationary robots (robot diameters)",
                            Real(0.0, 1e4, lo_open=True, fuzz=(1.0, 10.0))),
        "mobile_fraction": Param(0.1, "field: fraction of robots that move", Real(0.0, 1.0, fuzz=(0.0, 1.0))),
        "speed": Param(1.4, "field: speed of mobile robots (diameters per step)", Real(0.0, 1e4, fuzz=(0.0, 5.0))),
        "wireless_range": Param(16.0, "field: wireless range (diameters)",
                                Real(0.0, 1e6, lo_open=True, fuzz=(16.0, 40.0))),
        "visual_range": Param(16.0, "field: visual range (diameters, ≤ wireless range by Property 2)",
                              Real(0.0, 1e6, lo_open=True, fuzz=(1.0, 16.0))),
        "drop_time": Param(20, "mobile field: steps of silence before a wireless ID is dropped (Alg. 2)",
                           Int(1, 10_000, fuzz=(1, 30))),
        "miss_probability": Param(0.0, "probability that one reception (wireless or light) is missed (§6.3)",
                                  Real(0.0, 1.0, hi_open=True, fuzz=(0.0, 0.5))),
        "miss_tolerance": Param(0, "disagreements an edge survives before elimination (0 = Algorithm 1)",
                                Int(0, 200, fuzz=(0, 3))),
        "max_cycles": Param(100, "episode length limit", Int(1, 10_000_000, fuzz=(1, 60))),
        "emission_cost": Param(0.0, "reward cost per emission (team-averaged)", Real(0.0, 1e6, fuzz=(0.0, 1.0))),
    }
    METRICS = {
        "completion_time": "stationary scenes: steps until every observer's i-state is final (−1 if not yet / mobile)",
        "fraction_matched": "mean over measured observers of visual IDs with exactly one candidate / visual IDs tracked",
        "edge_ratio": "mean over measured observers of total edges / true edges in the i-state (§5.3)",
        "fraction_wrong": "unique matches that are wrong (ground truth; 0 on a perfect channel)",
        "conflicts": "visual IDs found with no candidate and re-opened (only with misses or premature drops)",
        "messages_sent": "message pairs emitted so far",
        "bits_sent": "bits emitted so far (⌈log2 N⌉-bit wireless ID + 1 light bit per message pair)",
    }
    INFO_KEYS = {"bits_sent": "bits this robot emitted this step (its fraction matched is in the observation)"}
    LOCAL_VIEW = {
        "matched": "visual IDs in this robot's i-state with exactly one wireless candidate",
        "visual_ids": "visual IDs this robot tracks",
        "edges": "candidate edges (wireless ID, visual ID) left in this robot's i-state",
        "unresolved": "visual IDs of this robot with more than one candidate",
    }
    DOCUMENTED_CONFIGS = {
        "default": {},
        "neighborhood": {"scene": "neighborhood", "w": 8, "v": 6},
        "stationary_field": {"scene": "field", "n_robots": 25, "mobile_fraction": 0.0},
        "large_field": {"scene": "field", "n_robots": 80, "separation": 5.0},
        "wide_wireless": {"scene": "field", "n_robots": 30, "wireless_range": 22.0, "visual_range": 10.0},
        "noisy": {"scene": "neighborhood", "w": 6, "v": 5, "miss_probability": 0.05, "miss_tolerance": 1},
    }
    VERSION_HISTORY = [("v0", "first release: scenes neighborhood and field, Algorithms 1–2, misses")]

    #: populations up to this size use slot-per-robot filters (bit sets, or the literal (N, N, N) 0/1
    #: matrix when ``miss_tolerance`` > 0); larger ones the k-d tree + edge list backend
    DENSE_MAX_N = 64

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
                    f"(Property 2: channel inclusion), got {c.visual_range:g}")
            self.n_agents = c.n_robots
        n = self.n_agents
        self._id_bits = max(1, int(math.ceil(math.log2(n))))
        self._msg_bits = self._id_bits + 1
        self._msg_bits_f = float(self._msg_bits)
        ids = np.arange(n)
        self._id_code = ((ids[:, None] >> np.arange(self._id_bits)[None, :]) & 1).astype(np.float32)
        self._obs_dim = self._id_bits + 1 + HISTORY + 5
        self._obs_space = spaces.Box(0.0, 1.0, shape=(self._obs_dim,), dtype=np.float32)
        self._act_space = spaces.Discrete(2)
        self._ledger = BitLedger(n)
        self._max_cycles, self._cost = c.max_cycles, c.emission_cost    # plain attributes: hot path
        self._wrange, self._vrange = c.wireless_range, c.visual_range
        self._neigh = c.scene == "neighborhood"
        small = n <= self.DENSE_MAX_N                       # slot-per-robot backends need (N, N) helpers
        self._self_inf = np.where(np.eye(n, dtype=bool), np.inf, 0.0) if small else None
        self._pow = _POW2[:n] if n <= 64 else None
        observer = np.zeros(n, dtype=np.float32) if self._neigh else np.ones(n, dtype=np.float32)
        observer[0] = 1.0
        # observation = [static: own ID bits, observer flag | dynamic: step, 4 emissions, 4 i-state stats]
        self._static_obs = np.concatenate((self._id_code, observer[:, None]), axis=1)
        self._n_static = self._static_obs.shape[1]
        k = np.arange(2 * n + 2, dtype=np.float64)           # counts are at most 2N (new W + new V IDs)
        self._squash8, self._squash4 = k / (k + 8.0), k / (k + 4.0)

    # ------------------------------------------------------------------ episode
    def _make_filter(self, b: int, w: int, v: int, extra: bool):
        c = self.cfg
        if c.miss_tolerance == 0 and w <= 64:
            f = BitsetFilter(b, w, v, c.drop_time, extra)
        else:
            f = DenseFilter(b, w, v, c.drop_time, c.miss_tolerance, extra)
        f.rng = self.np_random
        return f

    def _reset_world(self) -> None:
        c, n, rng = self.cfg, self.n_agents, self.np_random
        self._ledger.reset()
        # the observation rows: the static part is written once per episode, the dynamic part (columns
        # _n_static:) in place; that part is sliced where used, not kept as a view, so a pickled copy
        # of the env stays consistent
        self._obs = np.zeros((n, self._obs_dim), dtype=np.float32)
        self._obs[:, : self._n_static] = self._static_obs
        self._stats_key = None                              # i-state statistics not yet computed
        self._rows_key = None                               # mobile robots' in-range rows not yet known
        self._emit = np.zeros(n, dtype=bool)
        self._completion = -1
        self._q = c.miss_probability
        if self._neigh:
            self._setup_neighborhood(rng)
        else:
            self._setup_field(rng)
        self._refresh()
        self._score = self._team_score

    def _setup_neighborhood(self, rng) -> None:
        c = self.cfg
        self.mobile = False
        self.backend = "bitset" if (c.miss_tolerance == 0 and c.w <= 64) else "dense"
        self.moving = np.zeros(self.n_agents, dtype=bool)
        # the observer's own labelling: visual slot s is robot vis_robot[s] (a random subset, random order)
        self.vis_robot = 1 + rng.permutation(c.w)[: c.v]
        self.positions = _ring_positions(c.w, self.vis_robot)   # for rendering only
        self.filter = self._make_filter(1, c.w, c.v, False)
        self.filter.init_known(np.ones((1, c.w), bool), np.ones((1, c.v), bool))
        self.observer = np.zeros(self.n_agents, dtype=bool)
        self.observer[0] = True
        self.measured = self.observer

    def _setup_field(self, rng) -> None:
        c, n = self.cfg, self.n_agents
        self.positions, self.moving, self.size = layout_field(rng, n, c.separation, c.mobile_fraction)
        self._n_stat = n - int(self.moving.sum())
        heading = rng.uniform(0.0, 2.0 * np.pi, size=n - self._n_stat)
        self.vel = c.speed * np.stack((np.cos(heading), np.sin(heading)), axis=1)
        self.mobile = self._n_stat < n
        self.observer = np.ones(n, dtype=bool)
        self.measured = self.moving if self.mobile else self.observer
        extra = c.wireless_range > c.visual_range
        if n <= self.DENSE_MAX_N:
            self.filter = self._make_filter(n, n, n, extra)
            self.backend = "bitset" if isinstance(self.filter, BitsetFilter) else "dense"
            self._update_ranges()
            if not self.mobile:
                self.filter.init_known(self._wr, self._vr)
        else:
            self.backend = "sparse"
            self.filter = SparseFilter(n, c.drop_time, c.miss_tolerance, extra)
            self.filter.rng = rng
            self._update_pairs()
            if not self.mobile:
                self.filter.init_known(self._wkeys, self._vkeys)

    # ------------------------------------------------------------------ geometry
    def _move(self) -> None:
        p = self.positions[self._n_stat:]                   # mobile robots are stored last (a view)
        p += self.vel
        out = p < 0.0
        out |= p > self.size
        if np.count_nonzero(out):                          # bounce off the boundary (§5.4)
            np.abs(p, out=p)
            np.subtract(self.size, np.abs(self.size - p), out=p)
            self.vel[out] *= -1.0

    def _update_ranges(self, first: int = 0) -> None:
        """In-range matrices ``_wr``, ``_vr`` (and ``_wr_bits``) from the positions.

        ``first`` > 0 recomputes only the rows of robots ``first`` … N−1 (the mobile ones, stored last)
        and mirrors them into their columns: distances between stationary robots never change, and
        |a − b| equals |b − a| exactly in floating point, so the result is the full computation's.
        """
        z = self.positions.view(np.complex128).ravel()      # positions viewed as complex numbers
        d = np.abs(z[first:, None] - z)
        d += self._self_inf[first:]                         # a robot is not its own neighbour
        wr, vr = self._wrange, self._vrange
        if first == 0:
            self._wr = d <= wr
            self._vr = d <= vr if vr < wr else self._wr     # the same array when the ranges are equal
        else:
            w = d <= wr
            v = d <= vr if vr < wr else None
            # a robot moves a small part of the range per step: usually nobody entered or left it
            key = w.tobytes() if v is None else w.tobytes() + v.tobytes()
            if key == self._rows_key:
                return
            self._rows_key = key
            self._wr[first:] = w
            self._wr[:, first:] = w.T
            if v is not None:
                self._vr[first:] = v
                self._vr[:, first:] = v.T
        if self.backend == "bitset":
            self._wr_bits = self._wr @ self._pow            # pack_rows, inlined: hot path

    def _update_pairs(self) -> None:
        """Directed in-range pairs as sorted keys o*n + x (k-d tree).

        Pairs between stationary robots never change, so they are found once per episode; each step
        only the mobile robots are queried against a tree of all positions and merged in.
        """
        c, n, pos = self.cfg, self.n_agents, self.positions
        ns = self._n_stat
        if not hasattr(self, "_static_keys") or self._static_for is not pos:
            stat = pos[:ns]
            pairs = disk_pairs(stat, c.wireless_range).astype(np.int64)
            a, b = pairs[:, 0], pairs[:, 1]
            self._static_keys = np.sort(np.concatenate((a * n + b, b * n + a)))
            self._static_for = pos
        keys = self._static_keys
        if ns < n:
            lists = cKDTree(pos).query_ball_point(pos[ns:], c.wireless_range)
            cnt = np.fromiter(map(len, lists), dtype=np.int64, count=len(lists))
            x = np.fromiter(chain.from_iterable(lists), dtype=np.int64, count=int(cnt.sum()))
            m = np.repeat(np.arange(ns, n), cnt)
            keep = x != m
            m, x = m[keep], x[keep]
            st = x < ns                                     # mobile–stationary pairs also go the other way
            dyn = np.sort(np.concatenate((m * n + x, x[st] * n + m[st])))
            keys = np.sort(np.concatenate((keys, dyn)), kind="stable")   # merge of two sorted runs
        self._wkeys = keys
        if c.visual_range < c.wireless_range:
            d = pos[keys // n] - pos[keys % n]
            self._vkeys = keys[np.einsum("ij,ij->i", d, d) <= c.visual_range ** 2]
        else:
            self._vkeys = keys

    def _visual_in_range(self, keys: np.ndarray) -> np.ndarray:
        """Still in visual range? Only pairs involving a mobile robot can have left."""
        n = self.n_agents
        o, x = np.divmod(keys, n)
        inside = np.ones(len(keys), dtype=bool)
        mov = np.nonzero(self.moving[o] | self.moving[x])[0]
        d = self.positions[o[mov]] - self.positions[x[mov]]
        inside[mov] = np.einsum("ij,ij->i", d, d) <= self.cfg.visual_range ** 2
        return inside

    # ------------------------------------------------------------------ step
    def _step_world(self, actions: list) -> float:
        n = self.n_agents
        emit = np.array(actions, dtype=bool)
        self._emit = emit
        dyn = self._obs[:, self._n_static:]                 # dynamic part of the observation (a view)
        dyn[:, 2: 1 + HISTORY] = dyn[:, 1:HISTORY]       # shift own emission history, newest first
        dyn[:, 1] = emit
        n_emit = int(np.count_nonzero(emit))
        self._ledger.record(emit * self._msg_bits_f, n_emit)
        q, rng = self._q, self.np_random
        if self._neigh:
            recv = emit[None, 1:]
            vact = emit[self.vis_robot][None, :]
            if q > 0.0:
                recv = recv & (rng.random(recv.shape) >= q)
                vact = vact & (rng.random(vact.shape) >= q)
            self.filter.step(recv, vact)
        elif self.backend != "sparse":
            if self.mobile:
                self._move()
                self._update_ranges(self._n_stat)           # only the mobile robots' rows and columns
            if q > 0.0:
                recv = self._wr & emit & (rng.random((n, n)) >= q)
                vact = self._vr & emit & (rng.random((n, n)) >= q)
                self.filter.step(recv, vact, self._vr, self.mobile)
            elif not (n_emit or self.mobile):
                pass                                        # known neighbourhoods, nobody lit: no change
            elif self.backend == "bitset":
                self.filter.step(None, self._vr & emit, self._vr, self.mobile,
                                 recv_bits=self._wr_bits & (emit @ self._pow))
            else:
                self.filter.step(self._wr & emit, self._vr & emit, self._vr, self.mobile)
        else:
            if self.mobile:
                self._move()
                self._update_pairs()
            wk, vk = self._wkeys, self._vkeys
            recv = wk[emit[wk % n]]
            vact = vk[emit[vk % n]]
            salt = None
            if q > 0.0:
                # counter-based miss draws, so that "was key k received?" has one answer per step
                salt = rng.integers(0, 2**63, size=2, dtype=np.uint64)
                recv = recv[_uniform_hash(recv, salt[0]) >= q]
                vact = vact[_uniform_hash(vact, salt[1]) >= q]

            def w_active(keys):
                o, x = np.divmod(keys, n)
                on = emit[x]
                mov = np.nonzero(on & (self.moving[o] | self.moving[x]))[0]
                if len(mov):                                # stationary pairs tracked ⇒ in range
                    d = self.positions[o[mov]] - self.positions[x[mov]]
                    on[mov] = np.einsum("ij,ij->i", d, d) <= self.cfg.wireless_range ** 2
                if salt is not None:
                    on &= _uniform_hash(keys, salt[0]) >= q
                return on

            def v_active(keys):                             # tracked visual IDs are in range
                on = emit[keys % n]
                if salt is not None:
                    on &= _uniform_hash(keys, salt[1]) >= q
                return on

            self.filter.step(recv, vact, self._visual_in_range, self.mobile, w_active=w_active, v_active=v_active)
        self._refresh()
        score = self._team_score
        reward = score - self._score - self._cost * n_emit / n
        self._score = score
        if self._completion < 0 and not self.mobile and not self._stats[3].any():
            self._completion = self.step_count + 1
        return reward

    def _terminated(self) -> bool:
        return self._completion >= 0

    # ------------------------------------------------------------------ per-robot statistics
    def _refresh(self) -> None:
        """Cache (matched, visual IDs, edges, unresolved, new IDs) per robot and the fractions matched."""
        f = self.filter
        if self.backend != "sparse":
            # the statistics are functions of (candidates per visual ID, tracked visual IDs, new IDs):
            # most steps change none of them (everything matched), so compare raw bytes and skip
            key = (f.deg.tobytes(), f.vt.tobytes(), f.new_ids.tobytes())
            if key == self._stats_key:
                return
            self._stats_key = key
        matched, nv, ne, unres = f.stats()
        new = self.filter.new_ids
        if self._neigh:                                    # only robot_0 runs a filter
            cols = np.zeros((5, self.n_agents), dtype=np.int64)
            cols[:, 0] = (matched[0], nv[0], ne[0], unres[0], new[0])
            matched, nv, ne, unres, new = cols
            self._frac = matched / np.maximum(nv, 1)
            self._team_score = float(self._frac[0])
        else:
            self._frac = matched / np.maximum(nv, 1)
            self._team_score = float(np.add.reduce(self._frac)) / self.n_agents
        self._stats = (matched, nv, ne, unres, new)
        j, dyn = 1 + HISTORY, self._obs[:, self._n_static:]   # i-state statistics for the observation
        dyn[:, j] = self._frac
        dyn[:, j + 1] = (np.maximum(ne, nv) - nv) / np.maximum(ne, 1)   # unsigned-safe (ne − nv)⁺ / ne
        dyn[:, j + 2] = self._squash8[unres]                # u / (u + 8), tabulated
        dyn[:, j + 3] = self._squash4[new]                  # n / (n + 4), tabulated

    def _observe(self) -> np.ndarray:
        obs = self._obs
        obs[:, self._n_static] = min(self.step_count / self._max_cycles, 1.0)
        return obs.copy()                                   # the caller's rows must not change later

    def _local_view(self) -> dict:
        matched, nv, ne, unres, _ = self._stats
        return {"matched": matched, "visual_ids": nv, "edges": ne, "unresolved": unres}

    def _agent_infos(self):
        return {"bits_sent": self._ledger.step_bits}

    # ------------------------------------------------------------------ ground truth and metrics
    def _true_edges(self) -> np.ndarray:
        """Number of true edges (wireless and visual ID of the same robot) per observer."""
        E = getattr(self.filter, "E", None)
        if self._neigh:
            out = np.zeros(self.n_agents, dtype=np.int64)
            out[0] = int(E[0, self.vis_robot - 1, np.arange(self.cfg.v)].sum())
            return out
        if self.backend != "sparse":
            return np.einsum("ijj->i", E.astype(np.int64))
        f, n = self.filter, self.n_agents
        return np.bincount(f.ev[f.ew % n == f.ev % n] // n, minlength=n)

    def _wrong_matches(self) -> tuple[int, int]:
        if self._neigh:
            b, h, s = self.filter.matches()
            return int(np.count_nonzero(h + 1 != self.vis_robot[s])), len(b)
        o, a, b = self.filter.matches()
        return int(np.count_nonzero(a != b)), len(o)

    def metrics(self) -> dict[str, float]:
        matched, nv, ne = self._stats[:3]
        sel = self.measured & (nv > 0)
        frac = float((matched[sel] / nv[sel]).mean()) if sel.any() else 0.0
        true = self._true_edges()
        ratio = float((ne[sel] / np.maximum(true[sel], 1)).mean()) if sel.any() else 1.0
        wrong, total = self._wrong_matches()
        return {
            "completion_time": float(self._completion),
            "fraction_matched": frac,
            "edge_ratio": ratio,
            "fraction_wrong": wrong / total if total else 0.0,
            "conflicts": float(self.filter.conflicts),
            "messages_sent": float(self._ledger.messages),
            "bits_sent": float(self._ledger.total_bits.sum()),
        }

    def associations(self, agent: str) -> dict[int, list[int]]:
        """What ``agent`` knows: its own visual label → candidate wireless IDs (one entry = matched)."""
        i = self._index_of(agent)
        f, n = self.filter, self.n_agents
        if self._neigh:
            if i != 0:
                return {}
            E = f.E
            return {int(f.vlabel[0, s]): [int(h + 1) for h in np.nonzero(E[0, :, s])[0]]
                    for s in np.nonzero(f.vt[0])[0]}
        if self.backend != "sparse":
            E = f.E
            return {int(f.vlabel[i, b]): np.nonzero(E[i, :, b])[0].tolist() for b in np.nonzero(f.vt[i])[0]}
        lo, hi = np.searchsorted(f.vk, [i * n, (i + 1) * n])
        out = {}
        for key, lab in zip(f.vk[lo:hi], f.vlab[lo:hi], strict=True):
            a, b = np.searchsorted(f.ev, [key, key + 1])
            out[int(lab)] = sorted((f.ew[a:b] % n).tolist())
        return out

    # ------------------------------------------------------------------ rendering
    def _render(self, ax) -> None:
        pos = self.positions
        f = self._frac
        ax.scatter(pos[:, 0], pos[:, 1], c=f, cmap="viridis", vmin=0, vmax=1, s=14)
        ax.scatter(pos[self.moving, 0], pos[self.moving, 1], facecolors="none", edgecolors="red", s=40)
        lit = self._emit
        ax.scatter(pos[lit, 0], pos[lit, 1], marker="*", color="gold", s=30)
        r = 1.0 if self._neigh else self.cfg.visual_range
        from matplotlib.patches import Circle

        ax.add_patch(Circle(pos[0], r, fill=False, color="tab:blue"))
        ax.set_aspect("equal")
        ax.set_title(f"{self.ENV_ID} step {self.step_count}  matched {self._score:.2f}")


_M1, _M2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)


def _uniform_hash(keys: np.ndarray, salt) -> np.ndarray:
    """Uniform [0, 1) numbers from (key, salt) by the splitmix64 finaliser (vectorised, wrapping)."""
    z = keys.astype(np.uint64) + np.uint64(salt)
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    z ^= z >> np.uint64(31)
    return (z >> np.uint64(11)).astype(np.float64) * (1.0 / 2**53)


def _ring_positions(w: int, vis_robot: np.ndarray) -> np.ndarray:
    """Observer at the origin, visible neighbours inside the unit circle, the rest outside (render)."""
    ang = np.linspace(0.0, 2.0 * np.pi, w, endpoint=False)
    rad = np.where(np.isin(np.arange(1, w + 1), vis_robot), 0.7, 1.4)
    return np.concatenate(([[0.0, 0.0]], np.stack((rad * np.cos(ang), rad * np.sin(ang)), axis=1)))
