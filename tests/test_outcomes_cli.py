"""`python -m vitac.runs outcomes`: one report's outcomes, pooled evaluations, paired tests, success by factor."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import CONF
from vitac.utils.records import write_json

ROOT = Path(CONF).parent


def test_outcomes_refuses_a_truncated_or_foreign_report_before_printing_anything(tmp_path):
    truncated, foreign = tmp_path / "truncated.json", tmp_path / "foreign.json"
    truncated.write_text('{"episodes": 100, "success_rate": 0.9')
    foreign.write_text('{"rows": []}')
    for bad, reason in ((truncated, "cannot be read as a vitac.evaluate report"),
                        (foreign, "not a vitac.evaluate report")):
        result = subprocess.run([sys.executable, "-m", "vitac.runs", "outcomes", str(bad)], cwd=ROOT, capture_output=True, text=True)
        assert result.returncode != 0 and f"{bad.name}: {reason}" in result.stderr and result.stdout == ""


def test_pooled_success_adds_disjoint_evaluations_of_one_checkpoint_and_refuses_others():
    from vitac.analysis.outcomes import pooled

    setting = dict(ckpt="run/last.ckpt", randomization_scale=1.0, socket_obs_noise=0.005, randomize_only=None,
                   policy="deterministic")
    first = dict(setting, seed=2000000, episodes=100, success_rate=0.9)
    more = dict(setting, seed=2000100, episodes=300, success_rate=257 / 300)
    # 347 / 400: Wilson interval by hand, p = 0.8675, z = 1.96.
    assert pooled([first, more], ["a", "b"]) == "pooled: 347 of 400 episodes succeeded = 86.8% (95% Wilson interval 83.1-89.7%)"
    with pytest.raises(SystemExit, match="share episodes"):
        pooled([first, dict(more, seed=2000050)], ["a", "b"])
    with pytest.raises(SystemExit, match=r"\['ckpt'\] differ"):
        pooled([first, dict(more, ckpt="other/last.ckpt")], ["a", "b"])


def test_paired_outcomes_compare_steps_to_succeed_on_the_episodes_both_inserted():
    from scipy.stats import wilcoxon

    from vitac.analysis.outcomes import paired, report_name

    # tables name a run's evaluation by its run, any other report by its file
    assert report_name(Path("runs/wrist_seed0/checkpoints/last.eval.json")) == "wrist_seed0"
    assert report_name(Path("docs/data/results/e.json")) == "e"

    def report(success, steps):
        return dict(seed=2000000, episodes=len(success), randomization_scale=1.0, socket_obs_noise=0.005,
                    randomize_only=None, episode_success=success, steps_to_success=steps,
                    final_state=[dict(outcome="inserted" if ok else "stuck part-way in the hole") for ok in success])

    # Episodes 0, 2, 3, 5, 6 are inserted by both; the second is 10, 12, 8, 20, 6 steps slower on them.
    first = report([1, 1, 1, 1, 0, 1, 1], [100, 90, 110, 120, 105, 95])
    second = report([1, 0, 1, 1, 1, 1, 1], [110, 122, 128, 80, 125, 101])
    lines = paired(first, second, ("a", "b")).splitlines()
    assert lines[0] == "paired: inserted only by a: 1, only by b: 1, exact McNemar two-sided p = 1.000"
    p = wilcoxon([100, 110, 120, 105, 95], [110, 122, 128, 125, 101]).pvalue
    assert lines[1] == f"steps to succeed on the 5 episodes both inserted: a 106.0, b 117.2, Wilcoxon signed-rank two-sided p = {p:.3f}"
    # a report without its steps per success (an older one) gives only the McNemar line
    assert paired(first, dict(second, steps_to_success=None), ("a", "b")) == lines[0]
    # the pads' balance, paired over the episodes both measured (episode 1 measured no contact phase in b)
    balance = [dict(field_contact=v, net_contact=v, field_episode=v, net_episode=v) for v in (.1, .2, .3, .4, .5, .6, .7)]
    wider = [dict(e, field_contact=None if i == 1 else e["field_contact"] + .1) for i, e in enumerate(balance)]
    lines = paired(dict(first, force_balance=balance), dict(second, force_balance=wider), ("a", "b")).splitlines()
    p = wilcoxon([.1, .3, .4, .5, .6, .7], [.2, .4, .5, .6, .7, .8]).pvalue
    assert lines[2] == ("field asymmetry in contact (0 balanced, 1 one pad alone), mean over the 6 episodes both "
                        f"measured: a 0.433, b 0.533, Wilcoxon signed-rank two-sided p = {p:.3f}")


def test_paired_pairs_on_disjoint_episodes_sum_into_one_test_and_overlapping_ones_are_refused():
    from vitac.analysis.outcomes import mcnemar_exact, paired_summed

    def report(seed, success):
        return dict(seed=seed, episodes=len(success), randomization_scale=1.0, socket_obs_noise=0.005,
                    randomize_only=None, final_state=[dict(outcome="inserted" if ok else "on or above the socket")
                                                      for ok in success])

    held_out = (report(2_000_000, [1, 1, 1, 0]), report(2_000_000, [0, 0, 1, 1]))  # 2 to 1
    unseen = (report(3_000_000, [1, 1, 0]), report(3_000_000, [0, 0, 0]))  # 2 to 0
    line = paired_summed([*held_out, *unseen], ["a", "b", "a2", "b2"])
    assert line == ("summed over the 2 pairs (7 episodes): inserted only by the first of each pair: 4, only by the "
                    f"second: 1, exact McNemar two-sided p = {mcnemar_exact(4, 1):.3f}")
    with pytest.raises(SystemExit, match="share episodes"):
        paired_summed([*held_out, *held_out], ["a", "b", "a", "b"])


def test_paired_outcomes_count_any_tasks_successes():
    from vitac.analysis.outcomes import paired

    def report(success):  # the screw task's labels: a success is not "inserted"
        return dict(seed=2000000, episodes=len(success), randomization_scale=1.0, episode_success=success,
                    final_state=[dict(outcome="threaded on and seated" if ok else "jammed on the crest") for ok in success])

    line = paired(report([1, 1, 1, 0]), report([0, 1, 0, 0]), ("a", "b")).splitlines()[0]
    assert line == "paired: inserted only by a: 2, only by b: 0, exact McNemar two-sided p = 0.500"


def test_outcomes_tables_each_tasks_own_measurements_in_table_units(tmp_path):
    screw = dict(episodes=2, success_rate=0.5, seed=2_000_000, final_state=[
        dict(outcome="screwed down", turns_to_go=2.0, nut_offset_xy=0.0002, nut_tilt=0.01),
        dict(outcome="slipped in the grasp", turns_to_go=3.25, nut_offset_xy=0.004, nut_tilt=0.5)])
    insertion = dict(episodes=1, success_rate=1.0, seed=2_000_000, final_state=[
        dict(outcome="inserted", peg_offset_xy=0.0003, peg_height=0.0001, peg_tilt=0.0)])
    write_json(tmp_path / "screw.json", screw)
    write_json(tmp_path / "insertion.json", insertion)
    table = subprocess.run([sys.executable, "-m", "vitac.runs", "outcomes", str(tmp_path / "screw.json"),
                            str(tmp_path / "insertion.json")], check=True, cwd=ROOT, capture_output=True, text=True).stdout
    assert "| thread turns to go: median (quartiles) | offset from axis, mm | tilt, deg | height above floor, mm |" in table
    assert "| screw | slipped in the grasp | 1 | 3.2 (3.2-3.2) | 4.0 (4.0-4.0) | 28.6 (28.6-28.6) |  |" in table
    assert "| insertion | inserted | 1 |  | 0.3 (0.3-0.3) | 0.0 (0.0-0.0) | 0.1 (0.1-0.1) |" in table


def test_outcomes_by_factor_finds_the_factor_the_failures_come_from(tmp_path):
    rng = np.random.default_rng(0)
    tilt, depth = rng.uniform(-0.6, 0.6, 80), rng.uniform(0.03, 0.04, 80)
    failed = np.abs(tilt) > 0.45  # the failures are the steepest in-hand tilts, either way
    final_state = [dict(outcome="stuck part-way in the hole" if f else "inserted", peg_offset_xy=0.0, peg_height=0.0,
                        peg_tilt=0.0) for f in failed]
    report = dict(episodes=80, success_rate=float(1 - failed.mean()), seed=2_000_000, final_state=final_state,
                  episode_success=[int(not f) for f in failed],
                  episode_factors=[dict(peg_in_hand_tilt=float(t), peg_in_hand_depth=float(d), ee_pos=[0.5, float(d), 0.1])
                                   for t, d in zip(tilt, depth, strict=True)])
    write_json(tmp_path / "r.json", report)
    table = subprocess.run([sys.executable, "-m", "vitac.runs", "outcomes", str(tmp_path / "r.json"), "--by-factor"],
                           check=True, cwd=ROOT, capture_output=True, text=True).stdout
    rows = [line for line in table.splitlines() if line.startswith("| ") and "factor" not in line and "report" not in line
            and "inserted" not in line and "stuck" not in line]
    assert f"{failed.sum()} of 80 episodes failed" in table
    cells = [[c.strip() for c in row.split("|")[1:-1]] for row in rows]
    assert cells[0][0] == "abs(peg_in_hand_tilt)" and float(cells[0][4]) < 1e-6  # the most telling factor first
    assert cells[0][1].startswith("100 / 100 / ") and cells[0][1].endswith(" / 0")
    assert {c[0] for c in cells} == {"peg_in_hand_tilt", "abs(peg_in_hand_tilt)", "peg_in_hand_depth", "ee_pos.x",
                                     "ee_pos.y", "ee_pos.z"}
    stuck = subprocess.run([sys.executable, "-m", "vitac.runs", "outcomes", str(tmp_path / "r.json"), "--by-factor",
                            "--outcome", "stuck part-way in the hole"], check=True, cwd=ROOT, capture_output=True,
                           text=True).stdout
    assert "episodes stuck part-way in the hole" in stuck
    for args, message in ((["--outcome", "jammed"], "--outcome goes with --by-factor"),
                          (["--by-factor", "--outcome", "jammed"], "no episode of the report ended so")):
        refused = subprocess.run([sys.executable, "-m", "vitac.runs", "outcomes", str(tmp_path / "r.json"), *args],
                                 cwd=ROOT, capture_output=True, text=True)
        assert refused.returncode != 0 and message in refused.stderr and "Traceback" not in refused.stderr
        assert "| report |" not in refused.stdout  # refused before any table
