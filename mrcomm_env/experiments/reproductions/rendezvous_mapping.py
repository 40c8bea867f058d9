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
  clustering coefficient C of the landmark graph (d_max graph for Figs 8–9, d_comms graph for Fig. 10), over
  Monte-Carlo landmark draws along a ladder of layouts: d_comms = ∞, d_max = 15 (Fig. 8); d_comms = 0,
  d_max = 15 (Fig. 9); d_comms = 10, d_max = 30 (Fig. 10; t_window = 30 s at u = 1 m/s). A run that does not
  reach 50 % within the cap counts as the cap (censored; the table says how many). Each run also reports,
  at the cap, the fused map's information, the union of every vehicle's map (what the subgroups hold between
  them) and the fraction of phases the team was connected.

Layouts (Fig. 7, §VI-B.1). Each figure's grid is coarse enough that its own graph has no triangles at σ = 0:
a square grid of spacing s has C = 0 in the graph of radius d when d/√2 ≤ s < d (neighbours along the grid,
no diagonals). 8 × 8 = 64 landmarks on the 100 m square (s = 12.5 m) for d_max = 15, and 11 × 11 = 121
(s = 9.1 m) for d_comms = 10. The σ shift then raises C to about 0.55 (a uniformly random layout in graphs this
sparse); ``clumping`` (the env's extension) carries it past 0.6. With 64–121 landmarks for 10 vehicles, half of
the information takes about 3–6 phases if no time were lost travelling (each vehicle exhausts about one
landmark per phase at the default sensor: 5 observations per landmark at 1 Hz), a floor below what the
layouts make the planners measure; 200 landmarks put it at about 10 phases, under every run.
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
    "fig8_infinite_comms": {
        "d_comms": math.inf,
        "t_window": 15.0,
        "n_landmarks": 64,
        "graph": "d_max",
        "figure": "Fig. 8",
    },
    "fig9_zero_comms": {"d_comms": 0.0, "t_window": 15.0, "n_landmarks": 64, "graph": "d_max", "figure": "Fig. 9"},
    "fig10_long_window": {
        "d_comms": 10.0,
        "t_window": 30.0,
        "n_landmarks": 121,
        "graph": "d_comms",
        "figure": "Fig. 10",
    },
}
#: the ladder of layouts (σ of the grid's shift, clumping) from the exact grid (C = 0) past a random layout
LAYOUTS = [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0), (3.0, 0.0), (4.0, 0.0), (6.0, 0.0), (12.0, 0.0), (50.0, 0.0)]
LAYOUTS += [(50.0, 0.2), (50.0, 0.35)]
QUICK_LAYOUTS = [(0.0, 0.0), (3.0, 0.0), (50.0, 0.0), (50.0, 0.35)]
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
def episode_to_cap(env_kwargs: dict, planner: str, seed: int, cap: int) -> tuple[RendezvousMappingEnv, dict]:
    """One episode of ``planner`` over ``cap`` decision phases: the env at its end, and its metrics."""
    env = RendezvousMappingEnv(max_cycles=cap, **env_kwargs)
    return env, run_episode(env, make_policy(ENV_ID, planner), seed)


def sweep_run(scenario: str, sigma: float, clumping: float, draw: int, planner: str, cap: int) -> dict:
    """One run of a Figs 8–10 sweep (a sweep task), to the cap: the row of ``figs8_10_sweeps.csv``. The landmark
    draw's seed follows from the layout and the draw index alone, so every planner meets the same landmarks."""
    spec = SCENARIOS[scenario]
    seed = 1000 * draw + int(10 * sigma) + int(1000_000 * clumping)
    env_kwargs = {key: spec[key] for key in ("d_comms", "t_window", "n_landmarks")}
    env, metrics = episode_to_cap({**env_kwargs, "sigma": sigma, "clumping": clumping}, planner, seed, cap)
    reached = env.half_phase if not math.isnan(env.half_phase) else float(cap)
    c_dmax = env.clustering(env.d_max)
    c_dcomms = env.clustering(spec["d_comms"]) if math.isfinite(spec["d_comms"]) else 1.0
    return {
        "scenario": scenario,
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
        "C_dmax": c_dmax,
        "C_dcomms": c_dcomms,
        "C": c_dmax if spec["graph"] == "d_max" else c_dcomms,
    }


def sweep_tasks(name: str, size: str) -> list:
    layouts = pick(size, full=LAYOUTS, quick=QUICK_LAYOUTS, tiny=QUICK_LAYOUTS[:2])
    draws = pick(size, full=20, quick=2, tiny=1)
    planners = pick(size, full=PLANNERS, quick=("paper_protocol", "greedy"))
    if SCENARIOS[name]["d_comms"] > 0:
        cap = pick(size, full=60, quick=30, tiny=3)
    else:  # vehicles that never talk fuse only at rendezvous: a longer cap
        cap = pick(size, full=150, quick=60, tiny=3)
    return [
        task(
            sweep_run,
            f"{name} sigma={s:g} clumping={k:g} draw={d} {p}",
            scenario=name,
            sigma=s,
            clumping=k,
            draw=d,
            planner=p,
            cap=cap,
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
                    "median": float(np.median(phases)),
                    "min": float(min(phases)),
                    "max": float(max(phases)),
                    "censored": int(sum(r["censored"] for r in rs)),
                    "final_info": float(np.median([r["final_info_fraction"] for r in rs])),
                    "union_info": float(np.median([r["union_info_fraction"] for r in rs])),
                    "connected": float(np.median([r["connected_fraction"] for r in rs])),
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
def _flat_below(table_rows: list[dict], c_max: float = 0.3) -> tuple[bool | None, str]:
    """Whether the median phases stay within 20 % of each other over the layouts with C < ``c_max``."""
    low = [r["median"] for r in table_rows if r["C"] < c_max]
    if len(low) < 2:
        return None, f"not testable: {len(low)} layout(s) with C < {c_max}"
    spread = max(low) / min(low) - 1.0
    return spread <= 0.2, f"median phases {min(low):g}–{max(low):g} over the {len(low)} layouts with C < {c_max}"


def _correlation(rows: list[dict], planner: str) -> tuple[float, int]:
    mine = [r for r in rows if r["planner"] == planner]
    return spearman([r["C"] for r in mine], [r["phases_to_half"] for r in mine]), len(mine)


def check_claims(tables: dict, rows: dict) -> list[dict]:
    """The statements of §VI-B on Figs 8–10, quoted one by one, each with the measure that tests it on our runs
    (medians over draws; the direction by Spearman's rank correlation of C and phases over every run)."""
    claims = []

    def claim(figure: str, key: str, measure: str, holds: bool | None) -> None:
        claims.append({"figure": figure, "claim": QUOTES[key], "measure": measure, "holds": holds})

    fig8, fig9, fig10 = rows["fig8_infinite_comms"], rows["fig9_zero_comms"], rows["fig10_long_window"]
    rho, n = _correlation(fig8, "paper_protocol")
    claim("Fig. 8", "fig8_less_efficient", f"Spearman ρ(C, phases) = {rho:+.2f} over {n} runs", bool(rho > 0))
    holds, measure = _flat_below(tables["fig8_infinite_comms"]["paper_protocol"])
    claim("Fig. 8", "fig8_flat_to_0.3", measure + " (flat: within 20 %)", holds)
    if "no_partition" in tables["fig8_infinite_comms"]:
        a = float(np.median([r["phases_to_half"] for r in fig8 if r["planner"] == "paper_protocol"]))
        b = float(np.median([r["phases_to_half"] for r in fig8 if r["planner"] == "no_partition"]))
        claim(
            "Fig. 8",
            "fig8_module_little",
            f"median phases: paper_protocol {a:g} vs no_partition {b:g} (little: within 10 %)",
            bool(abs(a - b) <= 0.1 * b),
        )
    rho, n = _correlation(fig9, "paper_protocol")
    p_hi = tables["fig9_zero_comms"]["paper_protocol"][-1]["median"]
    g_hi = tables["fig9_zero_comms"].get("greedy", [{"median": math.nan}])[-1]["median"]
    claim(
        "Fig. 9",
        "fig9_shines",
        f"Spearman ρ(C, phases) = {rho:+.2f} over {n} runs; at the highest C, median phases paper_protocol "
        f"{p_hi:g} vs greedy {g_hi:g} (shines: fewer phases as C grows, and fewer than greedy there)",
        bool(rho < 0 and p_hi < g_hi),
    )
    holds, measure = _flat_below(tables["fig9_zero_comms"]["paper_protocol"])
    claim("Fig. 9", "fig9_flat_to_0.3", measure + " (a horizontal line: within 20 %)", holds)
    rho, n = _correlation(fig10, "paper_protocol")
    med = tables["fig10_long_window"]["paper_protocol"]
    drop = 1.0 - med[-1]["median"] / med[0]["median"]
    claim(
        "Fig. 10",
        "fig10_vastly",
        f"Spearman ρ(C, phases) = {rho:+.2f} over {n} runs; median phases {med[0]['median']:g} at C = "
        f"{med[0]['C']:.2f}, {med[-1]['median']:g} at C = {med[-1]['C']:.2f} ({100 * drop:.0f} % fewer; "
        "vastly: at least 20 % fewer)",
        bool(rho < 0 and drop >= 0.2),
    )
    return claims


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
    results = run_sweeps(out, plan, "Figs 6, 8–10: planners × σ × draws")
    fig6_md, fig6_res = fig6(out, plan["fig6"], results["fig6"])
    rows, tables = {}, {}
    for scenario in SCENARIOS:
        rows[scenario] = results[scenario]
        tables[scenario] = summarise(rows[scenario])
        plot_sweep(out, scenario, tables[scenario], rows[scenario])
    write_sweep_rows(out / "figs8_10_sweeps.csv", [r for scenario in SCENARIOS for r in rows[scenario]])
    claims = check_claims(tables, rows)
    timing = time_decision_phase(phases=pick(size, full=40, quick=10, tiny=2))
    atomic_write_json(
        out / "results.json",
        {
            "fig6": fig6_res,
            "tables": tables,
            "claims": claims,
            "timing": timing,
            "quick": quick,
            "seconds": time.perf_counter() - start,
        },
        indent=2,
        default=float,
    )

    return report(out.name, size, fig4_md, fig6_md, tables, claims, timing)


def report(name: str, size: str, fig4_md: str, fig6_md: str, tables: dict, claims: list[dict], timing: dict) -> str:
    """The markdown section: Figs 4 and 6, the layouts, Figs 8–10 and the paper's statements, the timing."""
    lines = ["## RendezvousMapping-v0 — Chapman & Sukkarieh, decentralised mapping with limited connectivity", ""]
    if size == "quick":
        lines += [
            "*Quick run: four layouts, two landmark draws each, two planners, a 30-phase cap (60 at d_comms = 0). "
            "Run without `--quick` for the full sweep (ten layouts, 20 draws, four planners, a 60-phase cap, 150 "
            "at d_comms = 0).*",
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
    ]
    lines += [
        "**Layouts for Figs 8–10** (Fig. 7, §VI-B.1). Each figure's grid is coarse enough that its own graph has no "
        "triangles at σ = 0 (a square grid of spacing s has C = 0 in the graph of radius d when d/√2 ≤ s < d): "
        "8 × 8 = 64 landmarks on the 100 m square (s = 12.5 m) for d_max = 15, 11 × 11 = 121 (s = 9.1 m) for "
        "d_comms = 10. The σ shift raises C to about 0.55, a uniformly random layout in graphs this sparse, and no "
        "further; the env's `clumping` (each landmark pulled that fraction of the way to the nearest of ⌈N_l/8⌉ "
        "random centres, our extension) carries it to about 0.7. Sensor: 5 observations per landmark at 1 Hz (the "
        "defaults), so with 64–121 landmarks for 10 vehicles half the information needs about 3–6 phases even "
        "without travel: the floor sits below what the layouts make the planners measure (200 landmarks put it "
        "near 10 phases, under every run).",
        "",
    ]
    for scenario, spec in SCENARIOS.items():
        lines += sweep_section(scenario, spec, tables[scenario], name)
    lines += [
        "**The paper's statements** on Figs 8–10, quoted (its figures give no numbers in the text; each "
        "statement is tested on our runs):",
        "",
        "| figure | the paper says | ours | holds |",
        "| --- | --- | --- | --- |",
    ]
    verdict = {True: "yes", False: "**no**", None: "n/a"}
    lines += [f"| {c['figure']} | “{c['claim']}” | {c['measure']} | {verdict[c['holds']]} |" for c in claims]
    lines += [
        "",
        f"Decision phase under `paper_protocol`, 10 vehicles × 200 landmarks, median of "
        f"{timing['phases']} phases on one thread: {timing['decision_phase_ms']:.1f} ms wall, "
        f"{timing['decision_phase_cpu_ms']:.1f} ms CPU (policy "
        f"{timing['policy_ms']:.1f} ms + env step {timing['env_step_ms']:.1f} ms); goal < 50 ms.",
        "",
    ]
    return "\n".join(lines)


def write_sweep_rows(path: Path, rows: list[dict]) -> None:
    """Every run of the Figs 8–10 sweeps, one CSV row each (atomically)."""
    atomic_write_csv(path, rows)


def sweep_section(scenario: str, spec: dict, table: dict, name: str) -> list[str]:
    """One figure's table: per planner and layout, phases to 50 % and the information and connectivity at the cap."""
    layouts = next(iter(table.values()))
    lines = [
        f"**{spec['figure']}**: d_comms = {spec['d_comms']:g}, d_max = {spec['t_window']:g} m, "
        f"{spec['n_landmarks']} landmarks; per layout (σ, clumping) and its mean C of the {spec['graph']} graph: "
        "phases to 50 % of the information, median [min–max] over landmark draws (a censored run did not get "
        "there within the cap); then, at the cap, the median fused / union information and the fraction of "
        "phases connected.",
        "",
        "| planner | " + " | ".join(f"σ {r['sigma']:g}, k {r['clumping']:g} (C {r['C']:.2f})" for r in layouts) + " |",
        "| --- |" + " --- |" * len(layouts),
    ]
    for planner, rs in table.items():
        cells = [
            f"{r['median']:g} [{r['min']:g}–{r['max']:g}]" + (f" ({r['censored']} cens.)" if r["censored"] else "")
            for r in rs
        ]
        lines.append(f"| `{planner}` | " + " | ".join(cells) + " |")
        cells = [f"{r['final_info']:.2f} / {r['union_info']:.2f}, {r['connected']:.2f}" for r in rs]
        lines.append("| ↳ info fused / union, connected | " + " | ".join(cells) + " |")
    return [*lines, "", f"![{spec['figure']}]({name}/{scenario}.png)", ""]


def benchmarks() -> dict[str, float]:
    """For ``mrcomm bench``: one decision phase, 10 vehicles and 200 landmarks, ``paper_protocol`` (goal < 50 ms)."""
    timing = time_decision_phase(phases=20, seed=0)
    return {k: float(v) for k, v in timing.items() if k.endswith("ms")}
