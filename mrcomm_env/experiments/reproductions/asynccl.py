"""Reproduction of paper 000: Table I (expected delay), Table II (p(delay = 1)), Figs. 7–8 (RMS errors).

``run(out_dir, quick, tiny=False)`` writes CSV/JSON/PNG files into ``out_dir`` and returns a markdown section.
The team's transfer mode is the scripted baseline of the same name (``baselines.asynccl``), played through
the shared episode loop (:func:`.common.run_episode`).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from baselines import make_policy
from mrcomm_env.asynccl import theory
from mrcomm_env.asynccl.env import AsyncCLEnv
from mrcomm_env.core.stats import mean_ci95
from mrcomm_env.experiments.reproductions.common import (
    atomic_open,
    atomic_write_json,
    figure,
    label_axes,
    pick,
    progress,
    run_episode,
    size_of,
)

ENV_ID = "mrcomm/AsyncCL-v0"

EXPERIMENTS = {
    "table1": "expected delay of Scheme 1, Scheme 2 q = ∞ and q = 1 for N = 3 … 100, p = 0.5, 1000 steps",
    "table2": "p(delay = 1) of Scheme 2 q = ∞: paper vs eq. (17)–(18) as printed vs exact enumeration vs simulation",
    "figs7_8": "RMS position / orientation error of robot 1's team estimate over 500 steps, N = 5, with bits per link",
}
TEAM_SIZES = (3, 5, 10, 20, 50, 100)
SCHEMES = ("scheme1", "scheme2_qinf", "scheme2_q1")
ARTIFACTS = ("table1.csv", "table2.csv", "figs7_8.json", "fig7_rms_position.png", "fig8_rms_orientation.png")


def delay_run(n: int, mode: str, steps: int, seed: int, q_rule: str = "paper", p: float = 0.5):
    """One delay-only episode (no EKF); returns (mean delay, delay histogram, bits per link)."""
    env = AsyncCLEnv(
        n_robots=n,
        link_probability=p,
        estimation=False,
        max_cycles=steps,
        max_history=steps + 5,
        modes=[mode],
        q_rule=q_rule,
    )
    m = run_episode(env, make_policy(ENV_ID, mode), seed)
    return m["mean_delay"], env.tables.delay_histogram(), m["bits_per_link"]


def _fmt(mean, half):
    return f"{mean:.4f} ± {half:.4f}" if half > 0 else f"{mean:.4f}"


def table1(out: Path, size: str):
    rows, hists = [], {}
    plan = []
    sizes = pick(size, full=TEAM_SIZES, quick=TEAM_SIZES, tiny=TEAM_SIZES[:2])
    for n in sizes:
        runs = pick(size, full=20 if n <= 10 else 6 if n <= 20 else 2, quick=3 if n <= 10 else 1, tiny=1)
        for mode in SCHEMES:
            steps = pick(size, full=1000, quick=1000, tiny=40)
            if size == "quick" and n >= 50:
                if mode == "scheme2_q1":
                    continue  # horizon-dependent and slow at N ≥ 50: full run only
                steps = 200
            plan.append((n, mode, steps, runs, "paper"))
        if n <= pick(size, full=20, quick=5, tiny=3):  # the q = 1 readings of "oldest time step", for the discussion
            for rule in ("oracle", "receiver"):
                plan.append(
                    (n, "scheme2_q1", pick(size, full=1000, quick=1000, tiny=40), pick(size, full=3, quick=1), rule)
                )
    results = {}
    timing = {}
    for n, mode, steps, runs, rule in progress(plan, desc="Table I"):
        t0 = time.perf_counter()
        vals, hist = [], None
        for s in range(runs):
            d, h, _ = delay_run(n, mode, steps, seed=1000 * n + s, q_rule=rule)
            vals.append(d)
            hist = h if hist is None else hist + h
        results[(n, mode, rule)] = (mean_ci95(vals), steps, runs)
        if mode == "scheme2_qinf":
            hists[n] = hist
        timing[(n, mode, rule)] = time.perf_counter() - t0
    for n in sizes:
        paper = theory.PAPER_TABLE1[n]
        row = {
            "N": n,
            "scheme1_theory_eq11": theory.scheme1_expected_delay(n, 0.5),
            "scheme1_paper_theory": paper[0],
            "scheme1_paper_sim": paper[1],
            "qinf_paper": paper[2],
            "q1_paper": paper[3],
        }
        if n == 3:
            row["qinf_theory_eq16"] = theory.scheme2_qinf_n3_expected_delay(0.5)
            row["qinf_paper_theory"] = theory.PAPER_QINF_N3_THEORY
        for (nn, mode, rule), ((mean, half), steps, runs) in results.items():
            if nn == n:
                key = mode if rule == "paper" else f"{mode}_{rule}"
                row[f"{key}_sim"], row[f"{key}_ci95"], row[f"{key}_steps"], row[f"{key}_runs"] = mean, half, steps, runs
        rows.append(row)
    _write_csv(out / "table1.csv", rows)
    n100 = sum(v for (n, _, r), v in timing.items() if n == 100 and r == "paper")
    return rows, hists, n100


def table2(out: Path, hists: dict):
    rows = []
    for n in [n for n in TEAM_SIZES if n in hists]:
        h = hists.get(n)
        sim = float(h[1] / h.sum()) if h is not None and h.sum() else math.nan
        rows.append(
            {
                "N": n,
                "paper_table2": theory.PAPER_TABLE2[n],
                "eq18_as_printed": theory.p_delay_eq1_as_printed(n, 0.5),
                "exact_enumeration": theory.p_delay_eq1_exact(n, 0.5) if n <= 5 else math.nan,
                "simulation": sim,
                "samples": int(h.sum()) if h is not None else 0,
                "(1-(1-p)^(N-1))^2": (1 - 0.5 ** (n - 1)) ** 2,
            }
        )
    _write_csv(out / "table2.csv", rows)
    return rows


def figs7_8(out: Path, size: str):
    runs = pick(size, full=5, quick=1)
    # q = 1 re-runs its causal EKF over a backlog of hundreds of steps (6 s with numba, 14 s without)
    steps = pick(size, full=500, quick=500, tiny=40)
    curves, bits = {}, {}
    for mode in progress(SCHEMES, desc="Figs 7-8"):
        pos, ori, bpl = [], [], []
        for s in range(runs):
            env = AsyncCLEnv(n_robots=5, max_cycles=steps, modes=[mode], max_history=steps + 5)
            p_err, o_err = [], []

            def record(step, observations, rewards, infos, p_err=p_err, o_err=o_err):
                p_err.append(infos["robot_0"]["rms_position"])
                o_err.append(infos["robot_0"]["rms_orientation"])

            metrics = run_episode(env, make_policy(ENV_ID, mode), 70 + s, on_step=record)
            pos.append(p_err)
            ori.append(o_err)
            bpl.append(metrics["bits_per_link"])
        curves[mode] = (np.mean(pos, axis=0), np.mean(ori, axis=0))
        bits[mode] = float(np.mean(bpl))
    _plot_figs(out, curves, bits)
    atomic_write_json(
        out / "figs7_8.json",
        {
            m: {"rms_position": c[0].tolist(), "rms_orientation": c[1].tolist(), "bits_per_link": bits[m]}
            for m, c in curves.items()
        },
    )
    return curves, bits, runs, steps


def _plot_figs(out, curves, bits):
    labels = {"scheme1": "Scheme 1", "scheme2_qinf": "Scheme 2, q = ∞", "scheme2_q1": "Scheme 2, q = 1"}
    for idx, (name, ylabel) in enumerate(
        (
            ("fig7_rms_position.png", "RMS position error (m)"),
            ("fig8_rms_orientation.png", "RMS orientation error (rad)"),
        )
    ):
        with figure(out / name, figsize=(6.4, 4.0), dpi=100) as (_, ax):
            for mode, c in curves.items():
                y = c[idx]
                k = np.arange(len(y))
                ax.plot(k[::20], y[::20], marker="o", ms=3, label=f"{labels[mode]} ({bits[mode]:.0f} bits/link)")
            label_axes(
                ax,
                xlabel="time step",
                ylabel=ylabel,
                yscale="log",
                legend=8,
                title=f"Robot 1's causal team estimate, N = 5 (Fig. {7 + idx})",
            )


def _span(rows, key):
    vals = [r[f"{key}_sim"] for r in rows if f"{key}_sim" in r]
    return f"{min(vals):.0f}–{max(vals):.0f}" if vals else "—"


def _write_csv(path: Path, rows: list[dict]):
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with atomic_open(path, "w") as f:
        f.write(",".join(keys) + "\n")
        for r in rows:
            f.write(
                ",".join(
                    "" if r.get(k) is None else (f"{r[k]:.6g}" if isinstance(r.get(k), float) else str(r[k]))
                    for k in keys
                )
                + "\n"
            )


def run(out_dir: Path, quick: bool, tiny: bool = False) -> str:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    size = size_of(quick, tiny)
    t1_rows, hists, n100_time = table1(out, size)
    t2_rows = table2(out, hists)
    curves, bits, fig_runs, fig_steps = figs7_8(out, size)
    name = out.name
    md = [
        "Nerurkar & Roumeliotis, *Asynchronous Multi-Centralized Cooperative Localization* (paper 000). "
        "Theory in `mrcomm_env/asynccl/theory.py`; CSV/JSON next to the figures.",
        "",
    ]
    md += [
        "### Table I: expected delay (steps), p = 0.5",
        "",
        "Simulation: delay-only runs (`estimation=False`), mean over robots and complete steps (eq. (7)), "
        "mean ± 95 % CI over runs. q = 1 uses the paper's rules (`q_rule=paper`).",
        "",
        "| N | Sch. 1 eq. (11) | Sch. 1 paper theor./sim. | Sch. 1 ours | Sch. 2 q=∞ paper | Sch. 2 q=∞ ours "
        "| Sch. 2 q=1 paper | Sch. 2 q=1 ours |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in t1_rows:
        q1 = _fmt(r["scheme2_q1_sim"], r["scheme2_q1_ci95"]) if "scheme2_q1_sim" in r else "(full run only)"
        qinf = _fmt(r["scheme2_qinf_sim"], r["scheme2_qinf_ci95"])
        if r["N"] == 3:
            qinf += f" (eq. (16): {r['qinf_theory_eq16']:.4f})"
        qp = "1.2333/1.2222 (theor./sim.)" if r["N"] == 3 else f"{r['qinf_paper']:.4f}"
        md.append(
            f"| {r['N']} | {r['scheme1_theory_eq11']:.4f} | {r['scheme1_paper_theory']:.4f}/{r['scheme1_paper_sim']:.4f} "
            f"| {_fmt(r['scheme1_sim'], r['scheme1_ci95'])} | "
            f"{qp} | {qinf} | {r['q1_paper']:.4f} | {q1} |"
        )
    var = [r for r in t1_rows if "scheme2_q1_oracle_sim" in r]
    md += [
        "",
        f"Team N = 100 took {n100_time:.1f} s for its Table I cells here"
        f"{' (200 steps, no q = 1 in quick mode)' if quick else ''}."
        if 100 in hists
        else "Tiny run: N = 3 and 5 only, 40 steps; the numbers mean nothing.",
        "",
        "**q = 1 readings** (mean delay over 1000 steps; the paper gives ≈ 66–74):",
        "",
        "| N | paper | `paper` rule | `oracle` discard | `receiver` columns |",
        "|---|---|---|---|---|",
    ]
    for r in var:
        md.append(
            f"| {r['N']} | {r['q1_paper']:.2f} | {r.get('scheme2_q1_sim', float('nan')):.1f} "
            f"| {r['scheme2_q1_oracle_sim']:.1f} | {r['scheme2_q1_receiver_sim']:.1f} |"
        )
    md += [
        "",
        "Scheme 1 agrees with eq. (11) and with the paper's Table I within Monte-Carlo error; our eq. (11) "
        "code reproduces the paper's theory column to 4 decimals. Scheme 2 q = ∞ agrees with eq. (15)–(16) for "
        "N = 3: evaluated as printed, eq. (16) gives 11/9 = 1.2222, which is the paper's *simulation* value; "
        "the paper's theory value 1.2333 is not what its own equation gives. For large N the q = ∞ delay goes to "
        "1 as in the paper.",
        "",
        "**q = 1 does not reproduce the paper's 66–74.** Under every reading we tried, a q = 1 sender can only "
        "move one time step per link and step, and a step leaves the tables only after every robot has it (and, "
        "with the paper's rule, knows that everyone has it). The backlog therefore grows linearly with time and "
        f"the mean delay over 1000 steps is a large fraction of the horizon: {_span(t1_rows, 'scheme2_q1')} with "
        f"the paper's discard rule, {_span(t1_rows, 'scheme2_q1_oracle')} with an oracle discard, "
        f"{_span(t1_rows, 'scheme2_q1_receiver')} when a sender picks the oldest column the receiver lacks. "
        "The paper's numbers imply ≈ 0.87 columns completed per step (a backlog growing by ≈ 0.15 steps per step), "
        "which none of these mechanisms reaches at p = 0.5; the paper does not describe its q = 1 simulation "
        "further, so we report the gap rather than tune a mechanism to it.",
        "",
    ]
    md += [
        "### Table II: p(delay = 1), Scheme 2 q = ∞, p = 0.5",
        "",
        "| N | paper Table II | eq. (17)–(18) as printed | exact enumeration | simulation | (1−(1−p)^{N−1})² |",
        "|---|---|---|---|---|---|",
    ]
    for r in t2_rows:
        ex = f"{r['exact_enumeration']:.4f}" if not math.isnan(r["exact_enumeration"]) else "—"
        md.append(
            f"| {r['N']} | {r['paper_table2']:.4f} | {r['eq18_as_printed']:.4f} | {ex} | {r['simulation']:.4f} "
            f"| {r['(1-(1-p)^(N-1))^2']:.4f} |"
        )
    md += [
        "",
        "Eq. (17)–(18) *as printed* are right: they equal the exact enumeration over two steps' link graphs "
        "(N ≤ 5, to 1e-12) and our simulation within Monte-Carlo error. The paper's Table II is wrong: its "
        "values are exactly (1 − (1 − p)^{N−1})², which is neither eq. (18) nor p(delay = 1) (for N = 3, the "
        "delay distribution is p(0) = 0.25, p(1) = 0.4375, so Table II's 0.5625 is not a probability of "
        "delay 1). Table II's trend (→ 1 as N grows) is right.",
        "",
    ]
    md += [
        f"### Figs. 7–8: RMS error of robot 1's causal team estimate, N = 5, {fig_steps} steps ({fig_runs} run(s))",
        "",
        f"![Fig. 7]({name}/fig7_rms_position.png)",
        f"![Fig. 8]({name}/fig8_rms_orientation.png)",
        "",
        "| scheme | bits per used link per step | mean RMS position (m) | mean RMS orientation (rad) |",
        "|---|---|---|---|",
    ]
    for mode, c in curves.items():
        md.append(
            f"| {mode} | {bits[mode]:.0f} | {float(np.mean(c[0])):.4f} | {float(np.mean(c[1])):.4f} "
            f"(over {len(c[0])} steps) |"
        )
    md += [
        "",
        "As in the paper, Scheme 1 and Scheme 2 (q = ∞) are almost indistinguishable for N = 5 while "
        "Scheme 1 sends fewer bits per link, and q = 1 is the least accurate (its causal estimates run on "
        "stale odometry of the other robots for hundreds of steps). The paper's figures give no numbers, so "
        "only the ordering can be compared.",
        "",
    ]
    return "\n".join(md)
