"""A training or evaluation run's values checked before anything is built: bad values, keys the run would
ignore, missing or corrupt checkpoints, resumes that cannot continue exactly, the automatic worker split."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch

from tests.conftest import compose_config
from vitac.evaluate import evaluate
from vitac.run_config import load_policy
from vitac.training import train
from vitac.utils.checks import resolve_groups, resolve_threads

SMOKE = ["preset=smoke", "obs=wrist_tactile", "fusion=cmt", "reg=sym"]


def test_resume_without_checkpoint_fails_clearly(tmp_path):
    with pytest.raises(FileNotFoundError, match="resume="):
        train(compose_config(SMOKE + [f"resume={tmp_path / 'nothing'}"], output_dir=tmp_path / "x"))


@pytest.mark.parametrize("value,pattern", [("tpu", r"trainer.accelerator='tpu' is not allowed: expected one of "
                                                    r"\['cpu', 'gpu', 'auto'\]"),
                                           ("gpu", r"trainer.accelerator='gpu' is not allowed here: torch sees no CUDA")])
def test_bad_accelerator_is_refused_before_simulation(tmp_path, monkeypatch, value, pattern):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr("vitac.envs.vector_env.TaskVectorEnv", lambda *a, **k: pytest.fail("simulation started"))
    with pytest.raises(ValueError, match=pattern):
        train(compose_config(SMOKE + [f"trainer.accelerator={value}"], output_dir=tmp_path / "x"))


@pytest.mark.parametrize("override,pattern", [
    ("algo.gamma=1.5", r"algo\.gamma=1\.5 is not allowed: expected a number in \[0, 1\]"),
    ("algo.gae_lambda=-0.1", r"algo\.gae_lambda=-0\.1 is not allowed: expected a number in \[0, 1\]"),
    ("algo.mini_epochs=0", r"algo\.mini_epochs=0 is not allowed: expected a positive integer"),
    ("algo.mini_epochs=2.5", r"algo\.mini_epochs=2\.5 is not allowed: expected a positive integer"),
    ("algo.clip=0", r"algo\.clip=0 is not allowed: expected a number > 0"),
    ("algo.lr=-1", r"algo\.lr=-1 is not allowed: expected a number > 0"),
    ("algo.critic_coef=-2", r"algo\.critic_coef=-2 is not allowed: expected a number >= 0"),
    ("trainer.iterations=0", r"trainer\.iterations=0 is not allowed: expected a positive integer"),
    ("envs.num_workers=3", r"envs\.num_workers=3 is not allowed: expected 0 or a divisor of envs\.num_envs=2"),
    ("algo.normalize_input=maybe", r"algo\.normalize_input='maybe' is not allowed: expected true or false"),
    ("algo.horizon=12", r"algo\.horizon=12 is not allowed: expected a multiple of algo\.seq_len"),
    ("algo.lr_min=0", r"algo\.lr_min=0 is not allowed: expected a number > 0"),
    ("algo.lr_schedule=adaptive algo.lr_max=1e-5", r"algo\.lr=0\.0001 is not allowed: expected a number within "
                                                   r"\[algo\.lr_min, algo\.lr_max\] = \[1e-06, 1e-05\]"),
    ("seed=abc", r"seed='abc' is not allowed: expected an integer in \[0, 2147483647\] or null"),
    ("seed=4294967296", r"seed=4294967296 is not allowed: expected an integer in \[0, 2147483647\] or null"),
    ("algo.critic_warmup_iterations=-1", r"algo\.critic_warmup_iterations=-1 is not allowed: expected an integer >= 0"),
    ("trainer.update_threads=0", r"trainer\.update_threads=0 is not allowed: expected a positive integer or auto"),
    ("envs.num_workers=many", r"envs\.num_workers='many' is not allowed: expected an integer >= 0 or auto"),
    ("trainer.deterministic=maybe", r"trainer\.deterministic='maybe' is not allowed: expected true or false"),
    ("eval.every=0", r"eval\.every=0 is not allowed: expected a positive integer"),
    ("eval.episodes=-1", r"eval\.episodes=-1 is not allowed"),
    ("eval.video_every=-1", r"eval\.video_every=-1 is not allowed"),
    ("checkpoint.every_n_epochs=0", r"checkpoint\.every_n_epochs=0 is not allowed"),
    ("curriculum=randomization curriculum.step=0", r"curriculum\.step=0 is not allowed"),
    ("envs.step_in_main=maybe", r"envs\.step_in_main='maybe' is not allowed"),
])
def test_bad_run_values_and_seed_are_refused_before_anything_is_built(tmp_path, monkeypatch, override, pattern):
    monkeypatch.setattr("vitac.envs.vector_env.TaskVectorEnv", lambda *a, **k: pytest.fail("simulation started"))
    monkeypatch.setattr("vitac.training.build_policy_from_config", lambda *a, **k: pytest.fail("policy built"))
    with pytest.raises(ValueError, match=pattern):
        train(compose_config(SMOKE + override.split(), output_dir=tmp_path / "x"))
    assert not (tmp_path / "x").exists()  # nor a run directory left behind


@pytest.mark.parametrize("envs,cores,groups", [(32, 16, 16), (32, 12, 8), (24, 16, 12), (16, 2, 2), (16, 1, 1),
                                               (7, 4, 1), (2, 64, 2)])
def test_auto_workers_take_the_largest_divisor_of_the_envs_within_the_usable_cores(monkeypatch, envs, cores, groups):
    monkeypatch.setattr("vitac.utils.checks.usable_cores", lambda: cores)
    assert resolve_groups(envs, "auto") == groups
    assert resolve_groups(envs, 0) == 0  # a number is kept as given
    assert resolve_threads("trainer.update_threads", "auto") == cores


def test_train_and_evaluate_run_their_environments_in_the_auto_groups(tmp_path, monkeypatch):
    smoke = ["preset=smoke", "experiment=table1/privileged"]
    ckpt = train(compose_config(smoke, output_dir=tmp_path / "run"))["checkpoint"]
    monkeypatch.setattr("vitac.utils.checks.usable_cores", lambda: 3)
    built = []

    def capture(*args, **kwargs):  # stop at the environments: the split is what this test checks
        built.append(kwargs["num_workers"])
        raise RuntimeError("stop")

    monkeypatch.setattr("vitac.envs.vector_env.TaskVectorEnv", capture)
    monkeypatch.setattr("vitac.evaluate.TaskVectorEnv", capture)
    with pytest.raises(RuntimeError, match="stop"):
        train(compose_config(smoke + ["envs.num_envs=6", "envs.num_workers=auto", "trainer.update_threads=auto"],
                             output_dir=tmp_path / "auto"))
    with pytest.raises(RuntimeError, match="stop"):
        evaluate(ckpt, episodes=4, num_envs=4, num_workers="auto", seed=0)
    assert built == [3, 2]


@pytest.mark.parametrize("arguments,pattern", [
    (dict(episodes=0), r"episodes=0 is not allowed: expected a positive integer"),
    (dict(num_envs=0), r"num_envs=0 is not allowed: expected a positive integer"),
    (dict(num_workers=3), r"num_workers=3 is not allowed: expected 0 or a divisor of num_envs=4"),
    (dict(seed="abc"), r"seed='abc' is not allowed: expected an integer in \[0, 2\^32 - 1 - episodes\]"),
    (dict(seed=2**32 - 5), r"seed=4294967291 is not allowed: expected an integer in \[0, 2\^32 - 1 - episodes\] = "
                           r"\[0, 4294967285\]"),
    (dict(socket_obs_noise=float("nan")), r"socket_obs_noise=nan is not allowed: expected a finite number"),
    (dict(task_overrides={"socket_friction": float("inf")}), r"task_overrides\.socket_friction=inf is not allowed"),
    (dict(deterministic="yes"), r"deterministic='yes' is not allowed: expected true or false"),
])
def test_bad_evaluation_arguments_are_refused_before_the_checkpoint_is_read(monkeypatch, arguments, pattern):
    monkeypatch.setattr("vitac.evaluate.load_policy", lambda *a, **k: pytest.fail("checkpoint read"))
    with pytest.raises(ValueError, match=pattern):
        evaluate("run/last.ckpt", **(dict(episodes=10, num_envs=4, num_workers=2, seed=0) | arguments))


def _float_keys(node, key=""):
    """Every float setting of a resolved config, with its dotted key (list entries as key[i])."""
    if isinstance(node, dict):
        for name, value in node.items():
            yield from _float_keys(value, f"{key}.{name}" if key else name)
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield from _float_keys(value, f"{key}[{i}]")
    elif isinstance(node, float):
        yield key


@pytest.mark.parametrize("experiment", ["experiment=table1/fusion_cmt_sym", "experiment=recipe/privileged_32envs",
                                        "task=screw", "finetune=kickstart"])
def test_every_float_setting_refuses_nan_and_infinity_by_its_key(experiment):
    """The float keys come from the composed configs, so a new key is covered without editing this test."""
    from omegaconf import OmegaConf

    from vitac.algos.run_checks import check_run

    resolved = OmegaConf.to_container(compose_config([experiment]), resolve=True)
    keys = list(_float_keys(resolved))
    assert len(keys) > 40
    for key in keys:
        for bad in (float("nan"), float("inf")):
            cfg = OmegaConf.create(resolved)
            OmegaConf.update(cfg, key.replace("[", ".").replace("]", ""), bad)
            with pytest.raises(ValueError, match=rf"{re.escape(key)}={bad} is not allowed: expected a finite number"):
                check_run(OmegaConf.to_container(cfg))


def test_a_task_config_refuses_nan_however_it_is_built():
    from vitac.envs.gym_env import TaskEnv

    with pytest.raises(ValueError, match=r"task\.randomization\.pad_stiffness\[1\]=nan is not allowed"):
        TaskEnv({"randomization": {"pad_stiffness": [150.0, float("nan")]}})
    env = TaskEnv({"observations": ["proprio"]})
    env.close()
    env.close()  # a second close is harmless


def test_resume_that_cannot_continue_exactly_is_refused_before_any_environment_is_built(tmp_path, monkeypatch):
    smoke = ["preset=smoke", "experiment=table1/privileged"]
    train(compose_config(smoke, output_dir=tmp_path / "run"))
    monkeypatch.setattr("vitac.envs.vector_env.TaskVectorEnv", lambda *a, **k: pytest.fail("environments built"))
    with pytest.raises(ValueError, match=r"envs\.num_envs=4 is not allowed with resume=.*holds the states of 2 "
                                         r"environments; resume with envs\.num_envs=2, or .* init_ckpt="):
        train(compose_config(smoke + ["envs.num_envs=4", f"resume={tmp_path / 'run'}"], output_dir=tmp_path / "a"))
    with pytest.raises(ValueError, match=r"does not fit this policy: \d+ tensors differ .*policy\.normalizers\.contact"
                                         r".*set differently from the checkpoint's: \['obs'\]"):
        train(compose_config(["preset=smoke", "experiment=table1/privileged_contact", f"resume={tmp_path / 'run'}"],
                             output_dir=tmp_path / "b"))


def test_a_warm_start_or_critic_checkpoint_that_does_not_fit_is_refused_before_any_environment_is_built(
        tmp_path, monkeypatch):
    torn = tmp_path / "torn.ckpt"
    torn.write_bytes(Path("pretrained/privileged.pt").read_bytes()[:5000])
    student = ["preset=smoke", "experiment=table1/tactile"]
    monkeypatch.setattr("vitac.envs.vector_env.TaskVectorEnv", lambda *a, **k: pytest.fail("environments built"))
    for overrides, pattern in (
            ([f"init_ckpt={torn}"], r"init_ckpt='.*torn\.ckpt' is not a readable vitac checkpoint"),
            (["init_ckpt=pretrained/privileged"], r"init_ckpt='pretrained/privileged' does not fit this policy"),
            ([f"critic_ckpt={torn}"], r"critic_ckpt='.*torn\.ckpt' is not a readable vitac checkpoint"),
            (["critic_ckpt=pretrained/privileged", "critic.units=[64,64]"],
             r"critic_ckpt='pretrained/privileged' does not fit this critic"),
            (["critic_ckpt=pretrained/privileged", "critic=none"], r"critic_ckpt='pretrained/privileged' needs an "
                                                                    r"asymmetric critic")):
        with pytest.raises(ValueError, match=pattern):
            train(compose_config(student + overrides, output_dir=tmp_path / "x"))


def test_every_algo_key_has_its_check():
    from vitac.algos import run_checks as c

    checked = set(c.POSITIVE_INTS + c.NON_NEGATIVE_INTS + c.POSITIVE_NUMBERS + c.NON_NEGATIVE_NUMBERS + c.FRACTIONS
                  + c.FLAGS + c.SCHEDULE)
    assert set(compose_config(["algo=ppo"]).algo) - {"_target_", "_partial_"} == checked


def test_corrupt_checkpoint_is_refused(tmp_path):
    bad = tmp_path / "bad.ckpt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="not a readable vitac checkpoint"):
        load_policy(bad)


def test_corrupt_critic_checkpoint_is_refused(tmp_path):
    bad = tmp_path / "bad.ckpt"
    bad.write_bytes(b"\x00truncated")
    with pytest.raises(ValueError, match="critic_ckpt=.*not a readable vitac checkpoint"):
        train(compose_config(SMOKE + [f"critic_ckpt={bad}"], output_dir=tmp_path / "run"))


@pytest.mark.parametrize("override,error,pattern", [
    ("+foo=1", ValueError, r"foo=1 is not allowed: expected one of \['algo', "),
    ("+algo.lr_decay=0.9", ValueError, r"algo\.lr_decay=0\.9 is not allowed: expected one of .*'kl_threshold'"),
    ("+fusion.depth=2", ValueError, r"fusion\.depth=2 is not allowed: .*CrossModalTransformer"),
    ("+obs.extra=1", ValueError, r"obs\.extra=1 is not allowed: expected one of \['name', 'modalities'\]"),
    ("logger.wandb=maybe", ValueError, r"logger\.wandb='maybe' is not allowed: expected true or false"),
    ("init_exclude=5", ValueError, r"init_exclude=5 is not allowed"),
    ("init_exclude=[policy.head]", ValueError, r"init_ckpt=None is not allowed: expected a checkpoint to start from"),
    ("init_ckpt=/no/such.ckpt", FileNotFoundError, r"init_ckpt='/no/such.ckpt': no such checkpoint file"),
    ("critic_ckpt=/no/such.ckpt", FileNotFoundError, r"critic_ckpt='/no/such.ckpt': no such checkpoint file"),
])
def test_keys_the_run_would_ignore_and_missing_checkpoints_are_refused_before_anything_is_built(
        tmp_path, monkeypatch, override, error, pattern):
    monkeypatch.setattr("vitac.envs.vector_env.TaskVectorEnv", lambda *a, **k: pytest.fail("simulation started"))
    monkeypatch.setattr("vitac.training.build_policy_from_config", lambda *a, **k: pytest.fail("policy built"))
    with pytest.raises(error, match=pattern):
        train(compose_config(SMOKE + [override], output_dir=tmp_path / "x"))


@pytest.mark.parametrize("command,message", [
    (["vitac.train", "reg.lambda_sym=-1"], "error: reg.lambda_sym=-1 is not allowed: expected a number >= 0"),
    (["vitac.train", "task=screw", "obs=privileged"], "error: fusion=cmt is not allowed with obs=privileged"),
    (["vitac.train", "algo.lr=nan"], "error: algo.lr=nan is not allowed: expected a finite number"),
    (["vitac.train", "+foo=1"], "error: foo=1 is not allowed: expected one of"),
    (["vitac.train", "init_ckpt=/no/such.ckpt"], "error: init_ckpt='/no/such.ckpt': no such checkpoint file"),
    (["vitac.evaluate", "policy=foo"], "error: policy='foo' is not allowed: expected one of ['ckpt', 'oracle', 'random']"),
    (["vitac.evaluate", "ckpt=pretrained/privileged", "episodes=0"], "error: episodes=0 is not allowed"),
    (["vitac.evaluate", "policy=oracle", "+oracle_options.foo=1"],
     "error: oracle_options.foo=1 is not allowed: expected one of ['align_tolerance', 'hover', 'observed_socket'"),
    (["vitac.train", "hydra.run.dir=/tmp/" + "a" * 300], "error: hydra.run.dir=/tmp/aaaa"),  # before Hydra makes it
    (["vitac.evaluate", "hydra.run.dir=" + "b/" * 2100], "error: hydra.run.dir=b/b/b/"),
    (["vitac.export", "/no/such.ckpt", "--out", "x.pt"], "error: ckpt='/no/such.ckpt': no such checkpoint file"),
    (["vitac.video", "--ckpt", "/no/such.ckpt"], "error: ckpt='/no/such.ckpt': no such checkpoint file"),
    (["vitac.runs", "outcomes", "/no/such.json"], "error: /no/such.json: cannot be read as a vitac.evaluate report"),
    (["vitac.runs", "summary", "/no/metrics.csv"], "error: /no/metrics.csv: cannot be read as a metrics CSV"),
    (["vitac.report", "/no/runs"], "error: /no/runs: no such directory"),
    (["vitac.train", "seed=-1"], "error: seed=-1 is not allowed: expected an integer in [0, 2147483647]"),
    (["vitac.evaluate", "ckpt=pretrained/privileged", "seed=abc"], "error: seed='abc' is not allowed"),
    (["vitac.runs", "archive", "/no/run", "--out", "/tmp/x"], "error: /no/run: not a run directory to archive"),
    (["vitac.runs", "status", "/no/runs"], "error: /no/runs: no such directory"),
    (["vitac.runs", "log-std", "/no/such.ckpt"], "error: ckpt='/no/such.ckpt': no such checkpoint file"),
])
def test_a_refused_value_prints_one_line_and_exits_2(command, message):
    import subprocess
    import sys

    result = subprocess.run([sys.executable, "-m", *command], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip().splitlines() == [result.stderr.strip()] and result.stderr.startswith(message)
    assert "Traceback" not in result.stderr + result.stdout


def test_a_crash_keeps_its_stack_and_full_error_shows_a_refusals(monkeypatch, capsys):
    from vitac.utils.checks import refuse
    from vitac.utils.cli import refusals_in_one_line

    def crash():
        raise ValueError("shapes (3,) and (4,) not aligned")  # no key=value: a bug, not a refusal

    def refusal():
        refuse("algo.lr", -1, "a number > 0")

    with pytest.raises(ValueError, match="not aligned"):
        refusals_in_one_line(crash)()
    with pytest.raises(SystemExit) as stopped:
        refusals_in_one_line(refusal)()
    assert stopped.value.code == 2 and capsys.readouterr().err == "error: algo.lr=-1 is not allowed: expected a number > 0\n"
    monkeypatch.setenv("HYDRA_FULL_ERROR", "1")
    with pytest.raises(ValueError, match="algo.lr=-1"):
        refusals_in_one_line(refusal)()
