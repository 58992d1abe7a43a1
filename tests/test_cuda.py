"""The policy and the PPO update on a CUDA device, the environments on the CPU (skipped without CUDA)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import torch
from lightning.pytorch.utilities import move_data_to_device

from tests.algos.test_recurrent_ppo import FakeVectorEnv, _policy
from tests.conftest import compose_config
from tests.test_train import ROOT, SMOKE, _rows
from vitac.algos.ppo import PPO
from vitac.evaluate import evaluate
from vitac.run_config import load_policy
from vitac.tasks.insertion.config import InsertionConfig
from vitac.training import train
from vitac.viz import policy_actor

pytestmark = [pytest.mark.gpu, pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")]


def _module_on(device: str) -> PPO:
    torch.manual_seed(0)
    module = PPO(_policy(), FakeVectorEnv(4), horizon=16, seq_len=8, minibatch_size=16, mini_epochs=1).to(device)
    # CPU statistics into the module's normalizers, wherever they live.
    module.policy.update_normalizers({k: torch.randn(64, *v.shape[1:]) for k, v in module.envs._obs().items()})
    module.on_train_start()
    module.policy.eval()
    return module


def test_rollout_and_minibatch_losses_on_cuda_agree_with_cpu():
    cpu, cuda = _module_on("cpu"), _module_on("cuda")
    assert next(cuda.policy.parameters()).is_cuda and cuda._state[0].is_cuda
    for module in (cpu, cuda):
        module.collect_rollout()
    a, b = cpu.buffer, cuda.buffer
    assert b.actions.device.type == "cpu"  # the buffer, GAE and the action noise stay on the CPU
    for name in ("actions", "log_probs", "values", "next_values", "advantages", "returns"):
        assert torch.allclose(getattr(a, name), getattr(b, name), atol=1e-3, rtol=1e-3), name
    assert torch.allclose(a.chunk_states[1][0], b.chunk_states[1][0], atol=1e-4)
    mb = next(a.minibatches(16, torch.Generator().manual_seed(0)))
    cpu.policy.train(), cuda.policy.train()
    on_cpu, on_cuda = cpu.minibatch_losses(mb), cuda.minibatch_losses(move_data_to_device(mb, cuda.device))
    for k in ("loss", "policy_loss", "value_loss", "entropy", "bounds_loss"):
        assert float(on_cuda[k].detach()) == pytest.approx(float(on_cpu[k].detach()), rel=1e-3, abs=1e-5), k
    on_cuda["loss"].backward()
    assert all(p.grad is None or torch.isfinite(p.grad).all() for p in cuda.policy.parameters())


def test_cuda_run_trains_evaluates_and_resumes_on_a_machine_without_cuda(tmp_path):
    gpu = SMOKE + ["trainer.accelerator=gpu", "eval.video_every=0", "logger=csv"]
    run = train(compose_config(gpu, output_dir=tmp_path / "gpu"))
    rows = [r for r in _rows(run["metrics_csv"]) if r.get("losses/loss")]
    assert len(rows) == 2 and all(np.isfinite(float(r["losses/loss"])) for r in rows)
    assert any(r.get("eval/success_rate") for r in _rows(run["metrics_csv"]))  # evaluation ran on the GPU policy
    # The checkpoint resumes where torch sees no GPU (tensors are read onto the CPU).
    env = dict(os.environ, CUDA_VISIBLE_DEVICES="", PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    resumed = subprocess.run([sys.executable, "-m", "vitac.train", *SMOKE, "trainer.iterations=3", "eval.video_every=0",
                              "logger=csv", f"resume={tmp_path / 'gpu'}", f"hydra.run.dir={tmp_path / 'cpu'}"],
                             cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert [r["epoch"] for r in _rows(tmp_path / "cpu" / "csv" / "metrics.csv") if r.get("losses/loss")] == ["2"]
    report = evaluate(run["checkpoint"], episodes=2, num_envs=2, num_workers=0, seed=5, out=str(tmp_path / "e.json"))
    assert report["episodes"] == 2
    # Videos record with a GPU policy too: the deterministic actor returns the CPU policy's action.
    policy, _, _ = load_policy(run["checkpoint"])
    shapes, rng = InsertionConfig().observation_shapes(), np.random.default_rng(0)
    obs = {k: rng.integers(0, 255, shapes[k], dtype=np.uint8) if k == "wrist" else rng.random(shapes[k], dtype=np.float32)
           for k in policy.image_keys + policy.vector_keys + ["critic_state"]}
    expected = policy_actor(policy)(obs)
    assert np.allclose(policy_actor(policy.cuda())(obs), expected, atol=5e-2)  # bfloat16 convolutions round differently
