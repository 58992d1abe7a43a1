"""The symmetry prior's report (vitac/analysis/symmetry.py): runs grouped by configuration, each against its
lambda_sym = 0 twin, from synthetic runs whose results are known."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from tests.test_report import episodes, fake_run
from vitac.analysis import symmetry
from vitac.analysis.status import run_statuses

# every evaluated wrist + tactile run committed that bears on the prior (docs/results.md names the command)
SYMMETRY_RUNS = ("docs/data/table1_runs", "docs/data/results/contact_teacher", "docs/data/results/residual_teacher",
                 "docs/data/results/screw_offthread", "docs/data/results/screw_insert",
                 "docs/data/results/symmetry_kickstart")


def sym_run(sweep, seed, lambda_sym, successes, algo="vitac.algos.dagger.DAgger", asymmetry=None, obs="wrist_tactile",
            task=None, balance=0.0, weighting="absolute", placement="encoder"):
    task = task or dict(_target_="vitac.tasks.insertion.config.InsertionConfig")
    run = fake_run(sweep, f"cmt lambda={lambda_sym} {algo.rsplit('.', 1)[-1]} {obs} {task.get('start')} {balance} {weighting} {placement}", seed, 10,
                   successes=successes)
    config = yaml.safe_load((run / "config.yaml").read_text())
    modalities = ["proprio", "wrist", "tactile_left", "tactile_right"] if obs == "wrist_tactile" else ["proprio", "wrist"]
    config.update(obs=dict(modalities=modalities), fusion={"_target_": "vitac.models.fusion.CrossModalTransformer"},
                  reg=dict(lambda_sym=lambda_sym, mirror="physical", weighting=weighting, placement=placement), algo={"_target_": algo, "horizon": 16},
                  task=dict(task, balance_penalty_scale=balance), residual={"_target_": None})
    (run / "config.yaml").write_text(yaml.safe_dump(config))
    (run / "teacher.json").write_text(json.dumps(dict(sha256="ab12cd34" + "0" * 56, env_steps=1)))
    report = json.loads((run / "checkpoints" / "last.eval.json").read_text())
    report["force_balance"] = [dict(field_contact=asymmetry)] * len(successes) if asymmetry is not None else None
    (run / "checkpoints" / "last.eval.json").write_text(json.dumps(report))
    return run


def test_each_weight_is_a_configuration_paired_against_its_unweighted_twin_on_shared_seeds(tmp_path):
    for seed in (0, 1):
        sym_run(tmp_path, seed, 0.0, episodes(360), asymmetry=0.6)
        sym_run(tmp_path, seed, 1.0, [0] * 10 + episodes(360)[10:], asymmetry=0.5)  # 10 fewer a seed, none gained
    sym_run(tmp_path, 0, 0.1, episodes(370))  # one seed of a scan, never measured for balance
    sym_run(tmp_path, 0, 1.0, episodes(390), algo="vitac.algos.kickstart.KickstartPPO")  # another regime: no twin
    sym_run(tmp_path, 0, 1.0, episodes(400), obs="wrist")  # not a wrist + tactile run: left out
    screw = sym_run(tmp_path, 0, 1.0, episodes(380), task=dict(_target_="vitac.tasks.screw.config.ScrewConfig",
                                                               start="off_thread"))  # another task: no twin
    sym_run(tmp_path, 0, 0.0, episodes(380), balance=0.02)  # the balance penalty instead: against neither
    relative = sym_run(tmp_path, 1, 0.1, episodes(365), weighting="relative")  # its own line; the same twin at 0
    attended = sym_run(tmp_path, 1, 0.1, episodes(355), placement="self_attention")  # its own line too
    found = symmetry.configurations(run_statuses([tmp_path]))
    [relative_result] = [r for r in found if r["weighting"] == "relative"]
    assert relative_result["runs"] == [str(relative)] and relative_result["against_lambda_0"]["only_with"] == 5
    [attended_result] = [r for r in found if r["placement"] == "self_attention"]
    assert attended_result["runs"] == [str(attended)] and attended_result["against_lambda_0"]["only_without"] == 5
    found = [r for r in found if r["placement"] == "encoder"]
    found = [r for r in found if r["weighting"] == "absolute"]
    penalised = [r for r in found if r["balance_penalty"] == 0.02]
    assert [(r["against_lambda_0"], r["against_no_penalty"]["only_with"], r["against_no_penalty"]["only_without"])
            for r in penalised] == [(None, 20, 0)]
    found = [r for r in found if r["balance_penalty"] == 0.0]
    assert [r["runs"] for r in found if r["task"] == "screw_offthread"] == [[str(screw)]]
    results = {(r["lambda_sym"], r["regime"]): r for r in found if r["task"] == "insertion"}
    assert set(results) == {(0.0, "dagger"), (0.1, "dagger"), (1.0, "dagger"), (1.0, "kickstart")}
    weighted = results[(1.0, "dagger")]
    assert weighted["seeds"] == [0, 1] and weighted["success"] == [87.5, 87.5] and weighted["std"] == 0.0
    assert weighted["mean_field_asymmetry"] == pytest.approx(0.5)
    assert results[(0.0, "dagger")]["mean_field_asymmetry"] == pytest.approx(0.6)
    paired = weighted["against_lambda_0"]
    assert (paired["episodes"], paired["only_with"], paired["only_without"]) == (800, 0, 20) and paired["p"] < 1e-5
    assert results[(0.1, "dagger")]["against_lambda_0"]["only_with"] == 10  # seed 0 only
    assert results[(0.1, "dagger")]["mean_field_asymmetry"] is None and results[(0.1, "dagger")]["std"] is None
    assert results[(1.0, "kickstart")]["against_lambda_0"] is None and results[(0.0, "dagger")]["against_lambda_0"] is None
    assert [r["against_lambda_0"] for r in found if r["task"] != "insertion"] == [None]
    assert symmetry.figure(found, tmp_path / "symmetry.png").stat().st_size > 0


def test_the_committed_symmetry_record_is_what_the_report_makes_of_the_committed_runs(monkeypatch):
    """docs/data/symmetry.json: `python -m vitac.report` of the directories below."""
    from tests.test_report import ROOT

    monkeypatch.chdir(ROOT)
    made = symmetry.configurations(run_statuses([Path(d) for d in SYMMETRY_RUNS]))
    committed = json.loads((ROOT / "docs/data/symmetry.json").read_text())
    assert json.loads(json.dumps(made)) == committed["configurations"]
