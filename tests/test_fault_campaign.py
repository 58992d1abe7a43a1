"""The fault-injection campaign: each fault of tests/test_faults.py injected many times at random points, with a
fast subset in the default run. docs/reliability.md records what it injects, how often, and what survives:
`python -m pytest -m slow -s tests/test_fault_campaign.py`, which records each tally in
docs/data/fault_campaign.json and rewrites the page's table from it (tests/campaign_table.py)."""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
from pathlib import Path

import numpy as np
import pytest
import torch

from tests import campaign_table
from tests.conftest import compose_config
from tests.test_faults import JOB, SMOKE, _training_job_after
from vitac.training import train
from vitac.utils.checkpoint import load_checkpoint

SIGKILLS, DAMAGES, WORKER_KILLS = 20, 50, 10


def _same(a, b) -> bool:
    """Whether two loaded checkpoints hold the same values, tensors and numpy arrays compared exactly."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and a.dtype == b.dtype and torch.equal(a, b)
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True)
    return type(a) is type(b) and (a == b or a != a and b != b)  # NaN scalars are the same NaN


def _damage(source, tmp_path, damages: int, seed: int) -> tuple[int, int]:
    """Truncate the checkpoint at `damages` random lengths and flip one random byte of it `damages` times; every
    truncation must be refused, every flip refused or read back exactly (a flip in a zip header's padding changes
    no value). Returns (refused flips, flips read back unchanged)."""
    rng, data = random.Random(seed), source.read_bytes()
    original, damaged = load_checkpoint(source), tmp_path / "damaged.ckpt"
    for _ in range(damages):
        damaged.write_bytes(data[: rng.randrange(len(data))])
        with pytest.raises(ValueError, match="is not a readable vitac checkpoint"):
            load_checkpoint(damaged)
    refused = unchanged = 0
    for _ in range(damages):
        flipped = bytearray(data)
        flipped[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        damaged.write_bytes(flipped)
        try:
            loaded = load_checkpoint(damaged)
        except ValueError as err:
            assert "not a readable vitac checkpoint" in str(err) or "not a vitac checkpoint" in str(err), str(err)
            refused += 1
        else:
            assert _same(loaded, original), "a damaged checkpoint was read as other values"
            unchanged += 1
    return refused, unchanged


def test_a_flipped_bit_in_a_shipped_policys_weights_is_refused_naming_the_record(tmp_path):
    data = bytearray(open("pretrained/privileged.pt", "rb").read())
    data[len(data) // 2] ^= 0x01  # inside the weights, which torch alone would load as other numbers
    (tmp_path / "flipped.pt").write_bytes(data)
    with pytest.raises(ValueError, match=r"not a readable vitac checkpoint: Bad CRC-32 for file '.*/data/"):
        load_checkpoint(tmp_path / "flipped.pt")


def test_a_truncated_or_bit_flipped_shipped_policy_is_refused_or_read_exactly(tmp_path):
    shipped = shutil.copy("pretrained/privileged.pt", tmp_path / "privileged.pt")
    refused, unchanged = _damage(Path(shipped), tmp_path, 8, seed=0)
    assert refused + unchanged == 8 and refused >= 6


@pytest.mark.slow
def test_campaign_damaged_training_checkpoints(tmp_path):
    """A training checkpoint (optimizer, environment and RNG states included), truncated and bit-flipped at
    random points: nothing is ever read as other values."""
    run = train(compose_config(SMOKE, output_dir=tmp_path / "run"))
    refused, unchanged = _damage(Path(run["checkpoint"]), tmp_path, DAMAGES, seed=1)
    print(f"\n{DAMAGES} truncations refused; {DAMAGES} bit flips: {refused} refused, {unchanged} read back unchanged")
    assert refused + unchanged == DAMAGES and refused >= DAMAGES * 3 // 4
    campaign_table.record("truncated_checkpoints", damages=DAMAGES, refused=DAMAGES)
    campaign_table.record("bit_flips", damages=DAMAGES, refused=refused, unchanged=unchanged)


@pytest.mark.slow
def test_campaign_sigkills_never_lose_a_checkpoint_or_a_logged_iteration(tmp_path):
    """SIGKILLS kills of one run, each followed by `resume=auto` in the same directory: every other kill at a random
    moment, the rest the instant a new last.ckpt lands (an iteration's end, before or while its metrics row is
    written). Every time last.ckpt loads whole and holds every iteration finished before the kill but the one in
    progress, and the run's metrics end with every iteration logged once."""
    import time

    from vitac.run_dirs import read_metrics

    rng, run, done = random.Random(), tmp_path / "run", 0
    last = run / "checkpoints" / "last.ckpt"
    for kill in range(SIGKILLS):
        proc = _training_job_after(done + 2, run, "resume=auto")
        if kill % 2:
            time.sleep(rng.uniform(0.0, 1.5))  # anywhere in the next iterations, mid-write included
        else:  # just after the next checkpoint replaces the last one
            saved_at = last.stat().st_mtime_ns
            while last.stat().st_mtime_ns == saved_at and proc.poll() is None:
                time.sleep(0.002)
            time.sleep(rng.uniform(0.0, 0.05))
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate(timeout=60)
        saved = load_checkpoint(last)  # whole, every time
        now = saved["vitac"]["env_steps"] // (16 * 4)
        assert now >= done + 2  # the progress bar had shown done + 2 iterations saved
        done = now
    train(compose_config(JOB + ["resume=auto", f"trainer.iterations={done + 1}"], output_dir=run))
    iterations = [int(float(r["iteration"])) for r in read_metrics(run) if r.get("iteration")]
    print(f"\n{SIGKILLS} SIGKILLs, resumed each time: iterations 1-{done + 1} all logged, none twice")
    assert sorted(iterations) == list(range(1, done + 2))
    campaign_table.record("sigkills", kills=SIGKILLS, iterations=done + 1)


@pytest.mark.slow
def test_campaign_killed_workers_are_replaced_every_time(tmp_path):
    """WORKER_KILLS workers killed at random steps: each is replaced, its environments' episodes end as
    truncations and every other episode goes on; one kill past `max_restarts` stops with the process named."""
    from vitac.envs.vector_env import RESTARTED, TaskVectorEnv

    rng = random.Random(2)
    venv = TaskVectorEnv({"observations": ["proprio", "peg_state"]}, num_envs=4, num_workers=2, seed=0,
                         max_restarts=WORKER_KILLS)
    try:
        venv.reset(seed=0)
        for kill in range(WORKER_KILLS + 1):
            for _ in range(rng.randrange(1, 6)):
                obs, *_ = venv.step(np.asarray([[rng.uniform(-1, 1) for _ in range(6)] for _ in range(4)]))
            victim = rng.randrange(2)
            os.kill(venv._procs[victim].pid, signal.SIGKILL)
            if kill == WORKER_KILLS:
                with pytest.raises(RuntimeError, match=rf"died \(exit code -9\) during 'step' after {WORKER_KILLS} "):
                    venv.step(np.zeros((4, 6)))
                break
            obs, _, _, truncated, info = venv.step(np.zeros((4, 6)))
            mine = [2 * victim, 2 * victim + 1]
            assert [info["env_infos"][i].get("outcome") for i in mine] == [RESTARTED, RESTARTED]
            assert list(truncated[mine]) == [True, True] and np.all(np.isfinite(obs["proprio"]))
            assert venv.restarts == kill + 1
    finally:
        venv.close()
    print(f"\n{WORKER_KILLS} worker kills replaced; kill {WORKER_KILLS + 1} stopped the run naming the process")
    campaign_table.record("worker_kills", kills=WORKER_KILLS)


def test_the_reliability_page_shows_the_recorded_campaign():
    recorded = campaign_table.render(json.loads(campaign_table.REPORT.read_text()))
    assert campaign_table.table_on_page(campaign_table.PAGE.read_text()) == recorded, \
        "docs/reliability.md's campaign table is not the recorded one: run python -m tests.campaign_table"
