"""End-to-end tier: smoke training run, seeding, exact resume, warm starts, evaluation, export, multirun."""

from __future__ import annotations

import csv
import hashlib
import json
import logging
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from tests.conftest import CONF, compose_config
from vitac.models.encoders import native_bfloat16
from vitac.models.normalizer import RunningNormalizer
from vitac.run_config import build_policy_from_config, load_policy, task_settings
from vitac.tasks.insertion.config import InsertionConfig
from vitac.training import load_weights, train
from vitac.utils.checkpoint import load_checkpoint

ROOT = Path(CONF).parent
SMOKE = ["preset=smoke", "obs=wrist_tactile", "fusion=cmt", "reg=sym"]


def _rows(path):
    with open(path) as f:
        return [r for r in csv.DictReader(f)]


def _losses(run):
    rows = [r for r in _rows(run["metrics_csv"]) if r.get("losses/loss")]
    return [(r["epoch"], r["losses/loss"], r["losses/value_loss"], r["losses/sym_loss"], r["charts/reward_per_step"])
            for r in rows]


def test_smoke_run_writes_checkpoint_and_metrics_and_logs_every_loss_term(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="vitac.training")
    run = train(compose_config(SMOKE, output_dir=tmp_path / "run"))
    precision = "bfloat16" if native_bfloat16("cpu") else "float32"  # the default, auto, follows the CPU
    assert f"image convolutions in {precision} (encoder.image.bf16=auto)" in caplog.messages
    # last.ckpt has one writer (no Lightning "last-v1.ckpt" beside it), periodic ones are named by iteration
    assert sorted(p.name for p in (tmp_path / "run" / "checkpoints").iterdir()) == [
        "best.ckpt", "iter_00001.ckpt", "iter_00002.ckpt", "last.ckpt"]
    rows = [r for r in _rows(run["metrics_csv"]) if r.get("losses/loss")]
    assert len(rows) == 2
    for key in ("losses/policy_loss", "losses/value_loss", "losses/bounds_loss", "losses/entropy", "losses/sym_loss",
                "losses/approx_kl", "losses/clipfrac", "charts/SPS", "charts/success_rate"):
        assert rows[-1][key] != "", key
    assert float(rows[-1]["losses/sym_loss"]) > 0
    assert run["preset"] == "smoke"
    assert (tmp_path / "run" / "videos" / "iter_00002.mp4").stat().st_size > 1000  # every 2nd evaluation


def test_same_seed_same_first_iterations(tmp_path):
    a = train(compose_config(SMOKE + ["seed=3"], output_dir=tmp_path / "a"))
    b = train(compose_config(SMOKE + ["seed=3"], output_dir=tmp_path / "b"))
    c = train(compose_config(SMOKE + ["seed=4"], output_dir=tmp_path / "c"))
    assert _losses(a) == _losses(b)
    assert _losses(a) != _losses(c)


def test_killed_run_resumes_to_the_same_metrics(tmp_path):
    full = train(compose_config(SMOKE + ["trainer.iterations=3"], output_dir=tmp_path / "full"))
    train(compose_config(SMOKE + ["trainer.iterations=2"], output_dir=tmp_path / "part"))  # "killed" after iteration 2
    resumed = train(compose_config(SMOKE + ["trainer.iterations=3", f"resume={tmp_path / 'part'}"],
                                   output_dir=tmp_path / "resumed"))
    (epoch, *full_losses, full_reward), = [row for row in _losses(full) if row[0] == "2"]
    (r_epoch, *resumed_losses, resumed_reward), = _losses(resumed)
    assert r_epoch == epoch
    # Environments, recurrent state and PPO's generator resume exactly: the rollout is identical.
    assert resumed_reward == full_reward
    # Weights and optimizer resume; CPU conv kernels are reproducible across processes only to ~1e-6.
    assert [float(x) for x in resumed_losses] == pytest.approx([float(x) for x in full_losses], rel=1e-4, abs=1e-9)
    # The environments split over other processes (here a worker each instead of the main process alone) resume too.
    split = train(compose_config(SMOKE + ["trainer.iterations=3", "envs.num_workers=2", f"resume={tmp_path / 'part'}"],
                                 output_dir=tmp_path / "split"))
    (s_epoch, *split_losses, split_reward), = _losses(split)
    assert (s_epoch, split_reward) == (epoch, full_reward)
    assert [float(x) for x in split_losses] == pytest.approx([float(x) for x in full_losses], rel=1e-4, abs=1e-9)


def test_a_run_resumed_in_place_again_and_again_keeps_one_best_and_one_last_checkpoint(tmp_path, monkeypatch):
    evaluations = iter(range(1, 100))  # every evaluation better than the last: each writes best.ckpt anew
    monkeypatch.setattr("vitac.algos.callbacks.run_episodes",
                        lambda *a, **k: dict(success_rate=next(evaluations) / 100, steps_to_success_mean=None))
    checkpoints = tmp_path / "run" / "checkpoints"
    train(compose_config(SMOKE + ["trainer.iterations=1", "resume=auto"], output_dir=tmp_path / "run"))
    (checkpoints / "last.ckpt").unlink()  # killed after its best and periodic checkpoints, before last.ckpt
    for iterations in (2, 3, 4):  # then killed after 2, after 3, and finished: `resume=auto` continues in place
        train(compose_config(SMOKE + [f"trainer.iterations={iterations}", "resume=auto"], output_dir=tmp_path / "run"))
    names = sorted(p.name for p in checkpoints.glob("*.ckpt"))
    assert names == ["best.ckpt", "iter_00001.ckpt", "iter_00002.ckpt", "iter_00003.ckpt", "iter_00004.ckpt",
                     "last.ckpt"]


@pytest.mark.parametrize("written", [0, 1, 2])
def test_a_kill_after_the_checkpoint_but_before_the_metrics_row_leaves_no_hole_in_the_metrics(tmp_path, monkeypatch,
                                                                                             written):
    """last.ckpt is written at an iteration's end before Lightning's logger writes that iteration's row: killed
    in between (here: the logger writes `written` rows, then nothing more), the resumed run still logs every
    iteration the checkpoint held exactly once."""
    from lightning.pytorch.loggers import csv_logs

    from vitac.run_dirs import read_metrics

    real_save, calls = csv_logs.ExperimentWriter.save, []

    def save_until_killed(self):
        calls.append(1)
        if len(calls) > written:
            raise RuntimeError("killed")  # nothing reaches the file from here on
        real_save(self)

    job = SMOKE + ["eval.video_every=0", "resume=auto", "logger=csv"]
    monkeypatch.setattr(csv_logs.ExperimentWriter, "save", save_until_killed)
    with pytest.raises(RuntimeError, match="killed"):
        train(compose_config(job + ["trainer.iterations=4"], output_dir=tmp_path / "run"))
    monkeypatch.setattr(csv_logs.ExperimentWriter, "save", real_save)
    train(compose_config(job + ["trainer.iterations=4"], output_dir=tmp_path / "run"))
    epochs = [r["epoch"] for r in read_metrics(tmp_path / "run") if r.get("losses/loss")]
    assert epochs == ["0", "1", "2", "3"]


def test_sigterm_to_the_whole_job_saves_the_current_iteration_and_resume_continues_from_it(tmp_path):
    # No periodic checkpoints: last.ckpt can only come from the SIGTERM. 4 envs in 2 groups: one worker process,
    # which gets the SIGTERM too (as from SLURM or `kill -- -PGID`).
    args = ["preset=smoke", "experiment=table1/privileged", "envs.num_envs=4", "envs.num_workers=2", "checkpoint.every_n_epochs=1000",
            "eval.every=1000", "logger=csv"]
    proc = subprocess.Popen([sys.executable, "-m", "vitac.train", *args, "trainer.iterations=500",
                             f"hydra.run.dir={tmp_path / 'run'}"], cwd=ROOT, stderr=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, start_new_session=True)
    progress = ""
    while "| 3/500" not in progress and proc.poll() is None:  # the progress bar after iteration 3
        progress += os.read(proc.stderr.fileno(), 4096).decode(errors="replace")
    os.killpg(proc.pid, signal.SIGTERM)
    stdout, _ = proc.communicate(timeout=120)
    saved = load_checkpoint(tmp_path / "run" / "checkpoints" / "last.ckpt")
    done = saved["vitac"]["env_steps"] // (16 * 4)  # iterations of 16 steps x 4 envs
    assert 3 <= done < 500 and "vitac: stopped by SIGTERM" in stdout
    resumed = train(compose_config(args + [f"trainer.iterations={done + 1}", f"resume={tmp_path / 'run'}"],
                                   output_dir=tmp_path / "resumed"))
    full = train(compose_config(args + [f"trainer.iterations={done + 1}"], output_dir=tmp_path / "full"))
    (epoch, *_, reward), = _losses(resumed)
    assert epoch == str(done) and reward == [row for row in _losses(full) if row[0] == epoch][0][-1]


def test_sigterm_to_an_image_run_closes_its_evaluation_renderers_before_exit(tmp_path):
    # Its evaluation environments render in the main process; left open, each one's renderer was freed after
    # EGL had shut down at exit and printed an EGL_NOT_INITIALIZED traceback.
    args = [*SMOKE, "eval.every=1", "eval.video_every=0", "checkpoint.every_n_epochs=1000", "logger=csv",
            "trainer.iterations=500", f"hydra.run.dir={tmp_path / 'run'}"]
    proc = subprocess.Popen([sys.executable, "-m", "vitac.train", *args], cwd=ROOT, stderr=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, start_new_session=True)
    progress = ""
    while "| 2/500" not in progress and proc.poll() is None:  # two evaluations done
        progress += os.read(proc.stderr.fileno(), 4096).decode(errors="replace")
    os.killpg(proc.pid, signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=120)
    assert "vitac: stopped by SIGTERM" in stdout
    assert "Exception ignored" not in progress + stderr and "EGL_NOT_INITIALIZED" not in progress + stderr


def test_resuming_without_the_curriculum_restores_the_configured_ranges(tmp_path):
    base = ["preset=smoke", "experiment=table1/privileged", "curriculum=randomization"]  # from scale 0.0
    train(compose_config(base + ["trainer.iterations=1"], output_dir=tmp_path / "part"))

    def env_scales(run_dir, extra):
        run = train(compose_config(base + ["trainer.iterations=2", f"resume={tmp_path / 'part'}"] + extra,
                                   output_dir=run_dir))
        states = load_checkpoint(run["checkpoint"])["vitac"]["env_states"]
        return {s["task"]["randomization_scale"] for s in states}

    assert env_scales(tmp_path / "kept", []) == {0.0}  # exact resume keeps the curriculum's stage
    assert env_scales(tmp_path / "off", ["curriculum=none"]) == {1.0}


def test_init_ckpt_starts_a_new_run_from_another_runs_weights(tmp_path):
    base = ["preset=smoke", "experiment=table1/privileged", "trainer.iterations=1"]
    first = train(compose_config(base, output_dir=tmp_path / "first"))
    source = load_checkpoint(first["checkpoint"])["state_dict"]
    warm = train(compose_config(base + ["seed=1", f"init_ckpt={first['checkpoint']}", "init_exclude=[policy.head.log_std]",
                                        "algo.lr=1e-12"], output_dir=tmp_path / "warm"))
    fresh = train(compose_config(base + ["seed=1", "algo.lr=1e-12"], output_dir=tmp_path / "fresh"))
    warm_state, fresh_state = (load_checkpoint(r["checkpoint"])["state_dict"] for r in (warm, fresh))
    k = "policy.head.mean.weight"
    assert torch.allclose(warm_state[k], source[k], atol=1e-6) and not torch.allclose(fresh_state[k], source[k])
    # The excluded layer keeps its fresh initialisation (zero weights, bias log_std_init).
    assert torch.allclose(warm_state["policy.head.log_std.weight"], fresh_state["policy.head.log_std.weight"], atol=1e-6)
    with pytest.raises(ValueError, match="init_ckpt=.*does not fit"):
        train(compose_config(SMOKE + [f"init_ckpt={first['checkpoint']}"], output_dir=tmp_path / "bad"))


def _warm_started(experiment: str, ckpt: str, tmp_path):
    """The policy of a Table I row after load_weights from `ckpt` (the module stand-in has PPO's state keys)."""
    cfg = compose_config(["preset=smoke", f"experiment={experiment}"], output_dir=tmp_path / experiment)
    holder = torch.nn.Module()
    holder.policy = build_policy_from_config(cfg, InsertionConfig.from_dict(task_settings(cfg)))
    holder.value_normalizer = RunningNormalizer((), clip=float("inf"))
    load_weights(holder, ckpt, [])
    return holder.policy, cfg


def test_init_ckpt_adds_contact_forces_with_zero_weights_so_the_warm_policy_acts_as_the_checkpoint(tmp_path):
    first = train(compose_config(["preset=smoke", "experiment=table1/privileged", "trainer.iterations=2"], output_dir=tmp_path / "first"))
    source, _, _ = load_policy(first["checkpoint"])
    warm, cfg = _warm_started("table1/privileged_contact", first["checkpoint"], tmp_path)
    shapes = InsertionConfig.from_dict(task_settings(cfg)).observation_shapes()
    generator = torch.Generator().manual_seed(0)
    obs = {k: 3 * torch.randn(5, 4, *shapes[k], generator=generator) for k in ("proprio", "peg_state", "contact_forces",
                                                                              "critic_state")}
    starts = torch.zeros(5, 4)
    starts[0] = 1.0
    expected = source({k: v for k, v in obs.items() if k != "contact_forces"}, source.initial_state(4), starts)
    got = warm(obs, warm.initial_state(4), starts)
    for e, g in zip(expected[:3], got[:3], strict=True):
        assert torch.allclose(e, g, atol=1e-6)
    # The new columns are zero but trainable: the contact forces reach the gradient.
    weight = warm.head.lstm.weight_ih_l0
    added = slice(source.feature_dim, warm.feature_dim)
    assert warm.feature_dim == source.feature_dim + shapes["contact_forces"][0]
    assert torch.equal(weight[:, added], torch.zeros_like(weight[:, added]))
    got[0].square().sum().backward()
    assert weight.grad[:, added].abs().sum() > 0
    # A warm start that changes which observations come first is refused, naming the checkpoint.
    with pytest.raises(ValueError, match="init_ckpt=.*does not fit this policy"):
        _warm_started("table1/fusion_naive", first["checkpoint"], tmp_path)
    # And a training run goes on from it.
    run = train(compose_config(["preset=smoke", "experiment=table1/privileged_contact", "trainer.iterations=1",
                                f"init_ckpt={first['checkpoint']}"], output_dir=tmp_path / "warm_run"))
    assert Path(run["checkpoint"]).is_file()


def test_adaptive_lr_schedule_steps_after_every_minibatch_or_at_its_boundary_and_fixed_keeps_lr(tmp_path):
    base = ["preset=smoke", "experiment=table1/privileged"]
    lr = compose_config(base).algo.lr
    steps = 2 * 2  # smoke: 2 mini-epochs of 2 minibatches per iteration
    # With a threshold no KL comes near, the rate grows by 1.5 at every minibatch step (its other branches:
    # test_adaptive_lr_follows_rl_games_rule_within_bounds).
    run = train(compose_config(base + ["algo.lr_schedule=adaptive", "algo.kl_threshold=1e9"], output_dir=tmp_path / "a"))
    logged = [float(r["charts/lr"]) for r in _rows(run["metrics_csv"]) if r.get("charts/lr")]
    assert logged == pytest.approx([lr * 1.5 ** steps, lr * 1.5 ** (2 * steps)])
    # Moved once per mini-epoch, or once per iteration, on the mean KL.
    for every, moves in (("mini_epoch", 2), ("iteration", 1)):
        per = train(compose_config(base + ["algo.lr_schedule=adaptive", "algo.kl_threshold=1e9",
                                           f"algo.lr_schedule_every={every}"], output_dir=tmp_path / every))
        logged = [float(r["charts/lr"]) for r in _rows(per["metrics_csv"]) if r.get("charts/lr")]
        assert logged == pytest.approx([lr * 1.5 ** moves, lr * 1.5 ** (2 * moves)])
    fixed = train(compose_config(base, output_dir=tmp_path / "f"))
    assert [float(r["charts/lr"]) for r in _rows(fixed["metrics_csv"]) if r.get("charts/lr")] == pytest.approx([lr, lr])
    # The learning curves of one branch with the other overlaid, the KL and learning-rate panel included.
    subprocess.run([sys.executable, "-m", "vitac.runs", "plot", run["metrics_csv"], "--compare", fixed["metrics_csv"],
                    "--out", str(tmp_path / "curves.png")], check=True, cwd=ROOT, capture_output=True)
    assert (tmp_path / "curves.png").stat().st_size > 10_000
    with pytest.raises(ValueError, match="algo.lr_schedule='cosine' is not allowed"):
        train(compose_config(base + ["algo.lr_schedule=cosine"], output_dir=tmp_path / "bad"))


def test_critic_from_a_privileged_run(tmp_path):
    privileged = train(compose_config(["preset=smoke", "experiment=table1/privileged"], output_dir=tmp_path / "priv"))
    run = train(compose_config(SMOKE + [f"critic_ckpt={privileged['checkpoint']}", "freeze_critic=true"],
                               output_dir=tmp_path / "aacd"))
    import torch

    a = torch.load(privileged["checkpoint"], weights_only=False)["state_dict"]
    b = torch.load(run["checkpoint"], weights_only=False)["state_dict"]
    critic_keys = [k for k in a if k.startswith("policy.critic.")]
    assert critic_keys and all(torch.equal(a[k], b[k]) for k in critic_keys)  # loaded and kept frozen


def test_a_sweep_with_one_bad_cell_trains_nothing_and_names_the_cell(tmp_path):
    """Every job of a multirun is checked before the first starts (hydra_plugins/vitac_sweeper): seed 0 is not
    trained hours before seed -1's typo stops the sweep."""
    cmd = [sys.executable, "-m", "vitac.train", "-m", "preset=smoke", "seed=0,-1", "+experiment/table1=tactile,wrist",
           f"hydra.sweep.dir={tmp_path}/sweep"]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert result.returncode == 2 and not (tmp_path / "sweep").exists()
    assert result.stderr.strip() == ("error: job 2 of 4 (preset=smoke seed=-1 +experiment/table1=tactile): seed=-1 is "
                                     "not allowed: expected an integer in [0, 2147483647] or null; no job was started")


@pytest.mark.slow
def test_multirun_over_seeds_and_every_experiment(tmp_path):
    cmd = [sys.executable, "-m", "vitac.train", "-m", "preset=smoke", "seed=0,1",
           f"hydra.sweep.dir={tmp_path}/sweep"]
    subprocess.run(cmd, check=True, timeout=600)
    assert len(list((tmp_path / "sweep").rglob("last.ckpt"))) == 2
    # `experiment=glob(table1/*)` would launch nothing: Hydra's glob lists a group's own options, not its folders'.
    cmd = [sys.executable, "-m", "vitac.train", "-m", "preset=smoke", "+experiment/table1=glob(*)",
           f"hydra.sweep.dir={tmp_path}/experiments"]
    subprocess.run(cmd, check=True, timeout=1200)
    assert len(list((tmp_path / "experiments").rglob("last.ckpt"))) == 10


def teacher_steps(ckpt) -> int:
    return int(torch.load(ckpt, weights_only=False)["vitac"]["env_steps"])


def test_a_student_with_the_teachers_observations_and_architecture_converges_to_its_actions(tmp_path):
    teacher = train(compose_config(["preset=smoke", "experiment=table1/privileged"], output_dir=tmp_path / "teacher"))
    student = train(compose_config(["preset=smoke", "experiment=table1/privileged", "algo=dagger", "seed=1",
                                    f"teacher_ckpt={teacher['checkpoint']}", "trainer.iterations=12",
                                    "algo.mini_epochs=8", "algo.beta_iterations=4", "eval.every=100"],
                                   output_dir=tmp_path / "student"))
    mse = [float(r["losses/action_mse"]) for r in _rows(Path(student["metrics_csv"])) if r.get("losses/action_mse")]
    assert len(mse) == 12 and max(mse[-3:]) < 0.2 * mse[0], mse
    betas = [float(r["charts/beta"]) for r in _rows(Path(student["metrics_csv"])) if r.get("charts/beta")]
    assert betas[0] == 1.0 and betas[4:] == [0.0] * 8  # the teacher acts first, then the student alone
    # The run names its teacher by content, so a shipped name that later points elsewhere cannot mislead.
    record = json.loads((tmp_path / "student" / "teacher.json").read_text())
    assert record["sha256"] == hashlib.sha256(Path(teacher["checkpoint"]).read_bytes()).hexdigest()
    assert record["env_steps"] == teacher_steps(teacher["checkpoint"]) > 0
    # Distilled further from its own weights, the student acts from the first step and starts where it ended.
    more = train(compose_config(["preset=smoke", "experiment=table1/privileged", "algo=dagger", "seed=2",
                                 f"teacher_ckpt={teacher['checkpoint']}", f"init_ckpt={student['checkpoint']}",
                                 "algo.beta_start=0", "trainer.iterations=2", "eval.every=100"],
                                output_dir=tmp_path / "more"))
    rows = [r for r in _rows(Path(more["metrics_csv"])) if r.get("losses/action_mse")]
    assert [float(r["charts/beta"]) for r in rows] == [0.0, 0.0]
    assert float(rows[0]["losses/action_mse"]) < 0.5 * mse[0], (rows[0]["losses/action_mse"], mse)


def test_a_checkpoint_written_before_the_layout_change_still_loads(tmp_path):
    # Runs before 2026-12-01 stored `env` for `task`, the default cmt + sym beside image-free observations (never
    # built) and the critic under models/head.py: load_policy reads them as the policy they always were.
    run = train(compose_config(["preset=smoke", "experiment=table1/privileged"], output_dir=tmp_path / "run"))
    checkpoint = torch.load(run["checkpoint"], weights_only=False)
    config = checkpoint["vitac_config"]
    config["env"] = {k: v for k, v in config.pop("task").items() if k != "_target_"}
    config["fusion"] = {"_target_": "vitac.models.fusion.CrossModalTransformer", "_partial_": True, "num_heads": 4}
    config["reg"] = {"_target_": "vitac.models.symmetry.SymmetryRegularizer", "lambda_sym": 1.0}
    config["critic"]["_target_"] = "vitac.models.head.StateCritic"
    torch.save(checkpoint, tmp_path / "old.ckpt")
    old, _, settings = load_policy(tmp_path / "old.ckpt")
    new, _, _ = load_policy(run["checkpoint"])
    assert old.fusion is None and not old.uses_symmetry and settings["observations"][-1] == "critic_state"
    assert all(torch.equal(a, b) for a, b in zip(old.state_dict().values(), new.state_dict().values(), strict=True))

