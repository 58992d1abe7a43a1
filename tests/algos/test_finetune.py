"""Fine-tuning a distilled student by PPO (finetune=kickstart): the actor frozen through the critic's warm-up, the
imitation term's weight on its schedule and 0 after, an exact resume mid-schedule, and a critic that reads the
student's recurrent features starting as the teacher's critic and moving no actor weight."""

from __future__ import annotations

import pytest
import torch

from tests.conftest import compose_config
from vitac.run_dirs import read_metrics
from vitac.utils.checkpoint import load_checkpoint

STUDENT = ["preset=smoke", "experiment=table1/tactile", "logger=csv"]
FINETUNE = STUDENT + ["finetune=kickstart", "envs.num_envs=2", "envs.num_workers=0", "algo.horizon=16", "algo.seq_len=8",
                      "algo.minibatch_size=16", "algo.lr=1e-3", "algo.critic_warmup_iterations=2",
                      "algo.imitation_coef=2.0", "algo.imitation_iterations=2", "eval.every=10",
                      "checkpoint.every_n_epochs=1"]


@pytest.fixture(scope="module")
def student(tmp_path_factory):
    from vitac.training import train

    out = tmp_path_factory.mktemp("student")
    train(compose_config(STUDENT + ["algo=dagger", "trainer.iterations=1"], output_dir=out))
    return out / "checkpoints" / "last.ckpt"


@pytest.fixture(scope="module")
def finetuned(student, tmp_path_factory):
    """Five iterations: two of warm-up, two of the imitation term's anneal, one of PPO alone."""
    from vitac.training import train

    out = tmp_path_factory.mktemp("finetuned")
    train(compose_config(FINETUNE + [f"init_ckpt={student}", "trainer.iterations=5"], output_dir=out))
    return out


def _weights(path, prefix):
    return {k: v for k, v in load_checkpoint(path)["state_dict"].items() if k.startswith(prefix)}


def test_kickstart_freezes_the_actor_through_the_warm_up_then_anneals_the_imitation_term(student, finetuned):
    rows = [r for r in read_metrics(finetuned) if r.get("charts/imitation_weight")]
    assert [float(r["charts/actor_frozen"]) for r in rows] == [1, 1, 0, 0, 0]
    assert [float(r["charts/imitation_weight"]) for r in rows] == [0, 0, 2.0, 1.0, 0]
    assert all(float(r["charts/lr"]) == pytest.approx(1e-3) for r in rows)  # the schedule waits out the warm-up
    checkpoints = finetuned / "checkpoints"
    before, warmed = (_weights(p, "policy.") for p in (student, checkpoints / "iter_00002.ckpt"))
    actor = [k for k in warmed if not k.startswith(("policy.critic", "policy.head.log_std", "policy.head.value"))]
    assert len(actor) > 10 and all(torch.equal(warmed[k], before[k]) for k in actor)  # weights and normalizers
    teacher = _weights("pretrained/privileged.pt", "policy.critic.")
    assert not torch.equal(warmed["policy.critic.value.weight"], teacher["policy.critic.value.weight"])  # it learned
    after = _weights(checkpoints / "iter_00003.ckpt", "policy.")
    assert not torch.equal(after["policy.head.mean.weight"], before["policy.head.mean.weight"])


def test_kickstart_resumes_mid_schedule_exactly(student, finetuned, tmp_path):
    from vitac.training import train

    def losses(run_dir):
        return {r["epoch"]: (float(r["losses/loss"]), float(r["losses/imitation_loss"]), r["charts/reward_per_step"],
                             r["charts/imitation_weight"]) for r in read_metrics(run_dir) if r.get("losses/loss")}

    job = FINETUNE + [f"init_ckpt={student}"]
    train(compose_config(job + ["trainer.iterations=3"], output_dir=tmp_path / "part"))  # stopped in the anneal
    train(compose_config(job + ["trainer.iterations=5", f"resume={tmp_path / 'part'}"], output_dir=tmp_path / "more"))
    full, more = losses(finetuned), losses(tmp_path / "more")
    assert list(more) == ["3", "4"]
    for epoch in more:  # the same rollouts (the teacher's state included) and the same weights on the schedule
        assert more[epoch][2:] == full[epoch][2:]
        assert more[epoch][:2] == pytest.approx(full[epoch][:2], rel=1e-4)


def test_a_critic_reading_the_actors_memory_starts_as_the_teachers_and_moves_no_actor_weight():
    from vitac.algos.weights import load_critic
    from vitac.models.normalizer import RunningNormalizer
    from vitac.run_config import build_policy_from_config, load_policy, task_settings
    from vitac.tasks.insertion.config import InsertionConfig

    teacher, _, _ = load_policy("pretrained/privileged")
    cfg = compose_config(["experiment=table1/privileged", "critic=state_memory"])
    torch.manual_seed(0)
    holder = torch.nn.Module()  # what load_critic reads of a training module
    holder.policy = build_policy_from_config(cfg, InsertionConfig.from_dict(task_settings(cfg)))
    holder.value_normalizer = RunningNormalizer((), clip=float("inf"))
    load_critic(holder, "pretrained/privileged")
    policy = holder.policy
    assert policy.critic.mlp[0].weight.shape[1] == teacher.critic.mlp[0].weight.shape[1] + policy.head.hidden
    torch.manual_seed(1)
    T, B = 5, 3
    obs = {k: torch.randn(T, B, *teacher_shape) for k, teacher_shape in
           (("proprio", (19,)), ("peg_state", (10,)), ("critic_state", (42,)))}
    starts = torch.zeros(T, B)
    state = policy.initial_state(B)
    _, _, value, _ = policy(obs, state, starts)
    _, _, expected, _ = teacher(obs, teacher.initial_state(B), starts)
    torch.testing.assert_close(value, expected)  # the memory enters with zero weights
    value.sum().backward()
    assert policy.critic.mlp[0].weight.grad[:, -policy.head.hidden:].abs().sum() > 0  # it can learn to use it
    actor = [p for name, p in policy.named_parameters() if not name.startswith("critic")]
    assert all(p.grad is None for p in actor)  # and the critic's loss never reaches the actor


@pytest.mark.parametrize("same_actor", [False, True])
def test_a_critic_that_read_another_actors_memory_starts_from_its_state_columns_only(same_actor):
    """The 97% teacher's critic read its own LSTM's features; a student's critic starts from it with zero weights on
    the student's (equally wide, differently meaning) features, unless the actor is the checkpoint's own."""
    from vitac.algos.weights import CRITIC_INPUT, load_critic
    from vitac.models.normalizer import RunningNormalizer
    from vitac.run_config import build_policy_from_config, task_settings
    from vitac.tasks.insertion.config import InsertionConfig

    cfg = compose_config(["experiment=table1/privileged_contact", "critic=state_memory"])
    holder = torch.nn.Module()
    holder.policy = build_policy_from_config(cfg, InsertionConfig.from_dict(task_settings(cfg)))
    holder.value_normalizer = RunningNormalizer((), clip=float("inf"))
    load_critic(holder, "pretrained/privileged_contact_residual", same_actor=same_actor)
    saved = _weights("pretrained/privileged_contact_residual.pt", CRITIC_INPUT)[CRITIC_INPUT]
    loaded, state = holder.policy.critic.mlp[0].weight, holder.policy.critic.state_dim
    assert loaded.shape == saved.shape and saved[:, state:].abs().sum() > 0
    torch.testing.assert_close(loaded[:, :state], saved[:, :state])
    assert torch.equal(loaded[:, state:], saved[:, state:]) if same_actor else not loaded[:, state:].any()


def test_a_residual_policy_starts_as_its_student_bit_for_bit_and_trains_only_its_head_and_critic(student, tmp_path):
    from vitac.run_config import load_policy
    from vitac.training import train

    job = FINETUNE[:3] + ["finetune=residual", "envs.num_envs=2", "envs.num_workers=0", "algo.horizon=16",
                          "algo.seq_len=8", "algo.minibatch_size=16", "algo.lr=1e-3", "algo.critic_warmup_iterations=1",
                          "eval.every=10", "checkpoint.every_n_epochs=1", f"init_ckpt={student}"]
    train(compose_config(job + ["trainer.iterations=1"], output_dir=tmp_path / "start"))
    distilled, _, _ = load_policy(student)
    residual, _, _ = load_policy(tmp_path / "start" / "checkpoints" / "last.ckpt")  # after the critic's warm-up
    assert residual.residual is not None and torch.equal(residual.residual.delta.weight, torch.zeros_like(
        residual.residual.delta.weight))
    torch.manual_seed(0)
    T, B = 6, 2
    obs = {"proprio": torch.randn(T, B, 19), "tactile_left": torch.randn(T, B, 3, 32, 32),
           "tactile_right": torch.randn(T, B, 3, 32, 32), "critic_state": torch.randn(T, B, 42)}
    starts = torch.zeros(T, B)
    starts[3, 1] = 1.0
    with torch.no_grad():
        ours = residual(obs, residual.initial_state(B), starts)[0]
        theirs = distilled(obs, distilled.initial_state(B), starts)[0]
    assert torch.equal(ours, theirs)  # the student's actions, bit for bit
    train(compose_config(job + ["trainer.iterations=3", f"resume={tmp_path / 'start'}"], output_dir=tmp_path / "more"))
    after, _, _ = load_policy(tmp_path / "more" / "checkpoints" / "last.ckpt")
    moved = {k for k, v in after.state_dict().items() if not torch.equal(v, residual.state_dict()[k])}
    assert any(k.startswith("residual.") for k in moved)
    assert all(k.startswith(("residual.", "critic")) for k in moved), sorted(moved)  # the student never moves
