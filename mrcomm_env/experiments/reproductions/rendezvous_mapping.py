"""Reproduction of Chapman & Sukkarieh (paper 004): Fig. 4 partition, Fig. 6 sample run, Figs 8–10 sweeps.

``run(out_dir, quick, tiny=False)`` writes CSV/JSON and PNGs into ``out_dir`` and returns a markdown section; every
episode runs through the shared episode loop (:func:`.common.run_episode`). The paper's
figures are plots without tabulated values (and the text of the paper we have carries none of their
numbers), so the comparison is with the paper's *statements*, checked one by one.

* Fig. 4 — one planning round of ten vehicles spread over the 10,000 m² area, d_comms = 10: the
  assignment, the main cluster, l_c and the outliers cut at every pass of eq. (7)–(8).
* Fig. 6 — det P / det P₀ of the fused map over the decision phases of a sample run (10 vehicles, 200
  landmarks) under ``paper_protocol``, the other planners beside it.
* Figs 8–10 — decision phases until the fused map holds 50 % of the available information, against the mean
  clustering coefficient C of the landmark graph (d_max graph for Figs 8–9, d_comms graph for Fig. 10) on the
  map the vehicles plan with, over Monte-Carlo landmark draws along a ladder of σ: d_comms = ∞, d_max = 15
  (Fig. 8); d_comms = 0, d_max = 15 (Fig. 9); d_comms = 10, d_max = 30 (Fig. 10; t_window = 30 s at u = 1 m/s).
  A run that does not reach 50 % within the cap counts as the cap (censored; the table says how many). Each run
  also reports, at the cap, the fused map's information, the union of every vehicle's map (what the subgroups
  hold between them), the fraction of phases the team was connected and how long the vehicles loitered.

The setup (:data:`SETUP_TABLE`) is derived from the paper's text setting by setting, never tuned toward a
verdict: one layout set for the three figures (64 landmarks on a 12.5 m grid) and a prior map error of 0.5 m (so
the grid the vehicles plan on has the C = 0 the paper gives it); at the env's sensor the vehicles loiter at
C = 0, as §VI-B.2 says they do (measured per run). Each statement of §VI-B is tested with
a bootstrap interval on its effect (:func:`check_claims`), and a sensitivity table flips each setting the paper
does not state (:data:`VARIANTS`). The clumped layouts (the env's ``clumping``) are our extension, reported
apart.
"""

from __future__ import annotations

import csv
import math
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.collections import LineCollection
from scipy.stats import spearmanr

from mrcomm_baselines import make_policy
from mrcomm_env.experiments.evaluation import limit_threads
from mrcomm_env.experiments.reproductions.common import (
    atomic_open,
    atomic_write_csv,
    atomic_write_json,
    figure,
    label_axes,
    pick,
    run_episode,
    run_sweeps,
    size_of,
    task,
)
from mrcomm_env.rendezvous import protocol, theory, world
from mrcomm_env.rendezvous.env import RendezvousMappingEnv

EXPERIMENTS = {
    "fig4_partition": "the partition passes of one planning round (10 vehicles, 200 landmarks, d_comms = 10)",
    "fig6_sample_run": "det P / det P0 of the fused map over decision phases, 10 vehicles, 200 landmarks",
    "fig8_infinite_comms": "phases to 50 % information vs d_max-graph C, d_comms = inf, d_max = 15",
    "fig9_zero_comms": "phases to 50 % information vs d_max-graph C, d_comms = 0, d_max = 15",
    "fig10_long_window": "phases to 50 % information vs d_comms-graph C, d_comms = 10, d_max = 30",
    "claims": "the paper's qualitative statements of §VI-B, one by one",
    "decision_phase_ms": "wall time of one decision phase (policy + env step) under paper_protocol, 10 × 200",
}

SCENARIOS: dict[str, dict[str, Any]] = {
    "fig8_infinite_comms": {"d_comms": math.inf, "t_window": 15.0, "graph": "d_max", "figure": "Fig. 8"},
    "fig9_zero_comms": {"d_comms": 0.0, "t_window": 15.0, "graph": "d_max", "figure": "Fig. 9"},
    "fig10_long_window": {"d_comms": 10.0, "t_window": 30.0, "graph": "d_comms", "figure": "Fig. 10"},
}
#: the env arguments of Figs 8–10 that the paper leaves open, as :data:`SETUP_TABLE` derives them: one landmark
#: set for the three figures, and a prior map close enough to the truth that the grid the vehicles plan on has
#: the C = 0 the paper gives it; the sensor is the env's default (at which the vehicles loiter at C = 0, §VI-B.2)
SETUP: dict[str, Any] = {"n_landmarks": 64, "prior_sigma": 0.5, "obs_per_landmark": 5, "start_spread": 0.0}
#: the sensitivity table: each setting the paper does not state, flipped alone from :data:`SETUP`
VARIANTS: dict[str, dict[str, Any]] = {
    "prior σ₀ = 5 m": {"prior_sigma": 5.0},
    "sensor budget 2": {"obs_per_landmark": 2},
    "121 landmarks": {"n_landmarks": 121},
    "spread start (σ_start = 12 m)": {"start_spread": 12.0},
}
#: Figs 8–10's setup, setting by setting: (setting, ours, the paper's sentence that fixes it, or "not stated"
#: with our choice and why)
SETUP_TABLE = [
    ("vehicles", "10", "stated: “a system of 10 vehicles” (§VI-A); “all 10 vehicles” (§VI-B.3)"),
    (
        "area",
        "100 m × 100 m",
        "stated for the sample run: “mapping area of 10000 m²” (§VI-A); §VI-B names no other",
    ),
    (
        "d_comms, d_max",
        "∞, 15 m (Fig. 8); 0, 15 m (Fig. 9); 10 m, 30 m (Fig. 10)",
        "stated: “d_comms ∼ ∞ and d_max = 15”, “d_comms = 0, d_max = 15”, “d_max = 30”, “d_comms = 10” (§VI-B.2–4)",
    ),
    ("speed u", "1 m/s, so t_window = d_max / u", "not stated: only “d_max = u·t_window” (§VI-B)"),
    (
        "landmark layouts",
        "one set for the three figures: an 8 × 8 grid of 64 landmarks (12.5 m apart) shifted by N(0, σ²)",
        "stated: “landmarks of the uniform grid are shifted by δs_x and δs_y … ∼ N(0, σ²)” and “C measured from "
        "these manufactured d_comms and d_max graphs” (§VI-B.1), one set in two graphs. The count is not stated: "
        "64 gives the d_max graph of the grid edges and C = 0, as “a uniformly distributed grid … globally has "
        "good connectivity but locally has a mean clustering coefficient C of 0”. No grid does that in both "
        "graphs (edges and C = 0 need a spacing of 10.6–15 m at d_max = 15, 7.1–10 m at d_comms = 10), so the "
        "d_comms graph of the grid has no edges (C = 0); the sensitivity table tries 121 (9.1 m)",
    ),
    (
        "σ values",
        "0, 1, 2, 3, 4, 6, 12, 50 m",
        "not stated (“As σ² increases the graphs connections are re-routed and approach a random graph”, "
        "§VI-B.1): from the grid to a uniformly random layout (σ = half the side)",
    ),
    (
        "clumping",
        "0.2 and 0.35 at σ = 50 m, reported apart",
        "not in the paper: our extension, for C beyond a random layout's; no verdict uses these runs",
    ),
    (
        "prior map error σ₀",
        "0.5 m",
        "not stated (“Vehicles are initialised with a common landmark map estimate”, §III). The vehicles plan "
        "and travel on that map, so C is measured on it; at σ₀ = 5 m the grid has C ≈ 0.45 there (d_max graph, "
        "mean of 10 draws), not the 0 the paper gives it",
    ),
    (
        "C",
        "on the vehicles' common prior map, in the figure's own graph",
        "stated: the d_max graph for Figs 8–9, the d_comms graph for Fig. 10 (their captions, §VI-B.1). On which "
        "map is not stated: the one the vehicles plan with (the true layout's C is in figs8_10_sweeps.csv)",
    ),
    (
        "sensor budget and rate",
        "5 observations per landmark, at 1 Hz, σ_obs = 3 m (the env's defaults)",
        "not stated (eq. (3)’s t_obs·I_obs has no cap). “the vehicles are loitering even when C = 0” "
        "(§VI-B.2) holds at these: a 12.5 m hop (12.5 s) and five observations do not fit one 15 s window, but a "
        "vehicle that exhausts its landmark early in a later window waits for the next decision phase (the "
        "loitering row of the Fig. 8 table, σ = 0). A budget of 2, which fits hop and observations in one window, "
        "is in the sensitivity table",
    ),
    (
        "utility",
        "eq. (1) with t_obs·I_obs capped at what the landmark has left",
        "not stated: the paper's eq. (3) has no cap, and without one an exhausted landmark would still attract",
    ),
    (
        "start",
        "all vehicles at one launch point drawn in the area",
        "not stated for Figs 8–10 (Fig. 4 shows them spread: the sensitivity table tries σ_start = 12 m)",
    ),
    (
        "information measure",
        "the fused map (the union of the vehicles' maps is reported beside it)",
        "stated: “the number of iterations required to gather 50% of the information available in the system” "
        "(§VI-B), and the fusion keeps “a common global map” (§III)",
    ),
    (
        "borders",
        "landmarks shifted across a border are reflected back",
        "“while remaining within the area bounds” (§VI-B.1): how is not stated",
    ),
    (
        "draws",
        "20 layouts per σ (10 per setup in the sensitivity table); seeds from the layout and the draw",
        "not stated: “for a random set of landmark distributions” (§VI-B)",
    ),
]
#: the ladder of layouts (σ of the grid's shift) from the exact grid (C = 0) to a random layout; the clumped
#: layouts are our extension, run and reported apart (no verdict uses them)
LAYOUTS = [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0), (3.0, 0.0), (4.0, 0.0), (6.0, 0.0), (12.0, 0.0), (50.0, 0.0)]
CLUMPED = [(50.0, 0.2), (50.0, 0.35)]
QUICK_LAYOUTS = [(0.0, 0.0), (2.0, 0.0), (6.0, 0.0), (50.0, 0.0)]
#: percentile-bootstrap resamples of the landmark draws for each verdict's interval (95 %)
BOOTSTRAP_RESAMPLES = 1000
#: the statements of §VI-B about Figs 8–10, quoted (paper 004, §VI-B.2–4)
QUOTES = {
    "fig8_less_efficient": "the decision phase performance becomes less efficient as clustering increases",
    "fig8_flat_to_0.3": "The lack of influence of d_max clustering from C = 0 → 0.3 on performance, in figure 8",
    "fig8_module_little": "Overall a Utility and Communication Network module offers little to this scenario.",
    "fig9_shines": "The use of the Utility and Communication Network module shines in high d_max graph clustering",
    "fig9_flat_to_0.3": "The landmark distribution does not become significantly clustered enough until at least "
    "C = 0.3 to take advantage of short rendezvousing distances.",
    "fig10_vastly": "The model improves vastly with increasing d_comms graph clustering",
}
PLANNERS = ("paper_protocol", "no_partition", "always_rendezvous", "greedy")
ENV_ID = "mrcomm/RendezvousMapping-v0"
ARTIFACTS = (
    "fig4_partition.png",
    "fig4_partition.json",
    "fig6_sample_run.csv",
    "fig6_sample_run.png",
    *(f"{name}.png" for name in SCENARIOS),
    "figs8_10_sweeps.csv",
    "results.json",
)


# ----------------------------------------------------------------------------------- one run
def episode_to_cap(
    env_kwargs: dict, planner: str, seed: int, cap: int, idle: list | None = None
) -> tuple[RendezvousMappingEnv, dict]:
    """One episode of ``planner`` over ``cap`` decision phases: the env at its end, and its metrics. ``idle``: a
    list that receives, for every vehicle-window until the fused map holds half the information, the seconds of
    the window the vehicle neither travelled nor observed (:class:`IdleTime`)."""
    env = RendezvousMappingEnv(max_cycles=cap, **env_kwargs)
    clock = IdleTime(env, idle if idle is not None else [])
    return env, run_episode(env, make_policy(ENV_ID, planner), seed, on_reset=clock.reset, on_step=clock.step)


class IdleTime:
    """The time a vehicle loiters (§VI-B.2): of each gathering window, what is left after its travel at speed u
    and one observation interval (1 / ``obs_rate``) per observation it made, from its positions in the local
    views and the ``observations`` of its infos; counted until the fused map holds half the information (the
    span the figures' metric measures)."""

    def __init__(self, env: RendezvousMappingEnv, out: list):
        self.env, self.out = env, out
        self.window = float(env.cfg.t_window)
        self.speed, self.rate = float(env.cfg.speed), float(env.cfg.obs_rate)
        self.before = np.zeros((0, 2))
        self.counting = True

    def reset(self, _observations) -> None:
        self.before = np.array(self.env.local_views().team("position"), dtype=float)
        self.counting = math.isnan(self.env.half_phase)

    def step(self, _step, _observations, _rewards, infos) -> None:
        now = np.array(self.env.local_views().team("position"), dtype=float)
        if infos and self.counting:  # the window that reaches half the information counts too
            travel = np.hypot(*(now - self.before).T) / self.speed
            observing = np.array([infos[a]["observations"] for a in self.env.possible_agents]) / self.rate
            self.out.extend(np.maximum(self.window - travel - observing, 0.0).tolist())
        self.before = now
        self.counting = math.isnan(self.env.half_phase)


def sweep_run(
    scenario: str, sigma: float, clumping: float, draw: int, planner: str, cap: int, setup: dict | None = None
) -> dict:
    """One run of a Figs 8–10 sweep (a sweep task), to the cap: the row of ``figs8_10_sweeps.csv``. ``setup``: the
    env arguments the paper leaves open (:data:`SETUP`, or a variant of the sensitivity table). The landmark
    draw's seed follows from the layout and the draw index alone, so every planner and every setup meets the
    same draws of the shift."""
    spec = SCENARIOS[scenario]
    setup = dict(SETUP if setup is None else setup)
    seed = 1000 * draw + int(10 * sigma) + int(1000_000 * clumping)
    env_kwargs = {"d_comms": spec["d_comms"], "t_window": spec["t_window"], **setup}
    idle: list[float] = []
    env, metrics = episode_to_cap({**env_kwargs, "sigma": sigma, "clumping": clumping}, planner, seed, cap, idle)
    reached = env.half_phase if not math.isnan(env.half_phase) else float(cap)
    finite = math.isfinite(spec["d_comms"])
    # C on the map the vehicles plan with (their common prior map), in each graph; the true layout's beside it
    c_dmax = env.planned_clustering(env.d_max)
    c_dcomms = env.planned_clustering(spec["d_comms"]) if finite else 1.0
    return {
        "scenario": scenario,
        "setup": setup_label(setup),
        "sigma": sigma,
        "clumping": clumping,
        "draw": draw,
        "seed": seed,
        "planner": planner,
        "phases_to_half": reached,
        "censored": reached >= cap,
        "final_info_fraction": metrics["info_fraction"],
        # what the vehicles hold between them: every observation made, fused or not (the union of the maps)
        "union_info_fraction": float(env.information_gain(env.world_count) / env.available),
        "connected_fraction": metrics["connected_fraction"],
        # seconds of a window a vehicle loitered, mean over vehicle-windows until half the information (§VI-B.2)
        "idle_s": float(np.mean(idle)) if idle else 0.0,
        "C_dmax": c_dmax,
        "C_dcomms": c_dcomms,
        "C": c_dmax if spec["graph"] == "d_max" else c_dcomms,
        "C_true": env.clustering(env.d_max if spec["graph"] == "d_max" else spec["d_comms"]),
    }


def setup_label(setup: dict) -> str:
    """The name of a setup in the tables: ``main`` or the variant's."""
    for name, change in VARIANTS.items():
        if setup == {**SETUP, **change}:
            return name
    return "main" if setup == SETUP else ", ".join(f"{k}={v:g}" for k, v in sorted(setup.items()))


#: the planners each figure's statements compare (the sensitivity table runs only these)
CLAIM_PLANNERS = {
    "fig8_infinite_comms": ("paper_protocol", "no_partition"),
    "fig9_zero_comms": ("paper_protocol", "greedy"),
    "fig10_long_window": ("paper_protocol",),
}


def _cap(name: str, size: str) -> int:
    if SCENARIOS[name]["d_comms"] > 0:
        return pick(size, full=60, quick=30, tiny=3)
    return pick(size, full=150, quick=60, tiny=3)  # vehicles that never talk fuse only at rendezvous: a longer cap


def sweep_tasks(name: str, size: str) -> list:
    """The main setup's runs: every planner (the quick run two) over the σ ladder and the clumped layouts."""
    layouts = pick(size, full=LAYOUTS + CLUMPED, quick=QUICK_LAYOUTS + CLUMPED[-1:], tiny=QUICK_LAYOUTS[:2])
    draws = pick(size, full=20, quick=2, tiny=1)
    planners = pick(size, full=PLANNERS, quick=("paper_protocol", "greedy"))
    return _tasks(name, layouts, draws, planners, _cap(name, size), SETUP)


def sensitivity_tasks(name: str, size: str) -> list:
    """Each variant of :data:`VARIANTS` over the σ ladder, with the planners the statements compare."""
    layouts = pick(size, full=LAYOUTS, quick=QUICK_LAYOUTS, tiny=QUICK_LAYOUTS[:2])
    draws = pick(size, full=10, quick=2, tiny=1)
    variants = pick(size, full=list(VARIANTS), quick=list(VARIANTS), tiny=list(VARIANTS)[:1])
    return [
        t
        for variant in variants
        for t in _tasks(name, layouts, draws, CLAIM_PLANNERS[name], _cap(name, size), {**SETUP, **VARIANTS[variant]})
    ]


def _tasks(name: str, layouts, draws: int, planners, cap: int, setup: dict) -> list:
    label = setup_label(setup)
    return [
        task(
            sweep_run,
            f"{name} [{label}] sigma={s:g} clumping={k:g} draw={d} {p}",
            scenario=name,
            sigma=s,
            clumping=k,
            draw=d,
            planner=p,
            cap=cap,
            setup=setup,
        )
        for s, k in layouts
        for d in range(draws)
        for p in planners
    ]


def summarise(rows: list[dict]) -> dict:
    """Per planner and layout: mean C, the median phases with their range over draws, the censored count, and the
    median information (fused, union) and connected fraction at the cap.

    Medians, because a censored run only says "at least the cap": a mean and a t-interval would treat the cap
    as a measurement."""
    out: dict = {}
    for r in rows:
        out.setdefault(r["planner"], {}).setdefault((r["sigma"], r["clumping"]), []).append(r)
    table: dict[str, list[dict]] = {}
    for planner, by_layout in out.items():
        table[planner] = []
        for (sigma, clumping), rs in sorted(by_layout.items()):
            phases = [r["phases_to_half"] for r in rs]
            table[planner].append(
                {
                    "sigma": sigma,
                    "clumping": clumping,
                    "C": float(np.mean([r["C"] for r in rs])),
                    "C_true": float(np.mean([r.get("C_true", r["C"]) for r in rs])),
                    "median": float(np.median(phases)),
                    "min": float(min(phases)),
                    "max": float(max(phases)),
                    "censored": int(sum(r["censored"] for r in rs)),
                    "final_info": float(np.median([r["final_info_fraction"] for r in rs])),
                    "union_info": float(np.median([r["union_info_fraction"] for r in rs])),
                    "connected": float(np.median([r["connected_fraction"] for r in rs])),
                    "idle": float(np.median([r.get("idle_s", math.nan) for r in rs])),
                    "n": len(rs),
                }
            )
    return table


def spearman(x, y) -> float:
    """Rank correlation (ties averaged); nan when either side is constant."""

    if len(set(x)) < 2 or len(set(y)) < 2:
        return math.nan
    return float(spearmanr(x, y).statistic)


# ----------------------------------------------------------------------------------- Fig. 4
def fig4(out: Path) -> str:

    rng = np.random.default_rng(4)
    side, L, n, d_comms, t_window = 100.0, 200, 10, 10.0, 15.0
    landmarks = world.jittered_grid(L, side, 3.0, rng)
    for _ in range(200):  # a start that needs a few passes, as the six plots of the paper's figure do
        centre = rng.uniform(25, 75, size=2)
        vehicles = np.clip(centre + rng.normal(0, 12.0, size=(n, 2)), 0, side)
        Y = np.broadcast_to(np.eye(2) * theory.prior_information(5.0), (L, 2, 2))
        U = protocol.utility_matrix(
            Y, np.zeros(L), vehicles, landmarks, 1.0, t_window, theory.information_per_observation(3.0), 1.0, 5
        )
        rec = protocol.recommend(U, landmarks, d_comms, record=True)
        if 3 <= len(rec.steps) <= 6:
            break
    steps = rec.steps
    panels = 1 + len(steps)
    cols = min(panels, 4)
    rows_n = math.ceil(panels / cols)
    adj = world.landmark_graph(landmarks, d_comms)
    ii, jj = np.nonzero(np.triu(adj))

    def base(ax, working):
        ax.add_collection(LineCollection(np.stack([landmarks[ii], landmarks[jj]], 1), colors="0.88", linewidths=0.4))
        cut = np.setdiff1d(np.arange(L), working)
        ax.scatter(landmarks[working, 0], landmarks[working, 1], marker="x", s=10, c="0.4")
        ax.scatter(
            landmarks[cut, 0],
            landmarks[cut, 1],
            marker="o",
            s=12,
            facecolors="none",
            edgecolors="tab:red",
            linewidths=0.6,
        )
        ax.scatter(vehicles[:, 0], vehicles[:, 1], marker="s", s=30, c="tab:blue")
        ax.set_xlim(0, side)
        ax.set_ylim(0, side)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])

    size_in = (4 * cols, 4 * rows_n)
    with figure(out / "fig4_partition.png", figsize=size_in, nrows=rows_n, ncols=cols, dpi=110) as (fig, grid):
        axes = np.asarray(grid, dtype=object).reshape(rows_n, cols)  # one row of panels comes back one-dimensional
        base(axes[0, 0], np.arange(L))
        axes[0, 0].set_title("1: vehicles (squares), landmarks, d_comms graph", fontsize=8)
        for k, st in enumerate(steps):
            ax = axes[(k + 1) // cols, (k + 1) % cols]
            base(ax, st.working)
            for v in range(n):
                lm = st.assignment[v]
                colour = "tab:green" if st.cluster_of[v] == st.main else "tab:orange"
                ax.plot([vehicles[v, 0], landmarks[lm, 0]], [vehicles[v, 1], landmarks[lm, 1]], ":", c=colour, lw=1)
                ax.scatter(*landmarks[lm], marker="D", s=18, c=colour, zorder=3)
            ax.scatter(*landmarks[st.central], marker="*", s=160, c="gold", edgecolors="k", zorder=4)
            if st.outlier >= 0:
                ax.scatter(*landmarks[st.outlier], marker="o", s=90, facecolors="none", edgecolors="tab:red", lw=1.5)
                axis = landmarks[st.outlier] - landmarks[st.central]
                normal = np.array([-axis[1], axis[0]]) / max(np.hypot(*axis), 1e-9)
                line = np.stack([landmarks[st.outlier] - 200 * normal, landmarks[st.outlier] + 200 * normal])
                ax.plot(line[:, 0], line[:, 1], "--", c="tab:red", lw=0.8)
            state = "connected" if st.outlier < 0 else f"cut l_o = {st.outlier}"
            ax.set_title(f"{k + 2}: pass {k + 1}, |l_w| = {len(st.working)}, l_c = {st.central}, {state}", fontsize=8)
        for k in range(panels, rows_n * cols):
            axes[k // cols, k % cols].axis("off")
        fig.suptitle(
            "Fig. 4: partition passes (green: main cluster μ_max, orange: other clusters, star: l_c, "
            "red circles: cut landmarks)",
            fontsize=9,
        )
    atomic_write_json(
        out / "fig4_partition.json",
        {
            "passes": len(steps),
            "connected": rec.connected,
            "working_sizes": [int(len(s.working)) for s in steps],
            "central": [s.central for s in steps],
            "outliers": [s.outlier for s in steps],
        },
        indent=2,
    )
    return (
        f"Fig. 4: {len(steps)} passes, working set "
        f"{' → '.join(str(len(s.working)) for s in steps)} landmarks, "
        f"{'connected' if rec.connected else 'marked unconnected'} at the end."
    )


# ----------------------------------------------------------------------------------- Fig. 6
def fig6_run(planner: str, phases: int) -> list[float]:
    """log10 det P / det P0 of the fused map before the first phase and after each (a sweep task; seed 6)."""
    env = RendezvousMappingEnv(max_cycles=phases)
    log10 = [0.0]  # det P = det P0 before the first phase

    def record(*_):
        log10.append(env.metrics()["log10_det_ratio"])

    run_episode(env, make_policy(ENV_ID, planner), 6, on_step=record)
    return log10


def fig6_tasks(size: str) -> list:
    phases = pick(size, full=120, quick=25, tiny=3)
    planners = pick(size, full=PLANNERS, quick=("paper_protocol", "greedy"))
    return [task(fig6_run, f"fig6 {planner}", planner=planner, phases=phases) for planner in planners]


def fig6(out: Path, tasks: list, results: list[list[float]]) -> tuple[str, dict]:
    curves = {t.kwargs["planner"]: log10 for t, log10 in zip(tasks, results, strict=True)}
    with atomic_open(out / "fig6_sample_run.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["phase", *curves])
        for k in range(max(len(c) for c in curves.values())):
            w.writerow([k, *[c[k] if k < len(c) else "" for c in curves.values()]])
    with figure(out / "fig6_sample_run.png", figsize=(6, 4), dpi=110) as (_, ax):
        for planner, c in curves.items():
            ax.plot(range(len(c)), c, label=planner)
        label_axes(
            ax,
            xlabel="decision phase",
            ylabel="log10 det(P) / det(P0) of the fused map",
            title="Fig. 6: 10 vehicles, 200 landmarks, d_comms = 10, d_max = 15",
            legend=8,
        )
    paper = curves["paper_protocol"]
    monotone = all(b <= a + 1e-12 for a, b in zip(paper, paper[1:]))
    md = (
        f"Fig. 6: under `paper_protocol` log₁₀ det P/det P₀ falls from 0 to "
        f"{paper[-1]:.1f} in {len(paper) - 1} phases, never rising ({'holds' if monotone else 'FAILS'}: fused "
        "information never decreases). The paper plots the same decreasing curve without numbers in the text."
    )
    return md, {"final_log10": {k: c[-1] for k, c in curves.items()}, "monotone": monotone}


def plot_sweep(out: Path, name: str, table: dict, rows: list[dict]) -> None:
    """Phases to 50 % against C: every draw as a point, the median per layout as a line, per planner. The x axis
    spans C's whole range [0, 1], as the paper's Figs 8–10 do (they print no numbers to match beyond it)."""
    spec = SCENARIOS[name]
    with figure(out / f"{name}.png", figsize=(6, 4), dpi=110) as (_, ax):
        for k, (planner, summary) in enumerate(table.items()):
            mine = [r for r in rows if r["planner"] == planner]
            ax.scatter([r["C"] for r in mine], [r["phases_to_half"] for r in mine], s=8, alpha=0.35, color=f"C{k}")
            ax.plot([r["C"] for r in summary], [r["median"] for r in summary], marker="o", color=f"C{k}", label=planner)
        ax.set_xlim(0.0, 1.0)
        label_axes(
            ax,
            xlabel=f"mean clustering coefficient C of the {spec['graph']} graph",
            ylabel="decision phases to 50 % of the information",
            title=f"{spec['figure']}: d_comms = {spec['d_comms']:g}, d_max = {spec['t_window']:g}",
            legend=8,
        )


# ----------------------------------------------------------------------------------- claims
def paper_layouts(rows: list[dict]) -> list[dict]:
    """The runs on the paper's own layouts: the σ shift alone (the clumped layouts are our extension)."""
    return [r for r in rows if r["clumping"] == 0.0]


def _median_phases(rows: list[dict], planner: str) -> float:
    values = [r["phases_to_half"] for r in rows if r["planner"] == planner]
    return float(np.median(values)) if values else math.nan


def _layout_medians(rows: list[dict], planner: str) -> list[tuple[float, float, float]]:
    """(σ, mean C, median phases) per layout of ``planner``'s runs, in increasing σ."""
    by_sigma: dict[float, list[dict]] = {}
    for r in rows:
        if r["planner"] == planner:
            by_sigma.setdefault(r["sigma"], []).append(r)
    return [
        (sigma, float(np.mean([r["C"] for r in rs])), float(np.median([r["phases_to_half"] for r in rs])))
        for sigma, rs in sorted(by_sigma.items())
    ]


def rho_of(rows: list[dict], planner: str = "paper_protocol") -> float:
    """Spearman's ρ of C and phases to 50 % over ``planner``'s runs."""
    mine = [r for r in rows if r["planner"] == planner]
    return spearman([r["C"] for r in mine], [r["phases_to_half"] for r in mine])


def low_clustering_sigmas(rows: list[dict], c_max: float = 0.3) -> list[float]:
    """The σ of the layouts whose mean C (over all their runs) is below ``c_max``: the span “C = 0 → 0.3”."""
    return [sigma for sigma, c, _ in _layout_medians(rows, "paper_protocol") if c < c_max]


def flat_change(rows: list[dict], sigmas: list[float]) -> float:
    """Relative change of the median phases from the first layout of ``sigmas`` (the grid) to the last: the
    influence of clustering over that span (nan below two layouts). The span is fixed by the caller on all the
    runs, so that a resample cannot move a layout in or out of it."""
    if len(sigmas) < 2:
        return math.nan
    medians = {sigma: m for sigma, _, m in _layout_medians(rows, "paper_protocol")}
    first, last = medians.get(sigmas[0], math.nan), medians.get(sigmas[-1], math.nan)
    return last / first - 1.0 if first > 0 else math.nan


def relative_difference(rows: list[dict], planner: str, other: str) -> float:
    """|median phases of ``planner`` − of ``other``| over ``other``'s."""
    a, b = _median_phases(rows, planner), _median_phases(rows, other)
    return abs(a - b) / b if b > 0 else math.nan


def gap_at_highest_sigma(rows: list[dict], planner: str = "paper_protocol", other: str = "greedy") -> float:
    """Median phases of ``planner`` minus ``other``'s on the most shifted layout."""
    top = max(r["sigma"] for r in rows)
    mine = [r for r in rows if r["sigma"] == top]
    return _median_phases(mine, planner) - _median_phases(mine, other)


def relative_drop(rows: list[dict], planner: str = "paper_protocol") -> float:
    """1 − median phases on the most shifted layout over those on the grid (σ = 0)."""
    medians = _layout_medians(rows, planner)
    return 1.0 - medians[-1][2] / medians[0][2] if len(medians) >= 2 and medians[0][2] > 0 else math.nan


def bootstrap_interval(rows: list[dict], statistic, seed: int, resamples: int = BOOTSTRAP_RESAMPLES):
    """(estimate, low, high): ``statistic`` of ``rows`` and its 95 % percentile-bootstrap interval. Each resample
    draws the landmark draws of every layout with replacement, keeping all planners of a draw together (they
    met the same landmarks), so the interval reflects the draws, the only randomness between runs. The
    resampling is seeded: the same runs give the same interval."""
    estimate = statistic(rows)
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["sigma"], r["clumping"], r["draw"]), []).append(r)
    layouts: dict[tuple, list[tuple]] = {}
    for key in groups:
        layouts.setdefault(key[:2], []).append(key)
    rng = np.random.default_rng(seed)
    values = []
    for _ in range(resamples):
        sample = []
        for keys in layouts.values():
            for pick_ in rng.integers(0, len(keys), size=len(keys)):
                sample.extend(groups[keys[pick_]])
        value = statistic(sample)
        if math.isfinite(value):
            values.append(value)
    if len(values) < resamples // 2 or not math.isfinite(estimate):
        return estimate, math.nan, math.nan
    low, high = np.percentile(values, [2.5, 97.5])
    return estimate, float(low), float(high)


def side_of(interval: tuple[float, float, float], threshold: float, claimed: str) -> str | None:
    """``holds`` when the whole interval is on the claimed side of ``threshold`` (``above`` or ``below``),
    ``fails`` when it is wholly on the other side, ``inconclusive`` when it straddles it, None untestable."""
    _, low, high = interval
    if not (math.isfinite(low) and math.isfinite(high)):
        return None
    above, below = low > threshold, high < threshold  # strictly: an interval that touches the bar straddles it
    if claimed == "above":
        return "holds" if above else "fails" if below else "inconclusive"
    return "holds" if below else "fails" if above else "inconclusive"


def within(interval: tuple[float, float, float], bound: float) -> str | None:
    """``holds`` when the whole interval lies within ±``bound``, ``fails`` when wholly outside it on one side,
    ``inconclusive`` otherwise, None untestable."""
    _, low, high = interval
    if not (math.isfinite(low) and math.isfinite(high)):
        return None
    if -bound <= low and high <= bound:
        return "holds"
    return "fails" if low > bound or high < -bound else "inconclusive"


def both(*verdicts: str | None) -> str | None:
    """A claim of several parts: it fails if one part fails, holds if all hold."""
    if any(v is None for v in verdicts):
        return None
    if "fails" in verdicts:
        return "fails"
    return "holds" if all(v == "holds" for v in verdicts) else "inconclusive"


def _interval_text(name: str, interval: tuple[float, float, float], percent: bool = False) -> str:
    estimate, low, high = interval
    scale, unit = (100.0, " %") if percent else (1.0, "")
    if not math.isfinite(estimate):
        return f"{name} not measurable"
    if not (math.isfinite(low) and math.isfinite(high)):
        return f"{name} = {scale * estimate:+.2f}{unit}"
    return f"{name} = {scale * estimate:+.2f}{unit} [{scale * low:+.2f}, {scale * high:+.2f}]"


def check_claims(rows: dict[str, list[dict]], resamples: int = BOOTSTRAP_RESAMPLES) -> list[dict]:
    """The statements of §VI-B on Figs 8–10, quoted one by one, each tested on the runs of the paper's layouts
    (the σ shift alone) with the effect it names and its 95 % bootstrap interval over the landmark draws:
    ``holds`` when the interval lies on the claimed side of the claim's bar, ``fails`` when on the other,
    ``inconclusive`` when it straddles it, ``None`` when the runs cannot test it."""
    claims = []

    def claim(figure: str, key: str, measure: str, verdict: str | None, **effects) -> None:
        claims.append({"figure": figure, "claim": QUOTES[key], "key": key, "measure": measure, "holds": verdict})
        claims[-1].update(effects)

    def interval(rows_, statistic, seed):
        return bootstrap_interval(rows_, statistic, seed, resamples)

    fig8 = paper_layouts(rows["fig8_infinite_comms"])
    fig9 = paper_layouts(rows["fig9_zero_comms"])
    fig10 = paper_layouts(rows["fig10_long_window"])
    rho8 = interval(fig8, rho_of, 8)
    claim(
        "Fig. 8",
        "fig8_less_efficient",
        _interval_text("ρ(C, phases)", rho8) + " (bar: ρ > 0)",
        side_of(rho8, 0.0, "above"),
        rho=rho8,
    )
    measure, verdict, effects = _flat_claim(fig8, interval, 80, "flat")
    claim("Fig. 8", "fig8_flat_to_0.3", measure, verdict, **effects)
    planners8 = {r["planner"] for r in fig8}
    if "no_partition" in planners8:
        little = interval(fig8, lambda rs: relative_difference(rs, "paper_protocol", "no_partition"), 81)
        claim(
            "Fig. 8",
            "fig8_module_little",
            _interval_text("|paper_protocol − no_partition| / no_partition", little, True) + " (bar: within 10 %)",
            side_of(little, 0.1, "below"),
            difference=little,
        )
    rho9 = interval(fig9, rho_of, 9)
    if "greedy" in {r["planner"] for r in fig9}:
        gap9 = interval(fig9, gap_at_highest_sigma, 90)
        claim(
            "Fig. 9",
            "fig9_shines",
            _interval_text("ρ(C, phases)", rho9)
            + "; on the most shifted layout "
            + _interval_text("paper_protocol − greedy phases", gap9)
            + " (bar: ρ < 0 and fewer phases than greedy)",
            both(side_of(rho9, 0.0, "below"), side_of(gap9, 0.0, "below")),
            rho=rho9,
            gap=gap9,
        )
    measure, verdict, effects = _flat_claim(fig9, interval, 91, "a horizontal line")
    claim("Fig. 9", "fig9_flat_to_0.3", measure, verdict, **effects)
    rho10 = interval(fig10, rho_of, 10)
    drop10 = interval(fig10, relative_drop, 100)
    claim(
        "Fig. 10",
        "fig10_vastly",
        _interval_text("ρ(C, phases)", rho10)
        + "; "
        + _interval_text("drop of the median phases from σ = 0 to the most shifted layout", drop10, True)
        + " (bar: ρ < 0 and at least 20 % fewer)",
        both(side_of(rho10, 0.0, "below"), side_of(drop10, 0.2, "above")),
        rho=rho10,
        drop=drop10,
    )
    return claims


def _flat_claim(rows: list[dict], interval, seed: int, what: str) -> tuple:
    """(measure, verdict, effects) of a “no influence of C from 0 to 0.3” statement, the effect ``change``: the
    change of the median phases across the layouts with C < 0.3, within ±20 %."""
    sigmas = low_clustering_sigmas(rows)
    if len(sigmas) < 2:
        return f"not testable: {len(sigmas)} layout(s) with C < 0.3", None, {}
    change = interval(rows, lambda rs: flat_change(rs, sigmas), seed)
    measure = (
        _interval_text(
            f"change of the median phases from σ = {sigmas[0]:g} to σ = {sigmas[-1]:g} (the layouts with C < 0.3)",
            change,
            True,
        )
        + f" (bar: {what}, within ±20 %)"
    )
    return measure, within(change, 0.2), {"change": change}


def sensitivity(rows: dict[str, list[dict]], resamples: int = BOOTSTRAP_RESAMPLES) -> dict[str, list[dict]]:
    """The claims' verdicts under each setup (the main one and each variant): ``{setup: claims}``."""
    present = {r["setup"] for rs in rows.values() for r in rs}
    setups = [s for s in ["main", *VARIANTS] if s in present]
    return {
        setup: check_claims({k: [r for r in rs if r["setup"] == setup] for k, rs in rows.items()}, resamples)
        for setup in setups
    }


# ----------------------------------------------------------------------------------- timing
class _TimedPolicy:
    """A policy whose ``act`` is clocked, so that the shared episode loop can split a phase into planning and
    env step: the env step is the time from the end of ``act`` to the loop's ``on_step``."""

    def __init__(self, policy):
        self.policy = policy
        self.act_start_cpu = math.nan
        self.act_start = math.nan
        self.act_end = math.nan

    def reset(self, views, seed):
        self.policy.reset(views, seed)

    def act(self, observations, views):
        self.act_start_cpu = time.process_time()
        self.act_start = time.perf_counter()
        actions = self.policy.act(observations, views)
        self.act_end = time.perf_counter()
        return actions


def time_decision_phase(phases: int = 30, seed: int = 0, **env_kwargs) -> dict[str, float]:
    """Median time (ms) of one decision phase under ``paper_protocol`` (10 vehicles, 200 landmarks by
    default): the policy's planning, the env step (window, fusion, the env's own plan), and both, in wall time
    and in this process's CPU time (``cpu_ms``: what the phase costs on one core when the machine is shared).

    This is the benchmark for the issue's goal of < 50 ms on one core; ``mrcomm bench`` can call it.
    """
    env = RendezvousMappingEnv(max_cycles=phases + 1, **env_kwargs)
    policy = _TimedPolicy(make_policy(ENV_ID, "paper_protocol"))
    t_policy, t_env, cpu = [], [], []

    def record(step, *_):
        t_env.append(1e3 * (time.perf_counter() - policy.act_end))
        cpu.append(1e3 * (time.process_time() - policy.act_start_cpu))
        t_policy.append(1e3 * (policy.act_end - policy.act_start))
        return step + 1 >= phases

    run_episode(env, policy, seed, on_step=record)
    total = [a + b for a, b in zip(t_policy, t_env)]
    return {
        "policy_ms": statistics.median(t_policy),
        "env_step_ms": statistics.median(t_env),
        "decision_phase_ms": statistics.median(total),
        "decision_phase_cpu_ms": statistics.median(cpu),
        "max_decision_phase_ms": max(total),
        "phases": len(total),
    }


# ----------------------------------------------------------------------------------- report
def run(out_dir: Path, quick: bool, tiny: bool = False) -> str:

    limit_threads()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    size = size_of(quick, tiny)
    start = time.perf_counter()

    fig4_md = fig4(out)
    # the Monte-Carlo runs, Fig. 6's sample runs and the three sweeps, as one sweep of independent tasks
    plan = {"fig6": fig6_tasks(size), **{scenario: sweep_tasks(scenario, size) for scenario in SCENARIOS}}
    plan.update({f"{scenario} sensitivity": sensitivity_tasks(scenario, size) for scenario in SCENARIOS})
    results = run_sweeps(out, plan, "Figs 6, 8–10: setups × planners × σ × draws")
    fig6_md, fig6_res = fig6(out, plan["fig6"], results["fig6"])
    rows, tables, every_setup = {}, {}, {}
    for scenario in SCENARIOS:
        rows[scenario] = results[scenario]
        every_setup[scenario] = rows[scenario] + results[f"{scenario} sensitivity"]
        tables[scenario] = summarise(rows[scenario])
        plot_sweep(out, scenario, tables[scenario], rows[scenario])
    write_sweep_rows(out / "figs8_10_sweeps.csv", [r for scenario in SCENARIOS for r in every_setup[scenario]])
    resamples = pick(size, full=BOOTSTRAP_RESAMPLES, quick=200, tiny=20)
    claims = check_claims(rows, resamples)
    verdicts = sensitivity(every_setup, resamples)
    timing = time_decision_phase(phases=pick(size, full=40, quick=10, tiny=2))
    atomic_write_json(
        out / "results.json",
        {
            "setup": SETUP,
            "variants": VARIANTS,
            "fig6": fig6_res,
            "tables": tables,
            "claims": claims,
            "sensitivity": verdicts,
            "timing": timing,
            "quick": quick,
            "seconds": time.perf_counter() - start,
        },
        indent=2,
        default=float,
    )

    return report(out.name, size, fig4_md, fig6_md, tables, claims, verdicts, timing)


VERDICT = {"holds": "yes", "fails": "**no**", "inconclusive": "inconclusive", None: "n/a"}


def report(
    name: str,
    size: str,
    fig4_md: str,
    fig6_md: str,
    tables: dict,
    claims: list[dict],
    verdicts: dict[str, list[dict]],
    timing: dict,
) -> str:
    """The markdown section: Figs 4 and 6, the setup of Figs 8–10, their tables, the paper's statements with
    intervals, the sensitivity of each verdict to what the paper does not state, the timing."""
    lines = ["## RendezvousMapping-v0 — Chapman & Sukkarieh, decentralised mapping with limited connectivity", ""]
    if size == "quick":
        lines += [
            "*Quick run: four σ layouts and one clumped, two landmark draws each, two planners, a 30-phase cap (60 "
            "at d_comms = 0), 200 bootstrap resamples. Run without `--quick` for the full sweep (eight σ layouts "
            "and two clumped, 20 draws, four planners, a 60-phase cap, 150 at d_comms = 0, 10 draws per setup in "
            "the sensitivity table, 1,000 resamples): with two draws most intervals straddle their bar.*",
            "",
        ]
    elif size == "tiny":
        lines += ["*Tiny run (smoke-test sizes, a 3-phase cap): the numbers mean nothing.*", ""]
    lines += [
        fig4_md,
        "",
        f"![Fig. 4]({name}/fig4_partition.png)",
        "",
        fig6_md,
        "",
        f"![Fig. 6]({name}/fig6_sample_run.png)",
        "",
        "**The setup of Figs 8–10**, setting by setting from the paper's text (§VI-B unless marked); where the text "
        "leaves a setting open, our choice and why. The sensitivity table below flips each unstated one.",
        "",
        "| setting | ours | the paper |",
        "| --- | --- | --- |",
        *(f"| {setting} | {ours} | {paper} |" for setting, ours, paper in SETUP_TABLE),
        "",
    ]
    for scenario, spec in SCENARIOS.items():
        lines += sweep_section(scenario, spec, tables[scenario], name)
    lines += [
        "**The paper's statements** on Figs 8–10, quoted (its figures give no numbers in the text), each tested on "
        "the runs of the paper's layouts (the σ shift alone; the clumped layouts are not used) with the effect it "
        "names and a 95 % bootstrap interval over the landmark draws: *yes* when the interval clears the bar, "
        "**no** when it lies on the other side, *inconclusive* when it straddles it.",
        "",
        "| figure | the paper says | ours | holds |",
        "| --- | --- | --- | --- |",
    ]
    # a run of two draws per layout (quick, tiny) resamples two values: its intervals are far too narrow to decide
    mark = "" if size == "full" else " ¹"
    lines += [f"| {c['figure']} | “{c['claim']}” | {c['measure']} | {VERDICT[c['holds']]}{mark} |" for c in claims]
    if mark:
        lines += [
            "",
            "¹ Two landmark draws per layout: a bootstrap of two values, indicative only; the full run decides.",
        ]
    setups = list(verdicts)
    lines += [
        "",
        "**Sensitivity** of each verdict to the settings the paper does not state: the main setup, then each "
        "unstated setting flipped alone ("
        + "; ".join(f"{k}: " + ", ".join(f"`{a}` = {v:g}" for a, v in change.items()) for k, change in VARIANTS.items())
        + "), with the "
        "planners each statement compares. The clumped layouts are our extension and are in the tables above "
        "only.",
        "",
        "| statement | " + " | ".join(setups) + " |",
        "| --- |" + " --- |" * len(setups),
    ]
    keys = [c["key"] for c in claims]
    for key in keys:
        cells = []
        for setup in setups:
            found = [c for c in verdicts[setup] if c["key"] == key]
            cells.append(_sensitivity_cell(found[0]) + mark if found else "n/a")
        figure_ = next(c["figure"] for c in claims if c["key"] == key)
        lines.append(
            f"| {figure_}: “{QUOTES[key][:60]}{'…' if len(QUOTES[key]) > 60 else ''}” | " + " | ".join(cells) + " |"
        )
    lines += [
        "",
        f"Decision phase under `paper_protocol`, 10 vehicles × 200 landmarks, median of "
        f"{timing['phases']} phases on one thread: {timing['decision_phase_ms']:.1f} ms wall, "
        f"{timing['decision_phase_cpu_ms']:.1f} ms CPU (policy "
        f"{timing['policy_ms']:.1f} ms + env step {timing['env_step_ms']:.1f} ms); goal < 50 ms.",
        "",
    ]
    return "\n".join(lines)


def _sensitivity_cell(claim: dict) -> str:
    """The verdict and the effect it rests on, short: ρ, the spread, the difference or the drop."""
    parts = []
    for name, percent in (("rho", False), ("change", True), ("difference", True), ("gap", False), ("drop", True)):
        if name in claim:
            estimate, low, high = claim[name]
            scale = 100.0 if percent else 1.0
            unit = " %" if percent else ""
            label = {"rho": "ρ", "change": "change", "difference": "diff.", "gap": "gap", "drop": "drop"}[name]
            if math.isfinite(estimate):
                span = f" [{scale * low:.3g}, {scale * high:.3g}]" if math.isfinite(low) else ""
                parts.append(f"{label} {scale * estimate:.3g}{unit}{span}")
    return f"{VERDICT[claim['holds']]} ({'; '.join(parts)})" if parts else VERDICT[claim["holds"]]


def write_sweep_rows(path: Path, rows: list[dict]) -> None:
    """Every run of the Figs 8–10 sweeps, one CSV row each (atomically)."""
    atomic_write_csv(path, rows)


def sweep_section(scenario: str, spec: dict, table: dict, name: str) -> list[str]:
    """One figure's table: per planner and layout, phases to 50 % and the information and connectivity at the cap."""
    layouts = next(iter(table.values()))
    lines = [
        f"**{spec['figure']}**: d_comms = {spec['d_comms']:g}, d_max = {spec['t_window']:g} m, "
        f"{SETUP['n_landmarks']} landmarks; per layout (σ, clumping) and its mean C of the {spec['graph']} graph "
        "on the map the vehicles plan with (and on the true layout): "
        "phases to 50 % of the information, median [min–max] over landmark draws (a censored run did not get "
        "there within the cap); then, at the cap, the median fused / union information and the fraction of "
        "phases connected, and the median time a vehicle loitered per window until half the information (the "
        f"window, {spec['t_window']:g} s, less its travel and one second per observation).",
        "",
        "| planner | "
        + " | ".join(
            f"σ {r['sigma']:g}, k {r['clumping']:g} (C {r['C']:.2f}; true {r.get('C_true', r['C']):.2f})"
            for r in layouts
        )
        + " |",
        "| --- |" + " --- |" * len(layouts),
    ]
    for planner, rs in table.items():
        cells = [
            f"{r['median']:g} [{r['min']:g}–{r['max']:g}]" + (f" ({r['censored']} cens.)" if r["censored"] else "")
            for r in rs
        ]
        lines.append(f"| `{planner}` | " + " | ".join(cells) + " |")
        cells = [f"{r['final_info']:.2f} / {r['union_info']:.2f}, {r['connected']:.2f}, {r['idle']:.1f} s" for r in rs]
        lines.append("| ↳ info fused / union, connected, loitering | " + " | ".join(cells) + " |")
    return [*lines, "", f"![{spec['figure']}]({name}/{scenario}.png)", ""]


def benchmarks() -> dict[str, float]:
    """For ``mrcomm bench``: one decision phase, 10 vehicles and 200 landmarks, ``paper_protocol`` (goal < 50 ms)."""
    timing = time_decision_phase(phases=20, seed=0)
    return {k: float(v) for k, v in timing.items() if k.endswith("ms")}
