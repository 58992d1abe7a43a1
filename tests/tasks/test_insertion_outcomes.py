"""How an insertion episode ends: where the peg is, the values its randomization drew, and the jams staged from
their causes (a peg held too high, MuJoCo's creep up the pads)."""

from __future__ import annotations

from dataclasses import asdict

import numpy as np
import pytest

from vitac.envs.gym_env import TaskEnv
from vitac.tasks.insertion.config import RANDOMIZED_FACTORS, Randomization


@pytest.mark.parametrize("seed", [3, 4])
def test_inserted_peg_twisted_by_the_hand_stays_within_the_clearance(seed):
    # TacSL's rigid contacts let a fully inserted peg tilt only as far as the clearance allows (1.3 degrees,
    # 3.75 mm of mean keypoint distance, under the 4.5 mm threshold). Soft MuJoCo defaults let the hand twist
    # it to 3.7 degrees and fail an inserted peg.
    from vitac.tasks.insertion.oracle import OracleController

    e = TaskEnv({"observations": ["proprio"]}, seed=0)
    e.reset(seed=seed)
    task, physics = e.task, e.physics
    oracle = OracleController(task)
    while task.first_success_step < 0:
        e.step(oracle(physics))
    for _ in range(40):  # down to the bottom
        e.step(oracle(physics))
    tilts = []
    for _ in range(60):  # push down while twisting about a horizontal axis at the largest action
        *_, info = e.step(np.array([0.0, 0.0, -1.0, 1.0, 0.0, 0.0]))
        axis = physics.data.xmat[task._ids["held_body"]].reshape(3, 3)[:, 2]
        tilts.append(np.degrees(np.arccos(abs(axis[2]))))
    e.close()
    assert max(tilts) < 1.6 and info["success"], (max(tilts), info["keypoint_distance"])


def test_episode_end_reports_where_the_peg_ended():
    e = TaskEnv({"observations": ["proprio"]}, seed=0)
    inserted = e.run_oracle_episode(seed=100)
    outcomes = {}
    for name, action in [("still", np.zeros(6)), ("down", np.array([0.0, 0.0, -1.0, 0.0, 0.0, 0.0]))]:
        e.reset(seed=100)
        done, steps = False, 0
        while not done:
            _, _, te, tr, info = e.step(action)
            done, steps = te or tr, steps + 1
            assert ("outcome" in info) == done  # only the last step carries it
        outcomes[name] = info
    e.close()
    assert inserted["outcome"] == "inserted" and abs(inserted["peg_height"]) < 1e-3 and inserted["peg_offset_xy"] < 5e-4
    assert inserted["fingers_on_socket"] == 0 and 0.029 < inserted["grasp_depth"] < 0.040
    assert outcomes["still"]["outcome"] == "not over the socket" and outcomes["still"]["peg_offset_xy"] > 0.05
    # Driven straight down beside the socket, the peg hits the table and turns over in the grasp.
    assert outcomes["down"]["outcome"] == "dropped or knocked over" and outcomes["down"]["peg_tilt"] > 1.0


def test_episode_end_reports_the_values_its_randomization_drew():
    e = TaskEnv({"observations": ["proprio"]}, seed=0)
    obs, _ = e.reset(seed=7)
    task, physics = e.task, e.physics
    socket, noise = task.socket_pos(physics), task._socket_noise.copy()
    done = False
    while not done:
        _, _, te, tr, info = e.step(np.zeros(6))
        done = te or tr
    e.close()
    factors = info["factors"]
    assert set(factors) == set(RANDOMIZED_FACTORS)  # every factor of the paper's table, by the names randomize_only takes
    np.testing.assert_allclose(factors["socket_pos"], socket)
    np.testing.assert_allclose(factors["socket_obs_noise"], noise)
    r = Randomization()
    assert r.peg_in_hand_depth[0] <= factors["peg_in_hand_depth"] <= r.peg_in_hand_depth[1]
    assert r.peg_in_hand_tilt[0] <= factors["peg_in_hand_tilt"] <= r.peg_in_hand_tilt[1]
    # The observation's hand position is the drawn one (the grasp settles with the hand held in place).
    np.testing.assert_allclose(obs["proprio"][:3], factors["ee_pos"], atol=2e-3)


def test_a_peg_held_too_high_in_the_hand_sticks_part_way_with_the_fingers_on_the_socket_rim():
    """The jam the policies' "stuck part-way" episodes end in, staged: with the peg's bottom 15 mm below the
    fingertips (the hole is 23 mm deep), the oracle's descent stops when a finger link lands on the socket's top,
    the peg 8 mm short of the floor, however hard the hand pushes."""
    r = asdict(Randomization().only(["ee_pos"]))
    r["peg_in_hand_depth"] = [0.015, 0.015]
    e = TaskEnv({"observations": ["proprio"], "randomization": r}, seed=0)
    info = e.run_oracle_episode(seed=3)
    e.close()
    assert info["outcome"] == "stuck part-way in the hole" and info["fingers_on_socket"] >= 1
    assert 0.006 < info["peg_height"] < 0.010 and info["grasp_depth"] == pytest.approx(0.015, abs=0.002)


def _grasp_depth_while_pushing_on_the_socket_top(noslip_iterations: int, push_steps: int) -> tuple[float, float]:
    """The peg's bottom below the fingertips (m) after it lands on the socket's top face 6 mm off the hole and
    after `push_steps` more steps of the hand pushing down at full action."""
    r = asdict(Randomization().only(["ee_pos"]))
    r["peg_in_hand_depth"] = [0.032, 0.032]
    e = TaskEnv({"observations": ["proprio"], "randomization": r, "episode_steps": 150 + 50 + push_steps,
                 "noslip_iterations": noslip_iterations}, seed=0)
    e.reset(seed=3)
    task, physics = e.task, e.physics
    peg, tcp = task._ids["held_body"], task._ids["tcp"]
    top = task.socket_pos(physics) + (0.006, 0.0, 0.023)
    depths = []
    for step in range(150 + 50 + push_steps):
        action = np.zeros(6)
        action[:3] = np.clip((top + (0, 0, 0.005) - physics.data.xpos[peg]) / 0.01, -1, 1)
        if step >= 150:
            action[2] = -1.0
        e.step(action)
        if step + 1 in (200, 200 + push_steps):
            d = physics.data
            depths.append(float((d.site_xpos[tcp] - d.xpos[peg]) @ d.xmat[peg][2::3]))
    e.close()
    return depths[0], depths[1]


def test_a_held_peg_creeps_up_the_pads_under_a_steady_push_unless_the_noslip_solver_runs():
    """MuJoCo's soft contacts let a held peg creep along the pads under a steady push below the friction limit
    (the policies' jams); PhysX, TacSL's engine, holds it. With noslip passes it slips on impact, then holds."""
    landed, pushed = _grasp_depth_while_pushing_on_the_socket_top(0, 200)
    assert landed - pushed > 0.003  # 3 mm or more in 200 steps (3.3 s), and still creeping
    landed, pushed = _grasp_depth_while_pushing_on_the_socket_top(3, 200)
    assert abs(landed - pushed) < 0.0003
