"""Table I from a sweep: the report on a synthetic sweep whose table is known, the status command, and sweeps
that skip finished cells and resume interrupted ones."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from tests.conftest import CONF, compose_config
from vitac.analysis import table1
from vitac.analysis.status import run_statuses
from vitac.run_dirs import read_metrics
from vitac.training import train

ROOT = Path(CONF).parent
PER_ITERATION = 2 * 16  # the synthetic runs' envs x horizon


def fake_run(sweep: Path, row: str, seed: int, done: int, budget: int = 10, successes: list | None = None,
             init_ckpt: str | None = None, task: str | None = None) -> Path:
    """A run directory as training and vitac.evaluate leave it: config, metrics, a checkpoint holding `done`
    iterations, and (given `successes`, one 0/1 per episode) an evaluation of its last checkpoint."""
    run = sweep / f"{row.replace(' ', '_')},seed={seed}" / (task or "")
    (run / "csv").mkdir(parents=True)
    (run / "checkpoints").mkdir()
    config = dict(row=row, seed=seed, trainer=dict(iterations=budget), envs=dict(num_envs=2), algo=dict(horizon=16),
                  init_ckpt=init_ckpt, **(dict(task=dict(name=task)) if task else {}))
    (run / "config.yaml").write_text(yaml.safe_dump(config))
    rows = ["epoch,charts/env_steps,charts/SPS,eval/success_rate"]
    rows += [f"{i},{(i + 1) * PER_ITERATION},{PER_ITERATION / 36.0},0.5" for i in range(done)]  # 36 s an iteration
    (run / "csv" / "metrics.csv").write_text("\n".join(rows) + "\n")
    torch.save(dict(vitac_config=config, state_dict={}, vitac=dict(env_steps=done * PER_ITERATION)),
               run / "checkpoints" / "last.ckpt")
    if successes is not None:
        report = dict(episodes=len(successes), success_rate=sum(successes) / len(successes), seed=2_000_000,
                      success_ci95=[0.0, 1.0], episode_success=successes, steps_to_success_mean=100.0 + seed)
        (run / "checkpoints" / "last.eval.json").write_text(json.dumps(report))
    return run


def episodes(successes: int, total: int = 400) -> list[int]:
    return [1] * successes + [0] * (total - successes)


def test_report_on_a_synthetic_sweep_gives_the_known_table(tmp_path):
    sweep = tmp_path / "sweep"
    for seed, k in enumerate((380, 360, 340)):  # 95, 90, 85%: 90.00 +- 5.00
        fake_run(sweep, "Privileged", seed, 10, successes=episodes(k))
    fake_run(sweep, "+ Contact forces", 0, 10, successes=episodes(388),  # 97%: +7.00 over Privileged
             init_ckpt="pretrained/privileged")
    fake_run(sweep, "+ Contact forces", 1, 4)  # partial: not counted
    fake_run(sweep, "Wrist", 0, 10)  # finished, never evaluated: not counted
    naive = fake_run(sweep, "Fusion - Naive", 0, 10, successes=episodes(360))
    (naive / "teacher.json").write_text(json.dumps(dict(sha256="fb727a81" + "0" * 56, env_steps=18_513_920)))
    # CMT succeeds on 20 episodes naive failed and fails on none naive succeeded: a paired difference.
    fake_run(sweep, "Fusion - CMT (lambda_sym=0)", 0, 10, successes=episodes(380))
    out = tmp_path / "out"
    result = subprocess.run([sys.executable, "-m", "vitac.report", str(sweep), "--out", str(out)], cwd=ROOT,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "| cmt | " in (out / "computation.md").read_text() and "6.52 / 21.45 / 153.37" in (out / "computation.md").read_text()
    md = (out / "table1.md").read_text()
    assert "| Privileged | 90.00 ± 5.00 | 3 of 3 | " in md
    assert "| + Contact forces | 97.00 (+7.00) | 1 of 3, 1 partial | " in md  # one seed: no standard deviation
    assert "| Tactile | missing | 0 of 3 |" in md
    assert "| Wrist | not evaluated (1 run started) | 0 of 3 |" in md
    assert "| Wrist + Contact forces | missing |" in md  # its baseline is unevaluated: no parenthesis either
    assert "| Fusion - CMT (lambda_sym=0) vs Fusion - Naive | 400 | 20 | 0 | " in md
    assert "| 92.97 ± 1.41 | fb727a81 (18.51 M) |" in md and "| 96.74 ± 1.63 |  |" in md  # distilled, or not
    assert "| 98.96 ± 0.83 | warm start: pretrained/privileged |" in md  # its env steps add to the checkpoint's
    tex = (out / "table1.tex").read_text()
    assert r"Privileged & \checkmark &  &  &  &  & 90.00 $\pm$ 5.00 & 96.74 $\pm$ 1.63 \\" in tex
    assert r"Tactile &  & \checkmark &  &  & \checkmark & missing & 91.41 $\pm$ 5.51 \\" in tex
    data = json.loads((out / "table1.json").read_text())
    rows = {r["row"]: r for r in data["rows"]}
    assert len(rows) == 10 and rows["Tactile"]["mean"] is None and rows["Tactile"]["seeds"]["0"]["status"] == "missing"
    privileged = rows["Privileged"]["seeds"]
    assert [privileged[s]["success"] for s in "012"] == [0.95, 0.9, 0.85]
    assert privileged["0"]["env_steps"] == 10 * PER_ITERATION and privileged["0"]["hours"] == 0.1  # 10 x 36 s
    assert rows["+ Contact forces"]["seeds"]["1"]["status"] == "partial"
    cmt = next(t for t in data["paired"] if t["first"] == "Fusion - CMT (lambda_sym=0)" and t["second"] == table1.NAIVE)
    assert cmt["only_first"] == 20 and cmt["p"] < 1e-5
    assert (out / "success_vs_steps.png").stat().st_size > 0 and (out / "learning_curves.png").stat().st_size > 0
    status = subprocess.run([sys.executable, "-m", "vitac.runs", "status", str(sweep)], cwd=ROOT, capture_output=True,
                            text=True)
    assert "| Privileged | done: 10/10 it, 0.00 M steps | done" in status.stdout
    assert "| + Contact forces | done: 10/10 it, 0.00 M steps | partial: 4/10 it, 0.00 M steps | missing |" in status.stdout
    assert "5 done" not in status.stdout and "7 done, 1 partial, 22 missing of 30 cells" in status.stdout


def test_a_table_beside_an_earlier_one_pairs_each_row_with_its_earlier_self(tmp_path):
    """`vitac.report <now> --against <before>`: each row's two results, budgets and the paired test across them."""
    cmt = "Fusion - CMT (lambda_sym=0)"
    fake_run(tmp_path / "before", cmt, 0, 10, successes=episodes(360))
    fake_run(tmp_path / "before", "Tactile", 0, 10, successes=episodes(300))
    now = fake_run(tmp_path / "now", cmt, 0, 20, budget=20, successes=episodes(380))  # 20 more, none lost
    (now / "teacher.json").write_text(json.dumps(dict(sha256="ab12cd34" + "0" * 56, env_steps=5_000_000)))
    (now / "unseen_seeds_eval.json").write_text(json.dumps(dict(episodes=400, success_rate=0.9325)))
    rows = {r["row"]: r for r in table1.versus(table1.build(run_statuses([tmp_path / "now"]), [0]),
                                               table1.build(run_statuses([tmp_path / "before"]), [0]))}
    assert set(rows) == {cmt, "Tactile"}  # rows evaluated in neither table are left out
    assert (rows[cmt]["now"]["mean"], rows[cmt]["before"]["mean"]) == (95.0, 90.0)
    assert (rows[cmt]["paired"]["only_first"], rows[cmt]["paired"]["only_second"]) == (20, 0)
    assert rows["Tactile"]["now"]["mean"] is None and rows["Tactile"]["paired"] is None
    md = table1.versus_markdown(list(rows.values()))
    assert rows[cmt]["now"]["unseen"] == dict(mean=93.25, seeds=1) and rows[cmt]["before"]["unseen"] is None
    assert (f"| {cmt} | 96.22 ± 0.98 | 90.00 (1 seed; 0.00 M, 0.1 h) | 95.00 (1 seed; 0.00 M, 0.2 h; unseen seeds 93.25 (1)) | "
            "ab12cd34 (5.00 M) | 20 / 0 (400), p = 1.91e-06 |") in md
    assert "| Tactile | 91.41 ± 5.51 | 75.00 (1 seed; 0.00 M, 0.1 h) | not evaluated |  |  |" in md


def test_the_committed_table_from_the_97_percent_teacher_is_the_report_of_its_runs_against_table_one(monkeypatch):
    """docs/data/versus_97_teacher.json: `python -m vitac.report docs/data/results/residual_teacher --against
    docs/data/table1_runs --out <dir>`'s versus.json (docs/results.md)."""
    monkeypatch.chdir(ROOT)
    committed = json.loads((ROOT / "docs/data/versus_97_teacher.json").read_text())
    now, before = ([Path(d) for d in committed[side]] for side in ("now", "before"))
    assert committed["now"] == ["docs/data/results/residual_teacher"] and committed["before"] == ["docs/data/table1_runs"]
    made = table1.versus(table1.build(run_statuses(now), [0, 1, 2]),
                         table1.build(run_statuses(before), [0, 1, 2]))
    assert json.loads(json.dumps(made)) == committed["rows"]


def test_the_steps_figure_trials_are_blocks_of_held_out_episodes():
    success = [1, 0, 1, 1] + [0, 0, 0, 0] + [1, 1, 1, 1] + [1, 0]
    steps = [100, 120, 140, 90, 100, 110, 120, 95]  # the successes' steps, in episode order, as vitac.evaluate lists them
    cell = dict(episode_steps=table1.episode_steps(success, steps))
    assert cell["episode_steps"][:4] == [100, None, 120, 140]
    # a block without a success has no steps to show; the last, incomplete block is no trial
    assert table1.trials(cell, 4) == [(75.0, 120.0), (100.0, 105.0)]
    assert table1.episode_steps(success, steps[:-1]) is None  # lists that do not line up give no trials
    assert table1.trials(dict(episode_steps=None), 4) == []


def test_an_archived_run_reads_as_the_run_once_its_directory_and_checkpoint_are_gone(tmp_path):
    from vitac.analysis.archive import archive

    sweep = tmp_path / "sweep"
    runs = [fake_run(sweep, "Wrist", 0, 10, successes=episodes(300)), fake_run(sweep, "Tactile", 1, 4)]
    (runs[0] / "teacher.json").write_text('{"sha256": "0f"}')  # a distilled run's teacher goes with it
    (runs[0] / "unseen_seeds_eval.json").write_text('{"episodes": 400, "success_rate": 0.7}')  # and its unseen seeds
    before = table1.build(run_statuses([sweep]), seeds=[0, 1])
    for run in runs:
        archive(run, tmp_path / "archive" / run.name)
    shutil.rmtree(sweep)
    assert (tmp_path / "archive" / runs[0].name / "teacher.json").read_text() == '{"sha256": "0f"}'
    after = table1.build(run_statuses([tmp_path / "archive"]), seeds=[0, 1])
    assert not list((tmp_path / "archive").rglob("*.ckpt"))
    for row_before, row_after in zip(before["rows"], after["rows"], strict=True):
        for seed, cell in row_before["seeds"].items():
            assert {k: v for k, v in row_after["seeds"][seed].items() if k != "run"} == \
                   {k: v for k, v in cell.items() if k != "run"}
    wrist = next(r for r in after["rows"] if r["row"] == "Wrist")["seeds"][0]
    assert wrist["status"] == "done" and wrist["success"] == 0.75 and wrist["env_steps"] == 10 * PER_ITERATION
    assert wrist["unseen_success"] == 0.7
    with pytest.raises(SystemExit, match="is not allowed: it is not empty"):
        archive(fake_run(sweep, "Wrist", 2, 10), tmp_path / "archive" / runs[1].name)
    with pytest.raises(SystemExit, match="not a run directory to archive, it has no checkpoints/last.ckpt"):
        archive(tmp_path / "archive" / runs[0].name, tmp_path / "again")


def test_evaluate_missing_evaluates_finished_unevaluated_runs_beside_their_checkpoint_and_skips_archives(
        tmp_path, monkeypatch):
    from vitac.analysis.archive import archive
    from vitac.report import evaluate_missing, screw_cells, screw_runs, table_cells

    sweep = tmp_path / "sweep"
    run = fake_run(sweep, "Wrist", 0, 10)
    fake_run(sweep, "Tactile", 0, 4)  # partial: not evaluated
    fake_run(sweep, "Privileged", 0, 10, successes=episodes(300))  # evaluated already
    archive(fake_run(tmp_path / "other", "Wrist", 1, 10), sweep / "archived")  # done, no checkpoint to evaluate
    calls = []
    monkeypatch.setattr("vitac.evaluate.evaluate", lambda ckpt, **kw: calls.append((ckpt, kw["out"], kw["seed"])))
    screw = fake_run(sweep, "Screw: wrist", 2, 10)  # the screw figure's cells are evaluated too
    statuses = run_statuses([sweep])
    cells = table_cells(table1.build(statuses, seeds=[0, 1, 2])) + screw_runs(screw_cells(statuses, [0, 1, 2], 400))
    assert evaluate_missing(cells, episodes=400) == 2
    assert calls == [(str(run / "checkpoints" / "last.ckpt"), str(run / "checkpoints" / "last.eval.json"), 2_000_000),
                     (str(screw / "checkpoints" / "last.ckpt"), str(screw / "checkpoints" / "last.eval.json"), 2_000_000)]


def test_evaluate_missing_with_unseen_adds_the_unseen_seed_evaluation_once(tmp_path, monkeypatch):
    from vitac.report import evaluate_missing, table_cells

    sweep = tmp_path / "sweep"
    fresh = fake_run(sweep, "Wrist", 0, 10)  # neither evaluation yet
    held_out = fake_run(sweep, "Privileged", 0, 10, successes=episodes(300))  # the held-out one only
    calls = []
    monkeypatch.setattr("vitac.evaluate.evaluate", lambda ckpt, **kw: calls.append((kw["out"], kw["seed"])))
    cells = table_cells(table1.build(run_statuses([sweep]), seeds=[0]))
    assert evaluate_missing(cells, episodes=400, unseen=True) == 3
    assert sorted(calls) == sorted([(str(fresh / "checkpoints" / "last.eval.json"), 2_000_000),
                                    (str(fresh / "unseen_seeds_eval.json"), 3_000_000),
                                    (str(held_out / "unseen_seeds_eval.json"), 3_000_000)])
    (held_out / "unseen_seeds_eval.json").write_text((held_out / "checkpoints" / "last.eval.json").read_text())
    calls.clear()
    cells = table_cells(table1.build(run_statuses([sweep]), seeds=[0]))
    assert evaluate_missing(cells, episodes=400, unseen=True) == 2  # the one with both is left alone
    assert str(held_out / "unseen_seeds_eval.json") not in [out for out, _ in calls]


def test_report_draws_both_pads_force_fields_over_an_episode_for_each_policy(tmp_path):
    from vitac.analysis import force_fields

    run = train(compose_config(["preset=smoke", "obs=tactile", "fusion=naive", "reg=none", "logger=csv"],
                               output_dir=tmp_path / "run"))
    episode = force_fields.record_fields(run["checkpoint"], seed=2_000_000)
    assert episode["left"].shape == episode["right"].shape == (12, 32, 32)  # the smoke preset's 12 steps
    assert episode["left"].max() > 0  # the pads press on the peg
    assert len(episode["asymmetry"]) == 12 and all(a is None or 0 <= a <= 1 for a in episode["asymmetry"])
    sweep = fake_run(tmp_path / "sweep", "Privileged", 0, 10).parent
    result = subprocess.run([sys.executable, "-m", "vitac.report", str(sweep), "--out", str(tmp_path / "out"), "--qual",
                             f"Naive={run['checkpoint']}", f"Other={run['checkpoint']}"], cwd=ROOT,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "out" / "force_fields.png").stat().st_size > 0


def test_a_negative_residual_force_field_is_drawn_visibly_not_as_zero(tmp_path):
    """The policy's fields are residuals against the grasp, negative where a pad presses less: they are drawn on a
    diverging scale, where a dip shows as blue and a rise as red (a scale starting at 0 drew every dip black)."""
    import matplotlib.image as mpimg

    from vitac.analysis import force_fields

    left = np.zeros((6, 32, 32))
    left[:, 4:28, 4:16] = -1.5  # the pad presses less than at the grasp over a large patch
    right = np.zeros((6, 32, 32))
    right[:, 4:28, 4:16] = 1.5
    episode = dict(left=left, right=right, asymmetry=[1.0] * 6, success=True)
    force_fields.figure({"policy": episode}, tmp_path / "f.png", columns=3)
    rgb = mpimg.imread(tmp_path / "f.png")[..., :3]
    third = rgb.shape[0] // 3  # three rows of panels: the left pad's fields, the right pad's, the imbalance plot
    left_row, right_row = rgb[:third, : int(0.8 * rgb.shape[1])], rgb[third:2 * third, : int(0.8 * rgb.shape[1])]
    assert (left_row[..., 2] > left_row[..., 0] + 0.2).sum() > 1000  # the dip, blue
    assert (right_row[..., 0] > right_row[..., 2] + 0.2).sum() > 1000  # the rise, red


def test_report_refuses_a_run_whose_evaluation_report_was_cut_short_naming_it(tmp_path):
    run = fake_run(tmp_path / "runs", "Privileged", 0, 10)
    (run / "checkpoints" / "last.eval.json").write_text('{"episodes": 100, "success_rate": 0.9')
    result = subprocess.run([sys.executable, "-m", "vitac.report", str(tmp_path / "runs"), "--out", str(tmp_path / "out")],
                            cwd=ROOT, capture_output=True, text=True)
    assert result.returncode != 0 and "last.eval.json: cannot be read as a vitac.evaluate report (JSONDecodeError" in result.stderr
    assert not (tmp_path / "out" / "table1.md").exists()


def test_a_finished_sweep_starts_no_training_when_run_again(tmp_path):
    command = [sys.executable, "-m", "vitac.train", "-m", "seed=0", "+experiment/table1=privileged,tactile",
               "preset=smoke", "logger=csv", "resume=auto", f"hydra.sweep.dir={tmp_path}"]
    first = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, env={**__import__("os").environ})
    assert first.returncode == 0, first.stderr[-2000:]
    again = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    assert again.returncode == 0 and again.stdout.count("nothing to train") == 2, again.stdout[-2000:]
    assert "PPO:" not in again.stderr


def test_resume_auto_continues_an_interrupted_run_in_its_directory_keeping_its_metrics(tmp_path):
    overrides = ["preset=smoke", "experiment=table1/privileged", "resume=auto"]
    train(compose_config(overrides + ["trainer.iterations=1"], output_dir=tmp_path))  # the interrupted attempt
    resumed = train(compose_config(overrides + ["trainer.iterations=3"], output_dir=tmp_path))
    assert not resumed.get("skipped")
    epochs = sorted({int(r["epoch"]) for r in read_metrics(tmp_path) if r.get("epoch")})
    assert epochs == [0, 1, 2] and (tmp_path / "csv" / "metrics_part000.csv").is_file()
    assert torch.load(tmp_path / "checkpoints" / "last.ckpt", weights_only=False)["vitac"]["env_steps"] == 3 * 32
    assert train(compose_config(overrides + ["trainer.iterations=3"], output_dir=tmp_path))["skipped"]


def test_the_symmetry_sweep_scans_the_weight_and_the_mirror_beside_table_one_cmt_cells():
    params = yaml.safe_load((ROOT / "conf" / "sweep" / "symmetry.yaml").read_text())["hydra"]["sweeper"]["params"]
    assert list(params) == ["seed", "+experiment/symmetry"]
    scanned = set()
    for path in (ROOT / "conf" / "experiment" / "symmetry").glob("*.yaml"):
        cfg = compose_config(["+sweep=symmetry", f"+experiment/symmetry={path.stem}"])
        assert (cfg.obs.name, cfg.fusion._target_, cfg.preset.name, cfg.teacher_ckpt) == (
            "wrist_tactile", "vitac.models.fusion.CrossModalTransformer", "cpu_table1", "pretrained/privileged_contact_residual")
        scanned.add((cfg.reg.lambda_sym, cfg.reg.mirror, cfg.reg.weighting, cfg.reg.placement))
    # the weights 0 and 1 with the physical mirror, read at the encoder, are Table I's CMT and CMT + sym cells
    assert scanned == {(0.01, "physical", "absolute", "encoder"), (0.1, "physical", "absolute", "encoder"),
                       (0.1, "physical", "relative", "encoder"), (1.0, "image", "absolute", "encoder"),
                       (1.0, "physical", "absolute", "self_attention")}


@pytest.mark.parametrize("sweep", ["table1"])
def test_the_table_sweep_runs_seed_0_of_every_row_first(sweep):
    config = yaml.safe_load((ROOT / "conf" / "sweep" / f"{sweep}.yaml").read_text())
    params = config["hydra"]["sweeper"]["params"]
    assert list(params) == ["seed", "+experiment/table1"] and config["resume"] == "auto"  # the first varies slowest
    # The sensing rows, distilled at one budget; the privileged rows are the teachers, trained by their PPO recipes.
    assert params["+experiment/table1"] == "glob(*,exclude=privileged*)"
    assert config["defaults"] == [{"override /preset": "cpu_table1"}]
    from vitac.analysis.status import expected_rows

    assert expected_rows("table1/*") == [r.label for r in table1.ROWS]  # every row of the report, in the paper's order


def test_compare_adds_the_distillation_panel_only_when_a_run_distils(tmp_path, monkeypatch):
    import csv

    from vitac.analysis import compare

    def write(path, with_error):
        keys = ["charts/env_steps", "charts/SPS", "charts/success_rate", "eval/success_rate"]
        keys += ["losses/action_mse"] if with_error else []
        with open(path, "w", newline="") as f:
            writer = csv.DictWriter(f, keys)
            writer.writeheader()
            for i in range(1, 6):
                writer.writerow({"charts/env_steps": 1024 * i, "charts/SPS": 100, "charts/success_rate": 0.1 * i,
                                 "eval/success_rate": 0.1 * i, **({"losses/action_mse": 1 / i} if with_error else {})})
    write(tmp_path / "ppo.csv", False)
    write(tmp_path / "dagger.csv", True)
    panels = []
    original = compare.compare

    def spy(runs, out, title=""):
        import matplotlib.pyplot as plt

        original(runs, out, title)
        panels.append(len(plt.gcf().axes))
    monkeypatch.setattr(compare, "compare", spy)
    compare.main(["--run", f"ppo={tmp_path / 'ppo.csv'}", "--out", str(tmp_path / "a.png")])
    compare.main(["--run", f"ppo={tmp_path / 'ppo.csv'}", "--run", f"dagger={tmp_path / 'dagger.csv'}",
                  "--out", str(tmp_path / "b.png")])
    assert panels == [3, 4]
    assert (tmp_path / "a.png").stat().st_size > 1000 and (tmp_path / "b.png").stat().st_size > 1000


def test_a_video_frame_of_zero_force_fields_draws_without_a_warning():
    """The first step of an episode: the residual fields (paper eq. 2) are exactly zero, no arrow to scale."""
    import warnings

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from vitac.viz import _frame

    fig, axes = plt.subplots(1, 4)
    zero = np.zeros((3, 32, 32), dtype=np.float32)
    between = zero.copy()
    between[:2, 1, 1] = 0.3  # shear on a taxel between the arrows drawn (every third): still none to scale
    for left, right in ((zero, zero), (between, between)):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            frame = _frame(fig, axes, np.zeros((240, 240, 3), np.uint8), np.zeros((64, 64, 3), np.uint8), left,
                           right, step=0, info={"keypoint_distance": 0.01})
        assert frame.ndim == 3 and frame.shape[2] == 3
    plt.close(fig)


def test_the_claims_compared_are_the_papers():
    labels = {row.label for row in table1.ROWS}
    assert all(a in labels and b in labels for a, b in table1.CLAIMS)
    # "achieving 96.59%, nearly matching the privileged wrist+force configuration (96.09%)"
    assert ("Fusion - CMT + Symmetry (lambda_sym=1)", "Wrist + Contact forces") in table1.CLAIMS
