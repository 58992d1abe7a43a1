"""The public Python surface: `from vitac import load_policy, make_env` and the gymnasium ids, run as the README
and docs/environment.md print them."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import vitac
from vitac import load_policy, make_env

ROOT = Path(__file__).resolve().parents[1]


def _python_blocks(page: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", (ROOT / page).read_text(), flags=re.S)


@pytest.mark.parametrize("page", ["README.md", "docs/environment.md"])
def test_the_python_examples_run_as_printed(page, capsys):
    blocks = _python_blocks(page)
    assert blocks
    for block in blocks:
        exec(compile(block, page, "exec"), {})
    printed = capsys.readouterr().out.split()
    assert printed and printed[0] in {"inserted", "stuck", "on", "not", "dropped", "at"}  # an outcome's first word


@pytest.mark.filterwarnings("ignore:.*Box observation space (minimum|maximum) value is")  # float observations are unbounded
@pytest.mark.parametrize("gym_id", list(vitac.api.GYM_IDS))
def test_the_gymnasium_ids_pass_gymnasiums_checker(gym_id):
    env = gymnasium.make(gym_id, observations=["proprio", "tactile_left", "tactile_right"])
    check_env(env.unwrapped, skip_render_check=True)
    assert set(env.observation_space.spaces) == {"proprio", "tactile_left", "tactile_right"}
    env.close()


def test_a_shipped_policy_acts_as_its_evaluation_does():
    """load_policy's actions are the evaluated policy's: the first steps' actions equal run_episodes' mean action
    (a fresh recurrent state at reset), and reset() starts the state again."""
    import torch

    policy = load_policy("privileged")
    env = make_env(policy=policy)
    first = []
    for _ in range(2):
        obs, _ = env.reset(seed=3)
        policy.reset()
        first.append(policy.act(obs))
    env.close()
    np.testing.assert_array_equal(first[0], first[1])
    network = policy.network
    inputs, starts = network.step_inputs({k: np.asarray(v)[None] for k, v in obs.items()}, torch.ones(1))
    with torch.no_grad():
        mean = network(inputs, network.initial_state(1), starts)[0][0, 0].numpy()
    np.testing.assert_allclose(first[0], np.clip(mean, -1, 1), rtol=1e-6)
    with pytest.raises(ValueError, match=r"name='no_such_policy' is not allowed"):
        load_policy("no_such_policy")
    with pytest.raises(ValueError, match=r"task='peg' is not allowed: expected one of \['insertion', 'screw', "):
        make_env("peg")


def test_make_env_builds_every_task_config_as_training_composes_it():
    """`make_env(task=<name>)` reads conf/task/<name>.yaml and the configs it extends, as `vitac.train task=<name>`
    does, and a keyword changes only the keys it names."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from tests.conftest import CONF

    assert vitac.api.task_names() == ["insertion", "screw", "screw_insert", "screw_offthread"]
    for task in vitac.api.task_names():
        with initialize_config_dir(version_base="1.3", config_dir=str(CONF)):
            trained = OmegaConf.to_container(compose("config", overrides=[f"task={task}"]).task, resolve=True)
        assert vitac.api.task_settings(task) == trained
    env = make_env("screw_insert", observations=["proprio"], randomization={"hover": [0.02, 0.02]})
    assert (env.config.start, env.config.episode_steps) == ("off_thread", 600)
    assert env.config.randomization.hover == [0.02, 0.02]
    assert env.config.randomization.bolt_obs_noise == 0.001  # screw_offthread's, kept beside the changed key
    env.close()
    # a policy's environment takes keywords the same way: its other randomization keys stay (the off-thread
    # task's bolt noise is not ScrewConfig's default)
    trained_on = SimpleNamespace(settings=vitac.api.task_settings("screw_offthread"), observations=["proprio"])
    env = make_env(policy=trained_on, randomization={"scale": 0.5})
    assert env.config.randomization.scale == 0.5 and env.config.randomization.bolt_obs_noise == 0.001
    env.close()
