"""ChannelAssociation-v0's declarations, apart from its behaviour (``env.py``): its arguments, metrics, infos and local view,
its documented configurations and limits, and its memory model with the probes that check it. ``ChannelAssociationEnv``
inherits them from :class:`ChannelAssociationSpec`; ``mrcomm docs`` reads them from there."""

from __future__ import annotations

from mrcomm_env.channel_association.limits import footprint_of
from mrcomm_env.core.base import EnvSpec
from mrcomm_env.core.config import Choice, Int, Param, Real

#: smallest spacing and ranges, in robot diameters: a thousandth of a robot is below any meaningful
#: geometry, and far smaller lengths break the k-d tree (squared distances under 1e-308 become 0)
MIN_LENGTH = 1e-3


class ChannelAssociationSpec(EnvSpec):
    """The declarations of ChannelAssociation-v0 (module docstring): class attributes the env class inherits."""

    PARAMS = {
        "scene": Param(
            "field",
            "`neighborhood` (one observer, §4) or `field` (grid + mobile robots, §5)",
            Choice(("neighborhood", "field")),
        ),
        "w": Param(8, "neighborhood: wireless IDs in the observer's range", Int(1, 512, fuzz=(6, 12))),
        "v": Param(6, "neighborhood: visual IDs in range (v ≤ w)", Int(1, 512, fuzz=(1, 6))),
        "n_robots": Param(
            12,
            "field: number of robots (the default 4×3 field is small on purpose: cheap; see "
            "DOCUMENTED_CONFIGS). Large fields must also fit the i-state budget of `limits.py`",
            Int(2, 10_000, fuzz=(2, 40)),
        ),
        "separation": Param(
            4.0, "field: grid spacing of stationary robots (robot diameters)", Real(MIN_LENGTH, 1e4, fuzz=(1.0, 10.0))
        ),
        "mobile_fraction": Param(0.1, "field: fraction of robots that move", Real(0.0, 1.0, fuzz=(0.0, 1.0))),
        "speed": Param(1.4, "field: speed of mobile robots (diameters per step)", Real(0.0, 1e4, fuzz=(0.0, 5.0))),
        "wireless_range": Param(16.0, "field: wireless range (diameters)", Real(MIN_LENGTH, 1e6, fuzz=(16.0, 40.0))),
        "visual_range": Param(
            16.0,
            "field: visual range (diameters, ≤ wireless range by Property 2)",
            Real(MIN_LENGTH, 1e6, fuzz=(1.0, 16.0)),
        ),
        "drop_time": Param(
            20, "mobile field: steps of silence before a wireless ID is dropped (Alg. 2)", Int(1, 10_000, fuzz=(1, 30))
        ),
        "miss_probability": Param(
            0.0,
            "probability that one reception (wireless or light) is missed (§6.3)",
            Real(0.0, 1.0, hi_open=True, fuzz=(0.0, 0.5)),
        ),
        "miss_tolerance": Param(
            0, "disagreements an edge survives before elimination (0 = Algorithm 1)", Int(0, 200, fuzz=(0, 3))
        ),
        "max_cycles": Param(100, "episode length limit", Int(1, 10_000_000, fuzz=(1, 60))),
        "reward_mode": Param(
            "team",
            "`team`: one reward, −(1 − mean fraction matched); `individual`: robot j gets −(1 − the fraction of the "
            "observers that see it which have singled it out), the part of the association its own blinking decides",
            Choice(("team", "individual")),
        ),
        "emission_cost": Param(0.0, "reward cost per emission (team-averaged)", Real(0.0, 1e6, fuzz=(0.0, 1.0))),
    }

    UNREACHED_TIMES = ("completion_time",)

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

    MEMORY_FORMULA = (
        "2 MiB + 80 B per i-state entry of a large field (`n_robots` > 64: E edges + T tracked wireless IDs, "
        "the expected counts of `limits.field_footprint` from `n_robots`, `separation`, `wireless_range`, "
        "`visual_range`, `mobile_fraction`, `speed`, `drop_time`; 80 B is the measured peak per entry when every "
        "robot emits at once), 8·`n_robots`³ for a small field's slot-per-robot filters, 8·`w`·`v` for a neighborhood"
    )

    MEMORY_SHARED = 2.0 * 2**20  # the formula's constant term: working memory the copies of a batch share

    MEMORY_ARGS = ("n_robots", "separation", "wireless_range", "visual_range")

    MEMORY_PROBES = {
        "stationary_field_1000": {"n_robots": 1000, "mobile_fraction": 0.0, "max_cycles": 3},
        "stationary_field_2000": {"n_robots": 2000, "mobile_fraction": 0.0, "max_cycles": 3},
        "stationary_field_4000": {"n_robots": 4000, "mobile_fraction": 0.0, "max_cycles": 3},
    }

    #: populations up to this size use slot-per-robot filters (bit sets, or the literal (N, N, N) 0/1
    #: matrix when ``miss_tolerance`` > 0); larger ones the k-d tree + edge list backend
    DENSE_MAX_N = 64

    @classmethod
    def memory_estimate(cls, cfg) -> float:
        base = cls.MEMORY_SHARED
        if cfg.scene == "neighborhood":
            return base + 8.0 * cfg.w * cfg.v
        if cfg.n_robots <= cls.DENSE_MAX_N:
            return base + 8.0 * float(cfg.n_robots) ** 3
        footprint = footprint_of(cfg)
        return base + 80.0 * (footprint["edges"] + footprint["tracked"])

    DOCUMENTED_CONFIGS = {
        "default": {},
        "neighborhood": {"scene": "neighborhood", "w": 8, "v": 6},
        "stationary_field": {"scene": "field", "n_robots": 25, "mobile_fraction": 0.0},
        "individual_reward": {
            "scene": "field",
            "n_robots": 25,
            "separation": 6.0,
            "mobile_fraction": 0.0,
            "reward_mode": "individual",
            "emission_cost": 0.1,
        },
        "large_field": {"scene": "field", "n_robots": 80, "separation": 5.0},
        "wide_wireless": {"scene": "field", "n_robots": 30, "wireless_range": 22.0, "visual_range": 10.0},
        "noisy": {"scene": "neighborhood", "w": 6, "v": 5, "miss_probability": 0.05, "miss_tolerance": 1},
    }

    VERSION_HISTORY = [
        ("v0", "first release: scenes neighborhood and field, Algorithms 1–2, misses"),
        (
            "v0 rev 2",
            "learnable: the reward is −(1 − fraction matched) per step (was its increase, so every "
            "policy's return was 1 and only discounting rewarded speed); the observation gains the clock phase "
            "one-hot of step mod (⌈log2 N⌉ + 1), which a blink code needs; `reward_mode=individual` gives each "
            "robot the share of the observers that see it which have singled it out (what its own blinking decides)",
        ),
        (
            "v0 rev 3",
            "the own ID bits are read relative to the clock: at phase p the observation holds the ID rotated left by "
            "p, so its first column is the bit a blink code would send now (an agent-relative layout; the same "
            "information as rev 2, which a shared PPO policy had to decode as a product of ID bit and phase and "
            "did not find in 300,000 agent-steps)",
        ),
    ]
