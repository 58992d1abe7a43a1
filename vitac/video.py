"""Render one episode to a video: outside view, wrist view, and both pads' force fields (arrows for shear
over a heatmap of normal force), side by side as in the paper's force-field figure.

    python -m vitac.video --out docs/media/oracle_episode.gif            # scripted oracle
    python -m vitac.video --ckpt outputs/.../checkpoints/last.ckpt --out episode.mp4

The right pad's map is shown with its rows flipped, so a balanced grasp looks like two matching maps.
"""

from __future__ import annotations

import argparse

from vitac.envs.gym_env import TaskEnv  # first: it selects headless EGL before mujoco loads
from vitac.tasks.insertion.oracle import OracleController
from vitac.utils.cli import int_at_least, output_file, refuse_bad_files, tool_entry
from vitac.viz import OUTSIDE, VIDEO_OBSERVATIONS, policy_actor, record_episode, save_video


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m vitac.video", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ckpt", default=None, help="policy checkpoint (default: the scripted oracle)")
    parser.add_argument("--seed", type=int_at_least(0), default=0)
    parser.add_argument("--every", type=int_at_least(1), default=3, help="render every k-th control step")
    parser.add_argument("--out", type=output_file, default="episode.gif")
    args = parser.parse_args(argv)
    if args.ckpt:
        from vitac.run_config import load_policy

        with refuse_bad_files():
            policy, _, settings = load_policy(args.ckpt)
        env = TaskEnv(dict(settings, observations=sorted(set(settings["observations"]) | set(VIDEO_OBSERVATIONS))),
                           seed=args.seed, offscreen_size=OUTSIDE)
        act = policy_actor(policy)
    else:
        env = TaskEnv({"observations": ["proprio"] + VIDEO_OBSERVATIONS}, seed=args.seed, offscreen_size=OUTSIDE)
        oracle = OracleController(env.task)
        act = lambda obs: oracle(env.physics)  # noqa: E731
    frames, info = record_episode(env, act, args.seed, args.every)
    env.close()
    save_video(frames, args.out, args.every)
    print(f"{args.out}: {len(frames)} frames, success={info['success']}, steps to succeed={info['steps_to_success']}")


if __name__ == "__main__":
    tool_entry(main)()
