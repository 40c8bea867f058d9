"""What ChannelAssociation-v0 can hold: the memory estimate checked at construction, and the documented maxima.

Memory of a large field (the edge-list backend, :class:`~.filters.SparseFilter`) grows with the i-states,
not with N²: every observer keeps its tracked wireless IDs and the edges between them and its visual IDs.
In a field of density ρ = N / arena area, an observer has about k_w = ρ·π·r_w² robots in wireless and
k_v = ρ·π·r_v² in visual range (§5.3 uses the same disk counts). Its i-state holds at most k_w·k_v edges —
Algorithm 1 starts from all of them in a stationary field, and a policy that has every robot emit in the
first step of a mobile field creates as many (new W × new V, Algorithm 2 line 27). Wireless IDs stay
tracked for ``drop_time`` silent steps, so a moving observer also keeps the robots it swept past in that
time (a band 2·r_w wide, relative speed ≤ 2·speed).

A step handles each edge and key a few times, with temporaries: measured peak 50–80 bytes per edge
(N = 10,000, 2.5·10⁷ edges: 1.3 GiB stationary; 3.8·10⁷ edges created in one all-emit step: 2.9 GiB,
11 s). :data:`FOOTPRINT_BUDGET` caps edges + tracked keys so that any configuration the constructor
accepts stays within about 3 GiB and a step within seconds; larger ones are rejected with a
``ValueError`` naming the arguments to change. Fields of at most 64 robots use slot-per-robot filters
(at most 64³ cells) and are not limited.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from mrcomm_env.core.config import Param

#: edges + tracked wireless IDs over all observers that a field may be expected to hold (≤ about 3 GiB peak)
FOOTPRINT_BUDGET = 40_000_000


def field_footprint(
    n: int,
    separation: float,
    mobile_fraction: float,
    speed: float,
    wireless_range: float,
    visual_range: float,
    drop_time: int,
) -> dict[str, float]:
    """Expected i-state size of a §5 field: ``edges`` (Σ k_w·k_v) and ``tracked`` wireless IDs, over all observers."""
    cols = math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    # per unit of separation², so that a tiny or huge separation neither underflows nor overflows
    area = cols * rows
    rw, rv = wireless_range / separation, visual_range / separation
    k_w = min(n - 1.0, n / area * math.pi * rw * rw)
    k_v = min(n - 1.0, n / area * math.pi * rv * rv)
    n_mob = int(round(mobile_fraction * n))
    if n_mob == 0 or speed == 0.0:
        tracked = n * k_w
    else:
        sweep = 2.0 * rw * 2.0 * (speed / separation) * drop_time  # area swept past in drop_time steps
        stationary = min(k_w + n_mob, k_w + n_mob / area * sweep)  # a stationary observer sees mobile robots pass
        moving = min(n - 1.0, k_w + n / area * sweep)
        tracked = (n - n_mob) * stationary + n_mob * moving
    return {"edges": n * k_w * k_v, "tracked": tracked, "k_w": k_w, "k_v": k_v}


def footprint_of(cfg) -> dict[str, float]:
    """:func:`field_footprint` of the env arguments ``cfg``."""
    return field_footprint(
        cfg.n_robots,
        cfg.separation,
        cfg.mobile_fraction,
        cfg.speed,
        cfg.wireless_range,
        cfg.visual_range,
        cfg.drop_time,
    )


def check_field_footprint(cfg) -> None:
    """Raise ``ValueError`` when a field would outgrow :data:`FOOTPRINT_BUDGET` (see the module docstring)."""
    est = footprint_of(cfg)
    total = est["edges"] + est["tracked"]
    if total > FOOTPRINT_BUDGET:
        raise ValueError(
            f"arguments 'n_robots' = {cfg.n_robots}, 'separation' = {cfg.separation:g}, 'wireless_range' = "
            f"{cfg.wireless_range:g}, 'visual_range' = {cfg.visual_range:g} (with 'speed', 'drop_time') give about "
            f"{est['k_w']:.3g} wireless and {est['k_v']:.3g} visual neighbours per robot: the i-states would hold "
            f"about {total:.3g} edges and IDs, more than the {FOOTPRINT_BUDGET:.3g} this environment allows "
            f"(50–80 bytes each); lower 'n_robots' or the ranges, or raise 'separation'"
        )


def documented_maxima(params: Mapping[str, Param], dense_max_n: int) -> dict[str, dict]:
    """Configurations at the edges of the documented ranges ``params`` (the env class's ``PARAMS``), each of which
    must run; ``dense_max_n`` is the largest field that uses slot-per-robot filters.

    ``largest_field`` is the documented maximum population with the other arguments at their defaults;
    the others push every other argument to its largest (or, for ranges, smallest) allowed value.
    """
    hi = {name: p.check.hi for name, p in params.items() if getattr(p.check, "hi", None) is not None}
    below_one = float(np.nextafter(1.0, 0.0))  # miss_probability's range is open at 1
    extremes = {
        "drop_time": hi["drop_time"],
        "miss_tolerance": hi["miss_tolerance"],
        "max_cycles": hi["max_cycles"],
        "emission_cost": hi["emission_cost"],
    }
    return {
        "largest_field": {"scene": "field", "n_robots": hi["n_robots"]},
        "largest_stationary_field": {"scene": "field", "n_robots": hi["n_robots"], "mobile_fraction": 0.0},
        "largest_neighborhood": {"scene": "neighborhood", "w": hi["w"], "v": hi["v"], **extremes},
        "largest_noisy_neighborhood": {
            "scene": "neighborhood",
            "w": hi["w"],
            "v": hi["v"],
            "miss_probability": below_one,
            "miss_tolerance": hi["miss_tolerance"],
        },
        # a dense field with every range at its top: all robots see each other, the fast ones cross the
        # arena many times per step
        "dense_field_extremes": {
            "scene": "field",
            "n_robots": dense_max_n,
            "separation": hi["separation"],
            "mobile_fraction": 1.0,
            "speed": hi["speed"],
            "wireless_range": hi["wireless_range"],
            "visual_range": hi["visual_range"],
            "miss_probability": below_one,
            **extremes,
        },
        # the smallest sparse field with the same extremes (every robot in range of every other)
        "sparse_field_extremes": {
            "scene": "field",
            "n_robots": dense_max_n + 1,
            "separation": hi["separation"],
            "mobile_fraction": 1.0,
            "speed": hi["speed"],
            "wireless_range": hi["wireless_range"],
            "visual_range": hi["visual_range"],
            "miss_probability": below_one,
            **extremes,
        },
    }
