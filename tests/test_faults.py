"""Fault injection: simulator breakdowns, non-finite updates and unusable output directories are contained,
counted or refused with a message, and nothing already written is lost."""

from __future__ import annotations

import csv
import os

import numpy as np
import pytest
import torch

from tests.conftest import compose_config
from vitac.envs.gym_env import TaskEnv
from vitac.run_dirs import check_output_dir
from vitac.training import train

SMOKE = ["preset=smoke", "experiment=table1/privileged", "logger=csv"]


def _metrics(run: dict) -> list[dict]:
    with open(run["metrics_csv"]) as f:
        return list(csv.DictReader(f))


def test_a_non_finite_observation_ends_its_episode_zeroed_and_named():
    env = TaskEnv({"observations": ["proprio", "peg_state"]}, seed=0)
    env.reset(seed=0)
    env.step(np.zeros(6))
    original = env.task._sources["peg_state"]
    env.task._sources["peg_state"] = lambda physics: np.full(10, np.nan, np.float32)  # a broken sensor
    obs, reward, terminated, truncated, info = env.step(np.zeros(6))
    assert terminated and not truncated and reward == 0.0
    assert info["outcome"] == "non-finite observation or reward" and not info["success"]
    assert np.all(np.isfinite(obs["peg_state"])) and np.all(obs["peg_state"] == 0)
    env.task._sources["peg_state"] = original
    obs, _ = env.reset(seed=1)  # the next episode is whole
    assert np.all(np.isfinite(obs["peg_state"]))
    env.close()


def test_training_counts_broken_episodes_and_continues(tmp_path, monkeypatch):
    from vitac.tasks.insertion.task import InsertionTask

    calls = {"n": 0}
    original = InsertionTask.peg_state

    def flaky_sensor(self, physics):  # every 7th reading of the privileged state is NaN
        calls["n"] += 1
        value = original(self, physics)
        return np.full_like(value, np.nan) if calls["n"] % 7 == 0 else value

    monkeypatch.setattr(InsertionTask, "peg_state", flaky_sensor)
    run = train(compose_config(SMOKE, output_dir=tmp_path))
    diverged = [float(r["charts/broken_episodes"]) for r in _metrics(run) if r.get("charts/broken_episodes")]
    assert sum(diverged) >= 3 and np.isfinite(run["metrics"]["losses/loss"])
    checkpoint = torch.load(run["checkpoint"], weights_only=False)
    assert all(torch.isfinite(v).all() for v in checkpoint["state_dict"].values() if v.is_floating_point())


def test_a_run_of_non_finite_updates_stops_with_a_named_cause_and_a_checkpoint(tmp_path, monkeypatch):
    from vitac.algos.ppo import PPO

    original = PPO.minibatch_losses

    def poisoned(self, mb):
        terms = original(self, mb)
        return dict(terms, loss=terms["loss"] * float("nan"))

    monkeypatch.setattr(PPO, "minibatch_losses", poisoned)
    with pytest.raises(RuntimeError, match=r"2 iterations in a row had non-finite gradients"):
        train(compose_config(SMOKE + ["trainer.iterations=5", "trainer.max_nonfinite_iterations=2"],
                             output_dir=tmp_path))
    checkpoint = torch.load(tmp_path / "checkpoints" / "last.ckpt", weights_only=False)
    assert checkpoint["vitac"]["env_steps"] == 2 * 32
    assert all(torch.isfinite(v).all() for v in checkpoint["state_dict"].values() if v.is_floating_point())


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_a_read_only_output_directory_is_refused_before_anything_is_built(tmp_path):
    out = tmp_path / "ro"
    out.mkdir()
    out.chmod(0o500)
    with pytest.raises(OSError, match="is not writable"):
        train(compose_config(SMOKE, output_dir=out / "run"))


def test_an_unwritable_or_full_output_directory_is_refused_naming_it(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the run directory should go")
    with pytest.raises(OSError, match=r"output directory .*file/run.* is not writable"):
        check_output_dir(blocker / "run")
    with pytest.raises(OSError, match=r"MiB free, less than the 1048576 MiB a run needs"):
        check_output_dir(tmp_path / "run", min_free=2**40)  # a disk with less than a tebibyte free


def test_a_killed_worker_is_restarted_its_episodes_truncated_and_counted():
    import signal

    from vitac.envs.vector_env import RESTARTED, TaskVectorEnv

    venv = TaskVectorEnv({"observations": ["proprio", "peg_state"]}, num_envs=4, num_workers=2, seed=0, max_restarts=1)
    try:
        venv.reset(seed=0)
        for _ in range(3):
            venv.step(np.zeros((4, 6)))
        victim = venv._procs[0].pid
        os.kill(victim, signal.SIGKILL)
        obs, rewards, terminated, truncated, info = venv.step(np.zeros((4, 6)))
        outcomes = [e.get("outcome") for e in info["env_infos"]]
        assert outcomes[:2] == [RESTARTED, RESTARTED] and list(truncated[:2]) == [True, True]
        assert sorted(info["final_obs"]) == [0, 1] and not any(truncated[2:])  # the other worker's episodes go on
        assert venv.restarts == 1 and venv._procs[0].pid != victim and np.all(np.isfinite(obs["proprio"]))
        before = obs["proprio"][:2].copy()
        for _ in range(3):  # the replacement steps like any worker
            obs, *_ = venv.step(np.full((4, 6), 0.5))
        assert np.abs(obs["proprio"][:2, :3] - before[:, :3]).min() > 1e-3  # its hands moved
        os.kill(venv._procs[1].pid, signal.SIGKILL)  # past max_restarts: the run stops, naming the process
        with pytest.raises(RuntimeError, match=r"died \(exit code -9\) during 'step' after 1 restarts"):
            venv.step(np.zeros((4, 6)))
    finally:
        venv.close()


def test_a_write_failure_mid_run_stops_it_naming_the_file_and_keeps_the_last_checkpoint(tmp_path, monkeypatch):
    import errno

    import vitac.utils.checkpoint as checkpoint_module

    real_save, calls = torch.save, {"n": 0}

    def disk_fills_up(obj, path, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] > 2:  # the first iteration's checkpoints are written, then the disk is full
            with open(path, "wb") as f:
                f.write(b"\x00" * 100)  # half a file
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_save(obj, path, *args, **kwargs)

    monkeypatch.setattr(checkpoint_module.torch, "save", disk_fills_up)
    with pytest.raises(OSError, match=r"could not write checkpoint .*\.ckpt \(No space left on device\); the previous"):
        train(compose_config(SMOKE + ["trainer.iterations=3", "checkpoint.every_n_epochs=1"], output_dir=tmp_path))
    monkeypatch.setattr(checkpoint_module.torch, "save", real_save)
    last = torch.load(tmp_path / "checkpoints" / "last.ckpt", weights_only=False)  # whole, from iteration 1
    assert last["vitac"]["env_steps"] == 32
    assert not list((tmp_path / "checkpoints").glob(".*.tmp"))  # no half-written file left behind


# A 500-iteration smoke run with one worker process and no periodic checkpoints: last.ckpt can only come from the
# per-iteration save or a signal. Iterations are 16 steps of 4 envs.
JOB = ["preset=smoke", "experiment=table1/privileged", "envs.num_envs=4", "envs.num_workers=2",
       "checkpoint.every_n_epochs=1000", "eval.every=1000", "logger=csv"]


def _training_job_after(iterations: int, run_dir, *extra: str):
    """A training job in its own process group, returned once its progress bar shows `iterations` done."""
    import subprocess
    import sys

    from tests.conftest import CONF

    proc = subprocess.Popen([sys.executable, "-m", "vitac.train", *JOB, "trainer.iterations=500",
                             f"hydra.run.dir={run_dir}", *extra], cwd=os.path.dirname(CONF), stderr=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, start_new_session=True)
    progress = ""
    while f"| {iterations}/500" not in progress and proc.poll() is None:
        progress += os.read(proc.stderr.fileno(), 4096).decode(errors="replace")
    return proc


def test_ctrl_c_to_the_whole_job_saves_the_current_iteration_and_a_second_stops_at_once(tmp_path):
    import signal

    proc = _training_job_after(3, tmp_path / "run")
    os.killpg(proc.pid, signal.SIGINT)  # what a terminal sends: the worker process gets it too
    stdout, stderr = proc.communicate(timeout=120)
    assert "vitac: stopped by SIGINT (Ctrl-C)" in stdout, stdout + stderr[-2000:]
    saved = torch.load(tmp_path / "run" / "checkpoints" / "last.ckpt", weights_only=False)
    assert 3 <= saved["vitac"]["env_steps"] // (16 * 4) < 500
    assert "died" not in stdout + stderr  # the worker ignored it and was closed by the main process


def test_sigkill_at_a_random_point_loses_at_most_the_iteration_in_progress(tmp_path):
    import random
    import signal
    import time

    proc = _training_job_after(4, tmp_path / "run")
    time.sleep(random.Random().uniform(0.0, 1.5))  # anywhere in the next iterations, mid-write included
    os.killpg(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=60)
    saved = torch.load(tmp_path / "run" / "checkpoints" / "last.ckpt", weights_only=False)  # whole
    done = saved["vitac"]["env_steps"] // (16 * 4)
    assert done >= 4
    resumed = train(compose_config(JOB + ["resume=auto", f"trainer.iterations={done + 1}"], output_dir=tmp_path / "run"))
    assert not resumed.get("skipped") and np.isfinite(resumed["metrics"]["losses/loss"])


def test_checkpoints_load_weights_only_and_one_holding_code_is_refused(tmp_path):
    from vitac.utils.checkpoint import load_checkpoint

    run = train(compose_config(SMOKE, output_dir=tmp_path / "run"))
    checkpoint = load_checkpoint(run["checkpoint"])  # environment and RNG states included
    assert checkpoint["vitac"]["env_steps"] == 64 and checkpoint["vitac"]["env_states"][0]["qacc_warmstart"].size > 0

    class Payload:  # what a malicious file would carry: unpickling calls os.system
        def __reduce__(self):
            return (os.system, ("touch " + str(tmp_path / "pwned"),))

    checkpoint["vitac"]["extra"] = Payload()
    torch.save(checkpoint, tmp_path / "evil.ckpt")  # a checkpoint file like any other, with the payload inside
    with pytest.raises(ValueError, match=r"holds objects other than tensors, numpy arrays and numbers"):
        load_checkpoint(tmp_path / "evil.ckpt")
    assert not (tmp_path / "pwned").exists()



# Every kind of bad value, in every group: each is refused by its key before a policy or an environment is built.
BAD_VALUES = [
    "envs.num_envs=0", "envs.num_envs=-4", "envs.num_workers=-1", "envs.max_restarts=-1", "envs.step_in_main=2",
    "eval.every=0", "eval.episodes=0", "eval.video_every=-1", "checkpoint.every_n_epochs=0",
    "checkpoint.save_top_k=abc", "trainer.iterations=0", "trainer.rollout_threads=0", "trainer.update_threads=-2",
    "trainer.deterministic=maybe", "trainer.max_nonfinite_iterations=0", "trainer.accelerator=tpu",
    "algo.horizon=0", "algo.seq_len=0", "algo.minibatch_size=0", "algo.mini_epochs=0", "algo.lr=0", "algo.lr=-1",
    "algo.gamma=1.5", "algo.gamma=-0.1", "algo.gae_lambda=2", "algo.clip=0", "algo.clip=-0.2",
    "algo.critic_coef=-1", "algo.grad_norm=0", "algo.entropy_coef=-1", "algo.bounds_loss_coef=-1",
    "algo.normalize_input=yes", "algo.lr_schedule=cosine", "+curriculum.start=0.5", "reg.lambda_sym=-1",
    "reg.mirror=diag", "fusion.num_heads=0", "fusion.num_heads=7", "fusion.dropout=-0.1", "fusion.dropout=1.0",
    "head.units=[0]", "head.hidden=-1", "head.layers=0", "head.log_std_init=5", "encoder.image.channels=[32,64,0]",
    "encoder.image.kernels=[8,4]", "encoder.image.bf16=maybe", "encoder.vector.hidden=[-5]", "task.control_hz=0",
    "task.physics_substeps=0", "task.episode_steps=0", "task.pos_action_scale=-0.01", "task.prop_gains=[1,2]",
    "task.taxel_rows=0", "task.camera_size=0", "task.camera_fovy=200", "task.tactile_kn=0", "task.peg_shape=hex",
    "task.peg_size=10", "task.clearance=-0.001", "task.randomization.scale=2",
    "task.randomization.ee_pos_low=[1,1,1]", "task.randomization.socket_obs_noise=-1",
    "task.randomization.pad_stiffness=[0,1]", "task.randomization.peg_in_hand_depth=[0,0.1]",
    "task.randomization.enabled=maybe", "task.tactile_residual=maybe", "task.use_shaped_keypoint_reward=maybe",
    "task.num_keypoints=0", "task.success_threshold=0", "task.density=0", "+task.peg_colour=red", "seed=-1",
    "seed=abc", "logger.wandb=maybe", "freeze_critic=maybe", "init_exclude=5", "obs.modalities=[wrist,nothing]",
    "+foo=1", "+algo.lr_decay=0.9", "+fusion.depth=2", "+obs.extra=1", "init_ckpt=/no/such.ckpt",
    "critic_ckpt=/no/such.ckpt",
]


@pytest.mark.parametrize("override", BAD_VALUES)
def test_a_bad_value_is_refused_by_its_key_before_anything_is_built(tmp_path, monkeypatch, override):
    monkeypatch.setattr("vitac.envs.vector_env.TaskVectorEnv", lambda *a, **k: pytest.fail("simulation started"))
    key = override.split("=")[0].lstrip("+")
    with pytest.raises((ValueError, FileNotFoundError)) as refused:
        train(compose_config(SMOKE[:1] + [override, "logger=csv"], output_dir=tmp_path))
    assert key in str(refused.value) and "Traceback" not in str(refused.value), str(refused.value)
