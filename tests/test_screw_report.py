"""The paper's screw figure from screw runs: one figure and record per screw task, and the sweeps that train them."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from tests.conftest import compose_config
from tests.test_report import ROOT, episodes, fake_run
from vitac.analysis.status import run_statuses


def test_report_draws_the_papers_screw_figure_from_screw_runs(tmp_path):
    sweep = tmp_path / "screw"
    for seed in range(3):
        fake_run(sweep, "Screw: tactile", seed, 10, successes=episodes(400 - seed), task="screw")
    fake_run(sweep, "Screw: privileged", 0, 10, successes=episodes(300), task="screw")
    fake_run(sweep, "Screw: CMT + sym", 1, 10, successes=episodes(396), task="screw")  # a fusion policy: drawn once run
    result = subprocess.run([sys.executable, "-m", "vitac.report", str(sweep), "--out", str(tmp_path / "out")], cwd=ROOT,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    data = json.loads((tmp_path / "out" / "screw.json").read_text())
    assert data["success_percent_per_seed"] == {"Privileged": [75.0], "Wrist-camera": [], "Tactile": [100.0, 99.75, 99.5],
                                                "CMT + sym": [99.0]}
    assert data["steps_to_success_per_seed"] == {"Privileged": [100.0], "Wrist-camera": [], "Tactile": [100.0, 101.0, 102.0],
                                                 "CMT + sym": [101.0]}
    assert data["task"] == "screw"
    # every pair on the seeds both have: tactile's seed 0 (400 of 400) against privileged's (300) and CMT + sym's seed 1
    assert [(p["first"], p["second"], p["episodes"], p["only_first"], p["only_second"]) for p in data["paired"]] == [
        ("Privileged", "Tactile", 400, 0, 100), ("Tactile", "CMT + sym", 400, 3, 0)]
    assert (tmp_path / "out" / "screw.png").stat().st_size > 0


def test_report_draws_one_screw_figure_per_task_when_the_runs_mix_tasks(tmp_path):
    """Runs of two screw tasks under one directory (the same rows and seeds) are two figures, each of its own task's
    runs only, never one figure mixing them."""
    sweep = tmp_path / "screw"
    fake_run(sweep, "Screw: tactile", 0, 10, successes=episodes(400), task="screw_offthread")
    fake_run(sweep, "Screw: tactile", 0, 10, successes=episodes(300), task="screw_insert")
    fake_run(sweep, "Screw: wrist", 0, 10, successes=episodes(200), task="screw_insert")
    result = subprocess.run([sys.executable, "-m", "vitac.report", str(sweep), "--out", str(tmp_path / "out")], cwd=ROOT,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    offthread, insert = (json.loads((tmp_path / "out" / f"{t}.json").read_text()) for t in ("screw_offthread", "screw_insert"))
    assert offthread["task"] == "screw_offthread" and insert["task"] == "screw_insert"
    assert offthread["success_percent_per_seed"]["Tactile"] == [100.0]
    assert offthread["success_percent_per_seed"]["Wrist-camera"] == []
    assert insert["success_percent_per_seed"]["Tactile"] == [75.0]
    assert insert["success_percent_per_seed"]["Wrist-camera"] == [50.0]
    assert not (tmp_path / "out" / "screw.json").exists()
    assert all((tmp_path / "out" / f"{t}.png").stat().st_size > 0 for t in ("screw_offthread", "screw_insert"))


@pytest.mark.parametrize(("task", "runs", "record"), [
    ("screw", ["docs/data/screw_runs"], "screw.json"),
    ("screw_offthread", ["docs/data/results/screw_offthread"], "screw_offthread.json"),
    ("screw_insert", ["docs/data/results/screw_insert"], "screw_insert.json"),
    # the 85% teacher (500 PPO iterations more) and its students
    ("screw_insert", ["docs/data/results/screw_insert_cont", "docs/data/results/screw_insert_1400"],
     "screw_insert_1400.json")])
def test_the_committed_screw_records_are_what_the_report_makes_of_the_committed_runs(tmp_path, monkeypatch, task, runs,
                                                                                   record):
    """docs/data/<record>: `python -m vitac.report <runs> --out <dir>`'s <task>.json."""
    from vitac.report import screw_cells, screw_figure

    monkeypatch.chdir(ROOT)
    cells = screw_cells(run_statuses([Path(r) for r in runs]), [0, 1, 2], 400)
    assert list(cells) == [task]
    screw_figure(task, cells[task], 400, tmp_path)
    assert json.loads((tmp_path / f"{task}.json").read_text()) == json.loads((ROOT / "docs/data" / record).read_text())


@pytest.mark.parametrize("task", ["screw_offthread", "screw_insert"])
def test_the_new_screw_tasks_sweeps_train_all_five_policies_on_their_task_from_their_own_teacher(task):
    params = yaml.safe_load((ROOT / "conf" / "sweep" / f"{task}.yaml").read_text())["hydra"]["sweeper"]["params"]
    experiments = params["+experiment/screw"].split(",")
    assert sorted(experiments) == sorted(p.stem for p in (ROOT / "conf" / "experiment" / "screw").glob("*.yaml"))
    assert list(params)[0] == "seed"  # seed 0 of every policy first
    for name in experiments:  # command-line-like parameters win over what the experiments set
        cfg = compose_config([f"+sweep={task}", f"+experiment/screw={name}", f"task={params['task']}",
                              f"teacher_ckpt={params['teacher_ckpt']}"])
        assert (cfg.task.start, cfg.teacher_ckpt, cfg.preset.name) == ("off_thread", f"pretrained/{task}_privileged",
                                                                       "cpu_screw")
    cmt_sym = compose_config(["experiment=screw/cmt_sym"])
    assert (cmt_sym.obs.name, cmt_sym.reg.lambda_sym, cmt_sym.row) == ("wrist_tactile", 1.0, "Screw: CMT + sym")
