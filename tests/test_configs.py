"""Config tier: every option of every group composes and instantiates; YAML keys match constructors."""

from __future__ import annotations

import importlib
import inspect
from pathlib import Path

import pytest
import torch
import yaml
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf

from tests.conftest import CONF, compose_config
from vitac.run_config import build_policy_from_config, load_policy, task_settings
from vitac.tasks import make_task_config
from vitac.tasks.insertion.config import InsertionConfig
from vitac.utils.checks import ConfigError

TABLE_I = [  # (obs, fusion) for every row of the paper's Table I
    ("privileged", "naive"), ("privileged_contact", "naive"), ("tactile", "naive"), ("wrist", "naive"),
    ("wrist_contact", "naive"), ("wrist_tactile", "naive"), ("wrist_tactile", "gated"), ("wrist_tactile", "cmt"),
]


def _targets():
    for path in sorted(Path(CONF).rglob("*.yaml")):
        if "hydra" in path.parts:
            continue
        data = yaml.safe_load(path.read_text()) or {}
        nodes = [data] + [v for v in data.values() if isinstance(v, dict)]
        for node in nodes:
            if isinstance(node, dict) and node.get("_target_"):
                yield path, node


def _resolve(target: str):
    module, _, attr = target.rpartition(".")
    try:
        return getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError):
        owner_module, _, owner = module.rpartition(".")
        return getattr(getattr(importlib.import_module(owner_module), owner), attr)


@pytest.mark.parametrize("path,node", list(_targets()), ids=lambda x: str(x)[-40:] if isinstance(x, Path) else "")
def test_target_resolves_and_keys_match_signature(path, node):
    from vitac.utils.checks import accepted_keywords

    target = _resolve(node["_target_"])
    params = accepted_keywords(target)  # a class passing **kwargs on to its base takes the base's keys too
    if params is None:
        params = set(inspect.signature(target).parameters)
    keys = {k for k in node if not k.startswith("_")}
    assert keys <= params, f"{path}: keys {sorted(keys - params)} are not parameters of {node['_target_']}"


def test_env_yaml_matches_insertion_config():
    data = yaml.safe_load((Path(CONF) / "task" / "insertion.yaml").read_text())
    InsertionConfig.from_dict(data)  # unknown keys or bad values would raise
    assert set(data) == set(InsertionConfig().to_dict()) - {"observations"}


@pytest.mark.parametrize("obs,fusion", TABLE_I)
@pytest.mark.parametrize("reg", ["none", "sym"])
def test_table_one_rows_build_and_backpropagate(obs, fusion, reg):
    if reg == "sym" and not obs.startswith(("tactile", "wrist_tactile")):
        pytest.skip("the symmetry prior needs both pads (refused: test_a_fusion_or_regularizer_whose_...)")
    cfg = compose_config([f"obs={obs}", f"fusion={fusion}", f"reg={reg}"])
    env_config = InsertionConfig.from_dict(task_settings(cfg))
    policy = build_policy_from_config(cfg, env_config)
    shapes = env_config.observation_shapes()
    T, B = 3, 2
    obs_t = {k: torch.rand(T, B, *shapes[k]) for k in list(cfg.obs.modalities) + ["critic_state"]}
    if "wrist" in obs_t:
        obs_t["wrist"] = (obs_t["wrist"] * 255).to(torch.uint8)
    mean, log_std, value, state, sym = policy(obs_t, policy.initial_state(B), torch.zeros(T, B), with_aux=True)
    assert mean.shape == (T, B, 6) and log_std.shape == (T, B, 6) and value.shape == (T, B)
    loss = mean.sum() + value.sum() + (sym.mean() if sym is not None else 0)
    loss.backward()
    assert (sym is not None) == (reg == "sym" and "tactile_left" in cfg.obs.modalities)
    grads = [p.grad for p in policy.parameters() if p.requires_grad]
    assert any(g is not None and g.abs().sum() > 0 for g in grads)


def test_symmetry_after_self_attention_reaches_the_self_attention_through_the_policy():
    cfg = compose_config(["obs=wrist_tactile", "fusion=cmt", "reg=sym", "reg.placement=self_attention"])
    env_config = InsertionConfig.from_dict(task_settings(cfg))
    policy = build_policy_from_config(cfg, env_config)
    shapes = env_config.observation_shapes()
    obs_t = {k: torch.rand(2, 2, *shapes[k]) for k in list(cfg.obs.modalities) + ["critic_state"]}
    obs_t["wrist"] = (obs_t["wrist"] * 255).to(torch.uint8)
    sym = policy(obs_t, policy.initial_state(2), torch.zeros(2, 2), with_aux=True)[-1]
    sym.mean().backward()
    assert sym.shape == (4,) and policy.fusion.self_attn.in_proj_weight.grad.abs().sum() > 0
    assert policy.fusion.cross_attn.in_proj_weight.grad is None


@pytest.mark.parametrize("fusion", ["naive", "gated"])
def test_symmetry_after_self_attention_is_refused_without_one(fusion):
    cfg = compose_config(["obs=wrist_tactile", f"fusion={fusion}", "reg=sym", "reg.placement=self_attention"])
    with pytest.raises(ValueError, match=rf"reg\.placement='self_attention' is not allowed with fusion={fusion}: only "
                                         r"fusion=cmt has a tactile self-attention"):
        build_policy_from_config(cfg, InsertionConfig.from_dict(task_settings(cfg)))


def test_nested_override_reaches_constructor():
    cfg = compose_config(["fusion=cmt", "fusion.num_heads=8"])
    policy = build_policy_from_config(cfg, InsertionConfig.from_dict(task_settings(cfg)))
    assert policy.fusion.self_attn.num_heads == 8


def test_unknown_choice_names_the_group_and_options():
    with pytest.raises(ConfigCompositionException) as err:
        compose_config(["fusion=foo"])
    message = str(err.value)
    assert "fusion" in message and "foo" in message and "cmt" in message


@pytest.mark.parametrize("value", ["abc", -1])
def test_bad_lambda_sym_is_refused_with_key_value_and_rule(value):
    cfg = compose_config([f"reg.lambda_sym={value}"])
    with pytest.raises(ValueError, match=r"reg\.lambda_sym=.*expected a number >= 0"):
        build_policy_from_config(cfg, InsertionConfig.from_dict(task_settings(cfg)))


def test_bad_symmetry_weighting_is_refused_with_key_value_and_choices():
    cfg = compose_config(["reg=sym", "reg.weighting=scaled"])
    with pytest.raises(ValueError, match=r"reg\.weighting='scaled' is not allowed: expected one of \['absolute', 'relative'\]"):
        build_policy_from_config(cfg, InsertionConfig.from_dict(task_settings(cfg)))


def test_observation_that_does_not_fit_its_encoder_is_refused():
    cfg = compose_config(["task.taxel_rows=6", "task.taxel_cols=6", "obs=tactile", "fusion=naive"])
    with pytest.raises(ValueError, match=r"task\.taxel_rows x task\.taxel_cols"):
        build_policy_from_config(cfg, InsertionConfig.from_dict(task_settings(cfg)))


@pytest.mark.parametrize("overrides,lacking", [
    (["obs=privileged", "fusion=cmt"], r"fusion=cmt is not allowed with obs=privileged.*lack \['vision', 'left', 'right'\]"),
    (["obs=privileged", "fusion=gated"], r"fusion=gated is not allowed with obs=privileged"),
    (["obs=wrist", "fusion=gated"], r"fusion=gated is not allowed with obs=wrist.*lack \['left', 'right'\]"),
    (["obs=tactile", "fusion=gated"], r"fusion=gated is not allowed with obs=tactile.*lack \['vision'\]"),
    (["obs=wrist_contact", "fusion=cmt"], r"fusion=cmt is not allowed with obs=wrist_contact"),
    (["obs=privileged", "fusion=naive", "reg=sym"], r"reg=sym is not allowed with obs=privileged.*\['left', 'right'\]"),
    (["obs=wrist", "fusion=naive", "reg=sym"], r"reg=sym is not allowed with obs=wrist"),
])
def test_a_fusion_or_regularizer_whose_modalities_obs_lacks_is_refused_naming_both(overrides, lacking):
    cfg = compose_config(overrides)
    with pytest.raises(ValueError, match=lacking):
        build_policy_from_config(cfg, InsertionConfig.from_dict(task_settings(cfg)))


@pytest.mark.parametrize("override,pattern", [
    ("task.clearance=-0.001", r"task\.clearance=-0\.001"),
    ("task.peg_shape=hexagon", r"task\.peg_shape='hexagon'.*round"),
    ("task.taxel_rows=0", r"task\.taxel_rows=0.*positive integer"),
    ("task.peg_size=20", r"task\.peg_size=20"),
])
def test_bad_env_values_are_refused_before_simulation(override, pattern):
    cfg = compose_config([override])
    with pytest.raises(ConfigError, match=pattern):
        InsertionConfig.from_dict(task_settings(cfg))


def test_peg_wider_than_hole_is_refused():
    # A negative clearance small enough to keep the check on the hole: refused as too narrow or not > 0.
    with pytest.raises(ConfigError, match=r"task\.clearance"):
        InsertionConfig.from_dict({"clearance": 0.0})


@pytest.mark.parametrize("preset", ["cpu", "cpu_table1", "paper", "smoke"])
def test_presets_compose_and_name_themselves(preset):
    cfg = compose_config([f"preset={preset}"])
    assert cfg.preset.name == preset
    algo = OmegaConf.to_container(cfg.algo)
    assert (algo["horizon"] * cfg.envs.num_envs) % algo["minibatch_size"] == 0
    assert algo["horizon"] % algo["seq_len"] == 0


def test_table_one_budget_is_the_distillation_recipes_settings_for_450_iterations():
    """Every sensing row at preset=cpu_table1 distils with recipe/cmt_sym_dagger's settings, for 450 iterations
    (the linear rate falls to 0 at each run's own last iteration), from the default teacher."""
    recipe = compose_config(["experiment=recipe/cmt_sym_dagger"])
    for row in ("tactile", "wrist", "fusion_cmt_sym"):
        cfg = compose_config(["preset=cpu_table1", f"experiment=table1/{row}"])
        assert cfg.algo == recipe.algo and cfg.envs == recipe.envs
        assert cfg.teacher_ckpt == "pretrained/privileged_contact_residual"  # the default teacher
        assert cfg.trainer.iterations * cfg.envs.num_envs * cfg.algo.horizon == 460_800
    assert recipe.teacher_ckpt == "pretrained/privileged"  # the one pretrained/cmt_sym_dagger learned from
    assert compose_config(["preset=cpu_table1", "algo=ppo"]).algo.lr == compose_config(["algo=ppo"]).algo.lr
    assert recipe.algo.lr == compose_config(["algo=dagger"]).algo.lr == 3e-4  # the rate of docs/results.md's rows
    assert (recipe.algo.lr_schedule, recipe.algo.dataset_rollouts) == ("linear", 4)  # Table I's rows' settings


def test_the_first_command_distils_with_table_ones_update_on_a_short_budget():
    """`python -m vitac.train` (preset=cpu) distils with Table I's update (the last 4 rollouts, the falling rate)
    for 120 iterations, as its documented run did; PPO at that preset and the 2-minute recipe keep their own."""
    first, table = compose_config([]), compose_config(["preset=cpu_table1"])
    assert first.algo._target_ == "vitac.algos.dagger.DAgger" and first.obs.name == "wrist_tactile"
    assert (first.trainer.iterations, first.algo.beta_iterations) == (120, 30)
    assert {**first.algo, "beta_iterations": None} == {**table.algo, "beta_iterations": None}
    assert compose_config(["algo=ppo"]).trainer.iterations == 20
    recipe = compose_config(["experiment=recipe/privileged_dagger"])
    assert (recipe.algo.lr_schedule, recipe.algo.dataset_rollouts, recipe.trainer.iterations) == ("fixed", 1, 60)


EXPERIMENTS = sorted(str(p.relative_to(Path(CONF) / "experiment").with_suffix("")) for p in
                     (Path(CONF) / "experiment").glob("*/*.yaml"))


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_experiments_compose_and_build_their_env_and_policy(experiment):
    cfg = compose_config([f"experiment={experiment}"])
    build_policy_from_config(cfg, make_task_config(task_settings(cfg)))


def test_every_table_one_row_has_an_experiment_and_recipes_name_their_row():
    assert len([e for e in EXPERIMENTS if e.startswith("table1/")]) == 10
    for experiment in EXPERIMENTS:
        assert compose_config([f"experiment={experiment}"]).row


def test_privileged_recipe_is_the_setting_its_documented_runs_used():
    cfg = compose_config(["experiment=recipe/privileged_32envs"])
    assert (cfg.envs.num_envs, cfg.envs.num_workers, cfg.trainer.iterations) == (32, 2, 2814)  # 23.05 M env steps
    assert {k: cfg.algo[k] for k in ("horizon", "seq_len", "minibatch_size", "mini_epochs", "lr", "lr_schedule",
                                    "kl_threshold", "lr_schedule_every", "lr_min", "lr_max")} == dict(
        horizon=256, seq_len=32, minibatch_size=2048, mini_epochs=4, lr=3e-4, lr_schedule="adaptive",
        kl_threshold=0.008, lr_schedule_every="minibatch", lr_min=1e-6, lr_max=1e-2)
    assert (cfg.head.log_std_mode, cfg.head.log_std_bound, cfg.head.log_std_init) == ("param", "sigmoid", -0.5)
    assert (cfg.task.lateral_reward_scale, cfg.task.success_reward_scale) == (0.5, 0.1)
    assert (cfg.obs.name, cfg.fusion._target_.rsplit(".", 1)[1], cfg.reg.lambda_sym) == ("privileged", "NaiveFusion", 0.0)
    assert cfg.curriculum._target_.endswith("RandomizationCurriculum")


def test_cmt_recipe_is_the_privileged_recipe_with_its_rate_capped_at_the_papers():
    privileged, cmt = (compose_config([f"experiment={name}"])
                       for name in ("recipe/privileged_32envs", "recipe/cmt_sym_32envs"))
    assert cmt.task == privileged.task and cmt.head == privileged.head  # critic_ckpt values the same reward
    assert cmt.envs == privileged.envs and cmt.curriculum == privileged.curriculum
    same = ("horizon", "seq_len", "minibatch_size", "mini_epochs", "lr_schedule", "kl_threshold",
            "lr_schedule_every", "lr_min")
    assert {key: cmt.algo[key] for key in same} == {key: privileged.algo[key] for key in same}
    assert cmt.algo.lr == cmt.algo.lr_max == 1e-4 < privileged.algo.lr_max
    assert (cmt.obs.name, cmt.fusion._target_.rsplit(".", 1)[1], cmt.reg.lambda_sym) == ("wrist_tactile", "CrossModalTransformer", 1.0)


def test_contact_warm_start_is_the_privileged_recipe_with_contact_forces_from_the_shipped_teacher():
    privileged = compose_config(["experiment=recipe/privileged_32envs"])
    warm = compose_config(["experiment=recipe/privileged_contact_warm"])
    assert warm.row == compose_config(["experiment=table1/privileged_contact"]).row == "+ Contact forces"
    assert warm.obs == compose_config(["experiment=table1/privileged_contact"]).obs
    assert (warm.algo, warm.task, warm.head, warm.envs) == (privileged.algo, privileged.task, privileged.head,
                                                             privileged.envs)
    assert warm.init_ckpt == "pretrained/privileged" and warm.curriculum.start == 1.0
    assert warm.trainer.iterations * warm.envs.num_envs * warm.algo.horizon == 2_457_600


@pytest.mark.parametrize("row", ["tactile", "fusion_cmt_sym"])
def test_finetuning_a_student_keeps_what_its_teachers_critic_was_trained_on(row):
    """finetune=aacd: PPO from the teacher's critic, with the teacher recipe's reward terms, rollouts and noise
    bounds, the student's own observations, and a starting noise inside the shipped teachers' trained range."""
    teacher = compose_config(["experiment=recipe/privileged_32envs"])
    cfg = compose_config([f"experiment=table1/{row}", "finetune=aacd"])
    assert cfg.algo._target_ == "vitac.algos.ppo.PPO" and cfg.critic_ckpt == cfg.teacher_ckpt  # the students' teacher
    assert cfg.obs == compose_config([f"experiment=table1/{row}"]).obs and cfg.critic == teacher.critic
    assert cfg.task == teacher.task and cfg.envs == teacher.envs  # the reward and batch the critic learned
    rollout = ("horizon", "seq_len", "minibatch_size", "mini_epochs")
    assert {k: cfg.algo[k] for k in rollout} == {k: teacher.algo[k] for k in rollout}
    assert cfg.algo.lr_schedule == "fixed" and cfg.algo.lr < teacher.algo.lr
    noise = ("log_std_mode", "log_std_bound", "log_std_min", "log_std_max")
    assert {k: cfg.head[k] for k in noise} == {k: teacher.head[k] for k in noise}
    assert list(cfg.init_exclude) == ["policy.head.log_std"]
    for shipped in ("privileged", "privileged_contact"):  # the first Table I's teacher and the default one
        policy, _, _ = load_policy(str(Path(CONF).parent / "pretrained" / shipped), key="teacher_ckpt")
        trained = policy.head._bounded_log_std(torch.zeros(1, 1))  # param mode: one bounded value per dimension
        assert trained.min() <= cfg.head.log_std_init <= trained.max()
    recipe = compose_config(["experiment=recipe/privileged_dagger_finetune"])
    assert recipe.algo == cfg.algo and recipe.task == cfg.task and recipe.head == cfg.head


@pytest.mark.parametrize("launcher,target", [("joblib_local", "JoblibLauncher"), ("slurm", "SlurmLauncher")])
def test_launcher_configs_compose(launcher, target):
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()
    with initialize_config_dir(version_base="1.3", config_dir=CONF):
        cfg = compose("config", overrides=[f"hydra/launcher={launcher}"], return_hydra_config=True)
    assert cfg.hydra.launcher._target_.endswith(target)


@pytest.mark.parametrize("override,pattern", [
    ("head.units=[256,-128,64]", r"head\.units=\[256, -128, 64\] is not allowed: expected a list of any number of positive"),
    ("encoder.vector.hidden=[-5]", r"encoder\.vector\.hidden=\[-5\] is not allowed"),
    ("head.hidden=0", r"head\.hidden=0 is not allowed: expected a positive integer"),
    ("head.layers=0", r"head\.layers=0 is not allowed: expected a positive integer"),
    ("encoder.image.kernels=[8,4]", r"encoder\.image\.kernels=\[8, 4\] is not allowed: expected a list of 3 positive"),
    ("encoder.image.channels=[32,64,0]", r"encoder\.image\.channels=\[32, 64, 0\] is not allowed"),
    ("encoder.image.bf16=maybe", r"encoder\.image\.bf16='maybe' is not allowed: expected true, false or auto"),
    ("fusion.dropout=1.5", r"fusion\.dropout=1\.5 is not allowed: expected a number in \[0, 1\)"),
    ("task.taxel_rows=4", r"encoder\.image\.kernels=\[8, 4, 3\] is not allowed with an observation of shape \(3, 4, 32\)"
                          r".*task\.taxel_rows"),
])
def test_bad_model_values_are_refused_naming_their_key(override, pattern):
    cfg = compose_config([override])
    with pytest.raises(ValueError, match=pattern):
        build_policy_from_config(cfg, InsertionConfig.from_dict(task_settings(cfg)))
