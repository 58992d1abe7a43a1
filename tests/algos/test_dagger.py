"""DAgger checklist (STYLE.md): labels belong to the states they label, the teacher's recurrent state follows the
trajectory and resets at episode starts, the teacher's normalization is its own, beta = 1 replays the teacher,
and the symmetry loss reaches the tactile encoders only with reg=sym."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.algos.test_recurrent_ppo import FakeVectorEnv
from tests.conftest import compose_config
from vitac.algos.buffer import RolloutBuffer, SequenceStore
from vitac.algos.dagger import DAgger
from vitac.envs.vector_env import TaskVectorEnv
from vitac.run_config import build_policy_from_config, task_settings
from vitac.tasks.insertion.config import InsertionConfig


def _policy(overrides, seed=0):
    torch.manual_seed(seed)
    cfg = compose_config(overrides)
    return build_policy_from_config(cfg, InsertionConfig.from_dict(task_settings(cfg)))


class _SpaceFake(FakeVectorEnv):
    @property
    def single_observation_space(self):
        import gymnasium as gym

        return gym.spaces.Dict({k: gym.spaces.Box(-np.inf, np.inf, v.shape[1:]) for k, v in self._obs().items()})


class _FunctionTeacher(torch.nn.Module):
    """A teacher whose action is a known function of the observation it is given: tanh(proprio[:6] + step
    count since its episode started), so a label taken from the wrong step, or a state not reset, shows."""

    input_keys = ["proprio"]

    def step_inputs(self, obs, starts):
        return {k: torch.as_tensor(v)[None] for k, v in obs.items()}, starts[None]

    def initial_state(self, batch, device=None):
        return (torch.zeros(1, batch, 1), torch.zeros(1, batch, 1))

    def forward(self, obs, state, starts):
        count = state[0] * (1 - starts)[None, ..., None] + 1  # steps since the episode started, this one included
        mean = torch.tanh(obs["proprio"][..., :6] + count[0])
        return mean, torch.zeros_like(mean), torch.zeros(mean.shape[:-1]), (count, count)


def _collect(module):
    module.on_train_start()
    module.policy.eval()
    module.collect_rollout()
    return module.buffer


def test_labels_are_the_teachers_function_of_the_state_they_label_across_episode_boundaries():
    envs = _SpaceFake(num_envs=4)
    module = DAgger(_policy(["experiment=table1/privileged"]), envs, _FunctionTeacher(), horizon=16, seq_len=8,
                    minibatch_size=16, beta_start=0.0, beta_end=0.0)
    buf = _collect(module)
    count = torch.zeros(4)
    for t in range(16):
        count = count * (1 - buf.starts[t]) + 1
        expected = torch.tanh(buf.obs["proprio"][t, :, :6] + count[:, None])
        torch.testing.assert_close(buf.labels[t], expected, rtol=0, atol=0)
    assert buf.starts[1:].sum() > 0  # episodes did restart inside the rollout


def test_the_teachers_labels_are_its_replay_along_the_trajectory_with_its_own_frozen_normalizers():
    teacher = _policy(["experiment=table1/privileged"], seed=1)
    envs = _SpaceFake(num_envs=4)
    teacher.update_normalizers({k: 3 + 2 * torch.randn(64, *v.shape[1:]) for k, v in envs._obs().items()})
    frozen = {k: v.clone() for k, v in teacher.state_dict().items() if "normalizer" in k}
    module = DAgger(_policy(["experiment=table1/privileged"]), envs, teacher, horizon=16, seq_len=8,
                    minibatch_size=16, beta_start=0.0, beta_end=0.0)
    buf = _collect(module)
    module.policy.update_normalizers({k: v.reshape(-1, *v.shape[2:]) for k, v in buf.obs.items()})  # the student's
    replay, _, _, _ = teacher({k: buf.obs[k] for k in ("proprio", "peg_state", "critic_state")},
                              teacher.initial_state(4), buf.starts)
    torch.testing.assert_close(buf.labels, replay.clamp(-1, 1), rtol=1e-5, atol=1e-6)  # within the action bounds
    assert all(torch.equal(v, teacher.state_dict()[k]) for k, v in frozen.items())


def test_with_the_teachers_action_always_executed_the_rollout_is_the_teachers_own():
    settings = dict(InsertionConfig.from_dict({"observations": ["proprio", "peg_state", "critic_state"],
                                               "episode_steps": 12}).to_dict())
    teacher = _policy(["experiment=table1/privileged"], seed=1)

    teacher.eval()
    envs = TaskVectorEnv(settings, num_envs=2, num_workers=0, seed=3)
    obs, _ = envs.reset(seed=None)
    state, starts, plain = teacher.initial_state(2), torch.ones(2), []
    with torch.no_grad():
        for _ in range(20):  # across one episode end (12 steps)
            inputs, s = teacher.step_inputs(obs, starts)
            mean, _, _, state = teacher(inputs, state, s)
            obs, reward, terminated, truncated, _ = envs.step(mean[0].clamp(-1, 1).numpy())
            starts = torch.as_tensor(terminated | truncated, dtype=torch.float32)
            plain.append((obs["proprio"].copy(), reward.copy()))
    envs.close()
    envs = TaskVectorEnv(settings, num_envs=2, num_workers=0, seed=3)
    module = DAgger(_policy(["experiment=table1/privileged"]), envs, teacher, horizon=20, seq_len=10,
                    minibatch_size=20, beta_start=1.0, beta_end=1.0)
    buf = _collect(module)
    envs.close()
    torch.testing.assert_close(buf.actions, buf.labels, rtol=0, atol=0)
    for t in range(19):  # the next step's stored observation is what the teacher's own step returned
        np.testing.assert_array_equal(buf.obs["proprio"][t + 1].numpy(), plain[t][0])
        np.testing.assert_array_equal(buf.rewards[t].numpy(), plain[t][1])


@pytest.mark.parametrize("reg", ["sym", "none"])
def test_the_symmetry_loss_reaches_the_tactile_encoders_only_with_reg_sym(reg):
    student = _policy(["obs=wrist_tactile", "fusion=cmt", f"reg={reg}", "critic=none"])
    module = DAgger(student, _SpaceFake(num_envs=2), _FunctionTeacher(), horizon=8, seq_len=4, minibatch_size=8)
    T, B = 4, 2
    shapes = InsertionConfig().observation_shapes()
    obs = {k: torch.rand(T, B, *shapes[k]) for k in ("proprio", "tactile_left", "tactile_right")}
    obs["wrist"] = (255 * torch.rand(T, B, *shapes["wrist"])).to(torch.uint8)
    mb = dict(obs=obs, state=student.initial_state(B), starts=torch.zeros(T, B), labels=torch.zeros(T, B, 6))
    terms = module.minibatch_losses(mb)
    if reg == "sym":
        (terms["loss"] - terms["distill_loss"]).backward()  # the symmetry term alone
        assert terms["sym_loss"] > 0
        for side in ("tactile_left", "tactile_right"):
            assert student.encoders[side].conv[0].weight.grad.abs().sum() > 0
    else:
        assert terms["sym_loss"] == 0 and not terms["sym_loss"].requires_grad
        assert torch.equal(terms["loss"], terms["distill_loss"])


def _symmetry_update(lambda_sym: float | None, weighting: str = "absolute") -> tuple[dict, dict]:
    """One DAgger minibatch's terms and the gradients of its whole loss, from the same weights and data; None: reg=none."""
    reg = ["reg=none"] if lambda_sym is None else ["reg=sym", f"reg.lambda_sym={lambda_sym}", f"reg.weighting={weighting}"]
    student = _policy(["obs=wrist_tactile", "fusion=cmt", "critic=none"] + reg)
    module = DAgger(student, _SpaceFake(num_envs=2), _FunctionTeacher(), horizon=8, seq_len=4, minibatch_size=8)
    generator = torch.Generator().manual_seed(1)
    shapes = InsertionConfig().observation_shapes()
    obs = {k: torch.rand(4, 2, *shapes[k], generator=generator) for k in ("proprio", "tactile_left", "tactile_right")}
    obs["wrist"] = (255 * torch.rand(4, 2, *shapes["wrist"], generator=generator)).to(torch.uint8)
    mb = dict(obs=obs, state=student.initial_state(2), starts=torch.zeros(4, 2), labels=torch.rand(4, 2, 6) - 0.5)
    terms = module.minibatch_losses(mb)
    terms["loss"].backward()
    return terms, {name: p.grad.clone() for name, p in student.named_parameters() if p.grad is not None}


def test_a_zero_symmetry_weight_updates_bit_for_bit_as_no_regularizer_and_the_weight_scales_its_gradient():
    none_terms, none_grads = _symmetry_update(None)
    zero_terms, zero_grads = _symmetry_update(0.0)
    assert torch.equal(zero_terms["loss"], none_terms["loss"]) and zero_grads.keys() == none_grads.keys()
    assert all(torch.equal(zero_grads[k], none_grads[k]) for k in none_grads)
    # The term's gradient alone (the whole gradient less the imitation's) doubles with the weight.
    half, one = ({k: g - none_grads.get(k, 0) for k, g in _symmetry_update(w)[1].items()} for w in (0.5, 1.0))
    moved = [k for k in one if one[k].abs().sum() > 0]
    assert any(k.startswith("encoders.tactile_left") for k in moved)
    for k in moved:
        torch.testing.assert_close(one[k], 2 * half[k], rtol=1e-4, atol=1e-7)


def test_a_relative_symmetry_weight_makes_the_term_that_share_of_the_imitation_loss():
    none_terms, none_grads = _symmetry_update(None)
    terms, _ = _symmetry_update(0.1, "relative")
    assert torch.equal(terms["distill_loss"], none_terms["distill_loss"]) and terms["sym_loss"] > 0
    torch.testing.assert_close(terms["loss"], 1.1 * terms["distill_loss"])  # the term is a tenth of the distance
    _, zero_grads = _symmetry_update(0.0, "relative")  # weight 0 is no prior, however it is read
    assert all(torch.equal(zero_grads[k], none_grads[k]) for k in none_grads)


def test_the_relative_term_has_the_symmetry_losss_gradient_rescaled_and_none_through_the_main_loss():
    from vitac.models.symmetry import SymmetryRegularizer

    x, y = torch.tensor([1.0, -2.0], requires_grad=True), torch.tensor(3.0, requires_grad=True)
    sym, main = (x ** 2).mean(), -2 * y  # L_sym = 2.5, |main| = 6
    term = SymmetryRegularizer(0.5, weighting="relative").term(sym, main)
    term.backward()
    assert term.item() == pytest.approx(3.0)  # 0.5 * |main|
    torch.testing.assert_close(x.grad, 0.5 * 6 / 2.5 * x.detach())  # d/dx of L_sym = x, scaled by 0.5 |main| / L_sym
    assert y.grad is None  # the main loss's size is read, not trained


def test_bad_dagger_values_are_refused_naming_the_key():
    envs = _SpaceFake(num_envs=2)
    for kwargs, pattern in ((dict(loss="l1"), r"algo\.loss='l1' is not allowed"),
                            (dict(beta_start=1.5), r"algo\.beta_start=1\.5 is not allowed"),
                            (dict(student_actions="noisy"), r"algo\.student_actions='noisy'"),
                            (dict(lr_schedule="cosine"), r"algo\.lr_schedule='cosine' is not allowed"),
                            (dict(dataset_rollouts=0), r"algo\.dataset_rollouts=0 is not allowed")):
        with pytest.raises(ValueError, match=pattern):
            DAgger(_policy(["experiment=table1/privileged"]), envs, _FunctionTeacher(), horizon=8, seq_len=4,
                   minibatch_size=8, **kwargs)


def test_a_linear_learning_rate_falls_from_lr_towards_0_at_the_last_iteration(tmp_path):
    from tests.conftest import compose_config as compose
    from vitac.run_dirs import read_metrics
    from vitac.training import train

    def rates(run_dir):
        return [float(r["charts/lr"]) for r in read_metrics(run_dir) if r.get("charts/lr")]

    job = ["preset=smoke", "experiment=table1/tactile", "algo=dagger", "algo.lr=4e-4", "algo.lr_schedule=linear",
           "trainer.iterations=4", "logger=csv"]
    train(compose(job, output_dir=tmp_path / "run"))
    assert rates(tmp_path / "run") == pytest.approx([4e-4, 3e-4, 2e-4, 1e-4])
    # Continued to 6 iterations (`resume=`): the rate is a function of the iteration and the run's length, so
    # the continuation follows the longer run's line.
    train(compose(job[:-2] + ["trainer.iterations=6", "logger=csv", f"resume={tmp_path / 'run'}"],
                  output_dir=tmp_path / "more"))
    assert rates(tmp_path / "more")[-2:] == pytest.approx([4e-4 / 3, 2e-4 / 3])


@pytest.mark.slow
def test_a_student_with_the_teachers_observations_learns_to_insert(tmp_path):
    """The end-to-end check distillation once failed (one gradient step an iteration never fitted the labels):
    recipe/privileged_dagger fits the teacher's actions and inserts on its own after the hand-over."""
    import csv

    from vitac.training import train

    run = train(compose_config(["experiment=recipe/privileged_dagger", "logger=csv"], output_dir=tmp_path / "run"))
    rows = [r for r in csv.DictReader(open(run["metrics_csv"])) if r.get("losses/action_mse")]
    last = rows[-12:]  # three episodes' worth of iterations, all with the student alone acting
    assert all(float(r["charts/beta"]) == 0.0 for r in last)
    assert np.mean([float(r["losses/action_mse"]) for r in last]) < 0.05
    success = [float(r["charts/success_rate"]) for r in last if r["charts/success_rate"] != "nan"]
    assert np.mean(success) >= 0.6, success


def _rollout_buffer(horizon, num_envs, seq_len, tag):
    """A filled RolloutBuffer whose every value names its rollout, step and env: obs proprio[..., 0] = tag,
    [..., 1] = t, [..., 2] = env; labels and chunk states are functions of the same."""
    buf = RolloutBuffer(horizon, num_envs, seq_len)
    buf.allocate({"proprio": torch.zeros(1, 3), "wrist": torch.zeros(1, 2, 2, dtype=torch.uint8)}, 6)
    t, env = torch.meshgrid(torch.arange(horizon), torch.arange(num_envs), indexing="ij")
    buf.obs["proprio"] = torch.stack([torch.full_like(t, tag), t, env], -1).float()
    buf.obs["wrist"] = (t * 7 + env + tag)[..., None, None].expand(-1, -1, 2, 2).to(torch.uint8)
    buf.starts = ((t + env) % 5 == 0).float()
    buf.labels = (100 * tag + 10 * t + env)[..., None].float().expand(-1, -1, 6).clone()
    buf.chunk_states = [tuple(torch.full((2, num_envs, 4), 0.0) + 1000 * tag + c * seq_len + 0.5 * k
                              + torch.arange(num_envs)[None, :, None] for k in (0, 1)) for c in range(horizon // seq_len)]
    return buf


def test_one_rollout_kept_gives_the_rollout_buffers_own_minibatches():
    buf = _rollout_buffer(8, 3, 4, tag=0)
    store = SequenceStore(1)
    store.add(buf)
    g_buffer, g_store = torch.Generator().manual_seed(5), torch.Generator().manual_seed(5)
    for _ in range(2):  # two passes, as mini_epochs=2 draws them
        plain = list(buf.minibatches(8, g_buffer, fields=("labels",)))
        kept = list(store.minibatches(8, g_store, count=24))
        assert len(plain) == len(kept) == 3
        for a, b in zip(plain, kept, strict=True):
            pairs = [(a["obs"][k], b["obs"][k]) for k in a["obs"]] + list(zip(a["state"], b["state"], strict=True))
            for x, y in pairs + [(a["starts"], b["starts"]), (a["labels"], b["labels"])]:
                assert torch.equal(x, y)


def test_the_dataset_keeps_the_last_rollouts_and_every_sequence_stays_whole():
    store = SequenceStore(2)
    for tag in range(3):  # the first rollout is dropped when the third comes
        store.add(_rollout_buffer(8, 3, 4, tag=tag))
    drawn = list(store.minibatches(8, torch.Generator().manual_seed(0), count=24))
    assert [mb["labels"].shape[:2] for mb in drawn] == [(4, 2)] * 3  # one rollout's worth: 6 chunks of 4 steps
    tags = set()
    for mb in drawn:
        tag, t, env = mb["obs"]["proprio"].unbind(-1)  # (L, B) each
        tags |= set(tag.flatten().tolist())
        assert torch.equal(t, t[:1] + torch.arange(4.0)[:, None]) and (t[0] % 4 == 0).all()  # consecutive chunks
        assert (tag == tag[:1]).all() and (env == env[:1]).all()
        assert torch.equal(mb["labels"][..., 0], 100 * tag + 10 * t + env)
        assert torch.equal(mb["obs"]["wrist"][..., 0, 0], (t * 7 + env + tag).to(torch.uint8))
        assert torch.equal(mb["starts"], ((t + env) % 5 == 0).float())
        h, c = mb["state"]  # (layers, B, H): the state stored at each chunk's first step
        assert torch.equal(h[0, :, 0], 1000 * tag[0] + t[0] + env[0]) and torch.equal(c - h, torch.full_like(h, 0.5))
    assert tags == {1.0, 2.0}  # drawn from both rollouts kept, never from the dropped one


def test_an_aggregated_dataset_resumes_exactly(tmp_path):
    """The kept rollouts travel in checkpoints: a run killed after iteration 2 and resumed trains iteration 3 on
    the same two rollouts as the uninterrupted run."""
    from vitac.run_dirs import read_metrics
    from vitac.training import train

    def losses(run_dir):
        return {r["epoch"]: (float(r["losses/distill_loss"]), r["charts/reward_per_step"])
                for r in read_metrics(run_dir) if r.get("losses/distill_loss")}

    job = ["preset=smoke", "experiment=table1/tactile", "algo=dagger", "algo.dataset_rollouts=2", "logger=csv"]
    train(compose_config(job + ["trainer.iterations=3"], output_dir=tmp_path / "full"))
    train(compose_config(job + ["trainer.iterations=2"], output_dir=tmp_path / "part"))
    train(compose_config(job + ["trainer.iterations=3", f"resume={tmp_path / 'part'}"], output_dir=tmp_path / "more"))
    full, more = losses(tmp_path / "full"), losses(tmp_path / "more")
    assert list(more) == ["2"] and more["2"][1] == full["2"][1]  # the same rollout
    assert more["2"][0] == pytest.approx(full["2"][0], rel=1e-4)  # and the same data: CPU kernels to ~1e-6
    # Another teacher than the one the run learned from (a changed default between sittings) would mix two teachers'
    # labels: refused, naming the recorded one.
    teacher = compose_config(job).teacher_ckpt
    other = "pretrained/privileged" if teacher != "pretrained/privileged" else "pretrained/privileged_contact"
    with pytest.raises(ValueError, match=rf"teacher_ckpt='{other}' is not allowed with resume=.*learned from another "
                                         rf"teacher \('{teacher}'.*resume with teacher_ckpt={teacher}"):
        train(compose_config(job + ["trainer.iterations=3", f"teacher_ckpt={other}", f"resume={tmp_path / 'part'}"],
                             output_dir=tmp_path / "other"))
    # Only last.ckpt carries them: periodic checkpoints are for evaluation and stay small.
    from vitac.utils.checkpoint import load_checkpoint

    checkpoints = tmp_path / "full" / "checkpoints"
    assert load_checkpoint(checkpoints / "last.ckpt")["vitac"]["dataset"]["filled"] == 2
    assert "dataset" not in load_checkpoint(checkpoints / "iter_00003.ckpt")["vitac"]


def test_the_progress_bar_never_shows_the_teachers_success_under_the_students_name():
    from types import SimpleNamespace

    from vitac.algos.callbacks import IterationProgressBar

    bar = IterationProgressBar()
    trainer = SimpleNamespace(max_epochs=3, current_epoch=0, callback_metrics={})
    module = SimpleNamespace(env_steps=1024)
    bar.on_train_start(trainer, module)
    trainer.callback_metrics = {"charts/SPS": 40.0, "charts/success_rate": 0.88, "charts/beta": 0.9}
    bar.on_train_epoch_end(trainer, module)
    assert "teacher_acts=90%" in str(bar.bar) and "success_with_teacher=0.88" in str(bar.bar)
    assert "success=" not in str(bar.bar).replace("success_with_teacher=", "")
    trainer.callback_metrics = {"charts/SPS": 40.0, "charts/success_rate": 0.5, "charts/beta": 0.0,
                                "eval/success_rate": 0.25}
    bar.on_train_epoch_end(trainer, module)
    assert "success=0.50" in str(bar.bar) and "eval=0.25" in str(bar.bar) and "teacher" not in str(bar.bar)
    bar.on_train_end(trainer, module)
