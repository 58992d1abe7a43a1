"""The shipped policies (pretrained/): each loads by name, weights-only, as the policy pretrained/README.md says
it is, and acts on its task's observations."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
import torch
import yaml
from omegaconf import OmegaConf

from tests.conftest import compose_config
from vitac.run_config import load_policy
from vitac.tasks import make_task_config
from vitac.utils.checkpoint import load_checkpoint


def test_the_shipped_teacher_is_the_privileged_policy():
    policy, _, _ = load_policy("pretrained/privileged", key="teacher_ckpt")
    assert set(policy.input_keys) == {"proprio", "peg_state", "critic_state"} and not policy.image_keys
    assert load_checkpoint("pretrained/privileged")["env_steps"] == 23_052_288  # the recipe's 2,814 x 32 x 256
    # The teacher of the first Table I cells and of the shipped student stays loadable under its own name.
    assert load_checkpoint("pretrained/privileged_18M")["env_steps"] == 18_513_920  # iteration 2,260


def test_the_contact_force_teacher_is_the_archived_run_and_reads_the_contact_forces():
    policy, config, _ = load_policy("pretrained/privileged_contact", key="teacher_ckpt")
    assert set(policy.input_keys) == {"proprio", "peg_state", "contact_forces", "critic_state"}
    assert load_checkpoint("pretrained/privileged_contact")["env_steps"] == 5_341_184  # 652 iterations of 32 x 256
    archived = json.loads(Path("docs/data/results/teacher_contact/checkpoints/last.eval.json").read_text())
    assert archived["episodes"] == 400 and round(archived["success_rate"] * 400) == 383
    assert config.seed == 2 and config.init_ckpt == "pretrained/privileged_seed2"


def test_the_shipped_student_is_the_distilled_wrist_tactile_cmt_sym_policy():
    policy, _, settings = load_policy("pretrained/cmt_sym_dagger")
    config = load_checkpoint("pretrained/cmt_sym_dagger")["vitac_config"]
    assert config["algo"]["_target_"] == "vitac.algos.dagger.DAgger"
    # Distilled from the shipped teacher: its Table I cell's record names the teacher's file by content.
    record = json.loads(Path("docs/data/table1_runs/fusion_cmt_sym_seed0/teacher.json").read_text())
    assert record["sha256"] == hashlib.sha256(Path("pretrained/privileged.pt").read_bytes()).hexdigest()
    assert type(policy.fusion).__name__ == "CrossModalTransformer" and policy.regularizer.lambda_sym == 1.0
    assert {"wrist", "tactile_left", "tactile_right"} <= set(policy.image_keys) and "peg_state" not in policy.input_keys
    # The force-field scale was learned (an untrained one is the identity: mean square 1).
    assert policy.force_scale.count > 1e5 and (policy.force_scale.mean_square < 0.1).all()
    specs = make_task_config(settings).observation_specs()
    obs = {k: torch.zeros((1, 2, *specs[k].shape)) for k in policy.input_keys}
    with torch.no_grad():
        mean, _, _, _ = policy(obs, policy.initial_state(2), torch.ones(1, 2, dtype=torch.bool))
    assert mean.shape == (1, 2, 6) and torch.isfinite(mean).all()


def test_the_97_percent_teacher_is_a_residual_head_on_the_frozen_contact_teacher():
    tuned = load_checkpoint("pretrained/privileged_contact_residual")["state_dict"]
    base = load_checkpoint("pretrained/privileged_contact")["state_dict"]
    added = set(tuned) - set(base)
    assert added and all(k.startswith("policy.residual.") for k in added) and not set(base) - set(tuned)
    moved = [k for k in base if not torch.equal(tuned[k], base[k])]  # the actor and its input statistics stay frozen
    assert moved and all(k.startswith(("policy.critic", "value_normalizer")) for k in moved)
    archive = Path("docs/data/results/teacher_contact_residual")
    inserted = [round(json.loads(p.read_text())["success_rate"] * 400)
                for p in (archive / "checkpoints" / "last.eval.json", archive / "unseen_seeds_eval.json")]
    assert inserted == [391, 393]  # at least 97% of both sets
    # its recipe composes the archived run's configuration
    recipe = OmegaConf.to_container(compose_config(["experiment=recipe/privileged_contact_residual"]), resolve=True)
    run = yaml.safe_load((archive / "config.yaml").read_text())
    assert recipe["task"].pop("name") == "insertion"  # the run predates task configs carrying their name
    for key in ("task", "obs", "head", "residual", "critic", "algo", "envs", "trainer", "init_ckpt", "critic_ckpt"):
        assert recipe[key] == run[key], key


@pytest.mark.parametrize("name,cell,lambda_sym,teacher", [
    ("cmt_contact", "contact_teacher/fusion_cmt_seed0", 0.0, "privileged_contact"),
    ("cmt_sym_contact", "contact_teacher/fusion_cmt_sym_seed0", 1.0, "privileged_contact"),
    ("cmt_residual_teacher_seed1", "residual_teacher/fusion_cmt_seed1", 0.0, "privileged_contact_residual")])
def test_the_shipped_cmt_students_are_their_archived_cells(name, cell, lambda_sym, teacher):
    policy, _, _ = load_policy(f"pretrained/{name}")
    assert type(policy.fusion).__name__ == "CrossModalTransformer" and policy.regularizer.lambda_sym == lambda_sym
    assert load_checkpoint(f"pretrained/{name}")["env_steps"] == 460_800  # Table I's budget, 450 x 1,024
    record = json.loads(Path(f"docs/data/results/{cell}/teacher.json").read_text())
    assert record["sha256"] == hashlib.sha256(Path(f"pretrained/{teacher}.pt").read_bytes()).hexdigest()


def test_the_off_thread_screw_teacher_is_its_archived_run_on_the_tightening_only_task():
    _, _, settings = load_policy("pretrained/screw_offthread_privileged", key="teacher_ckpt")
    assert settings["start"] == "off_thread" and settings["unidirectional_rotation"]
    assert load_checkpoint("pretrained/screw_offthread_privileged")["env_steps"] == 307_200  # 300 x 32 x 32
    archive = Path("docs/data/results/screw_offthread/privileged_seed0")
    report = json.loads((archive / "checkpoints" / "last.eval.json").read_text())
    assert report["outcomes"]["threaded on and seated"] == 380 and report["episodes"] == 400


def test_the_insert_then_screw_teacher_is_its_archived_900_iteration_run():
    _, _, settings = load_policy("pretrained/screw_insert_privileged", key="teacher_ckpt")
    assert settings["start"] == "off_thread" and settings["episode_steps"] == 600
    assert settings["randomization"]["start_offset_high"] == [0.03, 0.03]  # carried from 30 mm off the axis
    assert load_checkpoint("pretrained/screw_insert_privileged")["env_steps"] == 921_600  # 900 x 32 x 32
    report = json.loads(Path("docs/data/results/screw_insert/privileged_seed0/checkpoints/last.eval.json").read_text())
    assert report["outcomes"]["threaded on and seated"] == 288 and report["episodes"] == 400


def test_the_continued_insert_then_screw_teacher_starts_from_the_shipped_one_and_is_its_archived_run():
    config = yaml.safe_load(Path("docs/data/results/screw_insert_cont/privileged_seed0/config.yaml").read_text())
    assert config["init_ckpt"] == "pretrained/screw_insert_privileged" and config["trainer"]["iterations"] == 500
    assert load_checkpoint("pretrained/screw_insert_privileged_1400")["env_steps"] == 512_000  # 500 x 32 x 32
    report = json.loads(Path("docs/data/results/screw_insert_cont/privileged_seed0/checkpoints/last.eval.json").read_text())
    assert report["outcomes"]["threaded on and seated"] == 341 and report["episodes"] == 400


def test_a_teacher_whose_weights_do_not_fit_its_config_is_refused_naming_the_key(tmp_path):
    """A checkpoint is rebuilt from its own stored config, so a teacher of another architecture than the student
    is fine; weights that do not fit that config (a hand-edited file) are refused before anything is simulated."""
    shipped = torch.load("pretrained/privileged.pt", weights_only=True)
    shipped["vitac_config"]["head"]["hidden"] = 128  # the LSTM's weights are 256 wide
    torch.save(shipped, tmp_path / "edited.pt")
    with pytest.raises(ValueError, match=r"teacher_ckpt=.*edited.pt.*do not fit.*other shape \['head\.lstm"):
        load_policy(tmp_path / "edited.pt", key="teacher_ckpt")


def test_the_longer_distilled_student_continues_the_shipped_one_from_the_same_teacher():
    config = load_checkpoint("pretrained/cmt_sym_dagger_900")["vitac_config"]
    assert config["init_ckpt"] == "pretrained/cmt_sym_dagger" and config["algo"]["beta_start"] == 0.0
    record = json.loads(Path("docs/data/results/cmt_sym_dagger_continued/teacher.json").read_text())
    assert record["sha256"] == hashlib.sha256(Path("pretrained/privileged.pt").read_bytes()).hexdigest()


def test_shipped_policies_load_by_name_from_any_working_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the defaults (teacher_ckpt=pretrained/privileged) must not depend on where one runs
    assert load_checkpoint("pretrained/privileged")["env_steps"] == 23_052_288
    (tmp_path / "pretrained").mkdir()
    torch.save({"state_dict": {}, "vitac_config": {}}, tmp_path / "pretrained" / "privileged.pt")
    assert load_checkpoint("pretrained/privileged")["state_dict"] == {}  # one's own file of that name wins


def test_a_policy_stored_with_bfloat16_loads_with_the_machines_precision():
    # Shipped before `auto` existed with bf16=true, which CPUs without native bfloat16 emulate 6-7x slower.
    assert load_checkpoint("pretrained/cmt_sym_dagger")["vitac_config"]["encoder"]["image"]["bf16"] is True
    policy, cfg, _ = load_policy("pretrained/cmt_sym_dagger")
    assert {policy.encoders[k].bf16 for k in ("wrist", "tactile_left", "tactile_right")} == {"auto"}
    assert cfg.encoder.image.bf16 == "auto"
