"""vitac.evaluate and vitac.export on a smoke run's checkpoint: the report, its outcome tables and paired tests,
the evaluation settings, and a shipped policy that evaluates as its checkpoint."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from tests.conftest import CONF, compose_config
from vitac.evaluate import evaluate
from vitac.training import train

ROOT = Path(CONF).parent
SMOKE = ["preset=smoke", "obs=wrist_tactile", "fusion=cmt", "reg=sym"]


def test_evaluate_reports_success_with_interval(tmp_path, capfd):
    run = train(compose_config(SMOKE, output_dir=tmp_path / "run"))
    capfd.readouterr()
    report = evaluate(run["checkpoint"], episodes=2, num_envs=2, num_workers=0, seed=5, out=str(tmp_path / "e.json"))
    progress = capfd.readouterr().err  # the bar of finished episodes, with rate and ETA
    assert "evaluate: 100%" in progress and "2/2" in progress and "ep/s" in progress
    assert report["episodes"] == 2 and 0.0 <= report["success_rate"] <= 1.0
    low, high = report["success_ci95"]
    assert 0.0 <= low <= report["success_rate"] <= high <= 1.0
    assert json.loads((tmp_path / "e.json").read_text())["preset"] == "smoke"
    assert report["socket_obs_noise"] == 0.005
    assert sum(report["outcomes"].values()) == 2 and len(report["final_state"]) == 2
    assert len(report["force_balance"]) == 2 and all(0 <= e["field_episode"] <= 1 for e in report["force_balance"])
    table = subprocess.run([sys.executable, "-m", "vitac.runs", "outcomes", str(tmp_path / "e.json")], check=True, cwd=ROOT,
                           capture_output=True, text=True).stdout
    assert sum(int(line.split("|")[3]) for line in table.splitlines()[2:]) == 2
    same = subprocess.run([sys.executable, "-m", "vitac.runs", "outcomes", str(tmp_path / "e.json"), str(tmp_path / "e.json"),
                           "--paired"], check=True, cwd=ROOT, capture_output=True, text=True).stdout
    assert "paired: inserted only by e: 0, only by e: 0, exact McNemar two-sided p = 1.000" in same.splitlines()
    assert any(line.startswith("field asymmetry over the episode") and line.endswith("p = 1.000")
               for line in same.splitlines())
    # 5 vs 17 discordant episodes: 2 * sum_{k<=5} C(22, k) / 2^22 = 2 * 35,443 / 4,194,304.
    from vitac.analysis.outcomes import mcnemar_exact

    assert mcnemar_exact(5, 17) == pytest.approx(2 * 35443 / 2 ** 22)
    spread = subprocess.run([sys.executable, "-m", "vitac.runs", "log-std", run["checkpoint"], "--episodes", "1"], check=True,
                            cwd=ROOT, capture_output=True, text=True).stdout
    assert "past head.log_std_max=1.0: 0.0% (bound: clamp)" in spread  # a fresh policy's log-std starts at 0
    noiseless = evaluate(run["checkpoint"], episodes=2, num_envs=2, num_workers=0, seed=5, out=str(tmp_path / "n.json"),
                         socket_obs_noise=0.0)
    assert noiseless["socket_obs_noise"] == 0.0
    refused = subprocess.run([sys.executable, "-m", "vitac.runs", "outcomes", str(tmp_path / "e.json"), str(tmp_path / "n.json"),
                              "--paired"], cwd=ROOT, capture_output=True, text=True)
    assert refused.returncode != 0 and "not the same episodes (['socket_obs_noise'] differ)" in refused.stderr
    with pytest.raises(ValueError, match="socket_obs_noise"):
        evaluate(run["checkpoint"], episodes=2, num_envs=2, num_workers=0, seed=5, socket_obs_noise=-1.0)
    tilt_only = evaluate(run["checkpoint"], episodes=2, num_envs=2, num_workers=0, seed=5,
                         randomize_only=["peg_in_hand_tilt"])
    assert tilt_only["randomize_only"] == ["peg_in_hand_tilt"] and tilt_only["socket_obs_noise"] == 0.0
    assert Path(run["checkpoint"]).with_suffix(".eval.only-peg_in_hand_tilt.json").exists()
    with pytest.raises(ValueError, match="randomize_only"):
        evaluate(run["checkpoint"], episodes=2, num_envs=2, num_workers=0, seed=5, randomize_only=["tilt"])
    # Sampled actions: reproducible for a seed, and not the mean action.
    sampled = [evaluate(run["checkpoint"], episodes=2, num_envs=2, num_workers=0, seed=5, out=str(tmp_path / f"s{i}.json"),
                        deterministic=False) for i in range(2)]
    distances = [r["final_keypoint_distance_mm"] for r in [report] + sampled]
    assert sampled[0]["policy"] == "stochastic" and report["policy"] == "deterministic"
    assert distances[1] == distances[2] and distances[1] != distances[0]
    # `vitac.report` reads a run directory that belongs to no Table I row (no `row`): every row stays missing.
    subprocess.run([sys.executable, "-m", "vitac.report", str(tmp_path / "run"), "--out", str(tmp_path / "report")],
                   check=True, cwd=ROOT, capture_output=True)
    table = (tmp_path / "report" / "table1.md").read_text()
    assert table.count("| missing | 0 of 3 |") == 10  # tests/test_report.py checks a sweep's table
    assert (tmp_path / "report" / "learning_curves.png").stat().st_size > 0


def test_an_exported_policy_is_small_loads_weights_only_and_evaluates_as_its_checkpoint(tmp_path):
    from vitac.utils.checkpoint import export_policy

    run = train(compose_config(["preset=smoke", "experiment=table1/privileged"], output_dir=tmp_path / "run"))
    export_policy(run["checkpoint"], tmp_path / "pretrained" / "p.pt")
    shipped = torch.load(tmp_path / "pretrained" / "p.pt", weights_only=True)  # no optimizer, env or RNG state
    assert set(shipped) == {"vitac_config", "state_dict", "env_steps", "source"} and shipped["env_steps"] == 64
    assert (tmp_path / "pretrained" / "p.pt").stat().st_size < Path(run["checkpoint"]).stat().st_size / 2
    episodes = dict(episodes=2, num_envs=2, num_workers=0, seed=7)
    original = evaluate(run["checkpoint"], out=str(tmp_path / "a.json"), **episodes)
    by_name = evaluate(str(tmp_path / "pretrained" / "p"), out=str(tmp_path / "b.json"), **episodes)  # no suffix
    assert original["final_keypoint_distance_mm"] == by_name["final_keypoint_distance_mm"]
    # A critic (TacSL's AACD) and a warm start come from it as from the checkpoint.
    student = train(compose_config(["preset=smoke", "experiment=table1/privileged", "trainer.iterations=1",
                                    f"critic_ckpt={tmp_path / 'pretrained' / 'p.pt'}",
                                    f"init_ckpt={tmp_path / 'pretrained' / 'p.pt'}"], output_dir=tmp_path / "student"))
    assert math.isfinite(student["metrics"]["losses/loss"])
