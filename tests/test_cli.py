"""The ``mrcomm`` command as users and other tools call it."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from baselines import default_policy, policy_names
from mrcomm_env.experiments.cli import main, parse_params
from mrcomm_env.core.stats import mean_ci95
from mrcomm_env.registry import env_class, env_ids


def test_parse_params_reads_json_where_possible():
    got = parse_params(["a=3", "b=0.5", "c=true", "d=inf", 'e="inf"', "f=[1, 2]", "g=grid", "h=null"])
    assert got == {"a": 3, "b": 0.5, "c": True, "d": "inf", "e": "inf", "f": [1, 2], "g": "grid", "h": None}
    with pytest.raises(ValueError, match="key=value"):
        parse_params(["novalue"])


def test_list_names_every_env_policy_and_reproduction(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for env_id in env_ids():
        assert env_id in out and env_class(env_id).DESCRIPTION in out
        for name in policy_names(env_id):
            assert name in out


@pytest.mark.parametrize("env_id", env_ids())
def test_evaluate_writes_json_of_stable_shape(env_id, tmp_path, capsys):
    path = tmp_path / "eval.json"
    short = env_id.split("/", 1)[1]  # ids work without the namespace
    code = main(
        ["evaluate", short, "--policy", default_policy(env_id), "--episodes", "3", "--seed", "5",
         "--param", "max_cycles=15", "--json", str(path), "--quiet"]
    )
    assert code == 0
    record = json.loads(path.read_text())
    assert set(record) == {"env", "policy", "episodes", "seed", "params", "policy_params", "metrics"}
    assert record["env"] == env_id and record["episodes"] == 3 and record["seed"] == 5
    assert record["params"] == {"max_cycles": 15}
    assert set(env_class(env_id).METRICS) <= set(record["metrics"])
    for m in record["metrics"].values():
        assert set(m) == {"mean", "ci95", "values"} and len(m["values"]) == 3
        finite = [v for v in m["values"] if v is not None and np.isfinite(v)]
        if finite:
            mean, half = mean_ci95(finite)
            assert m["mean"] == pytest.approx(mean) and m["ci95"] == pytest.approx(half)
    table = capsys.readouterr().out
    assert "±" in table and "bits_sent" in table


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["evaluate", "Nope-v0", "--policy", "x"], "valid ids are"),
        (["evaluate", env_ids()[0], "--policy", "no_such_policy"], "valid policies are"),
        (["evaluate", env_ids()[0], "--policy", default_policy(env_ids()[0]), "--param", "bogus=1"], "valid arguments are"),
        (["reproduce"], "--all"),
    ],
)
def test_bad_input_exits_nonzero_listing_valid_choices(argv, message, capsys):
    assert main(argv) != 0
    assert message in capsys.readouterr().err


def test_console_script_exit_code_on_unknown_id():
    proc = subprocess.run(
        [sys.executable, "-m", "mrcomm_env.experiments.cli", "evaluate", "Nope-v0", "--policy", "x"],
        capture_output=True, text=True,
    )
    assert proc.returncode != 0 and "valid ids are" in proc.stderr


def test_bench_writes_json_with_ratio(tmp_path):
    pytest.importorskip("mpe2")
    out = tmp_path / "bench.json"
    env_id = env_ids()[0]
    assert main(["bench", env_id, "--runs", "1", "--seconds", "0.2", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    entry = data["envs"][env_id]
    assert data["reference"]["env_steps_per_s"] > 0 and entry["env_steps_per_s"] > 0
    assert entry["ratio_to_reference"] == pytest.approx(entry["env_steps_per_s"] / data["reference"]["env_steps_per_s"])
