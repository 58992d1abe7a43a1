"""Ship a trained policy: `python -m vitac.export <run>/checkpoints/last.ckpt --out pretrained/<name>.pt`.

Keeps the weights, normalizer statistics and the run's config (no optimizer or environment state), so the file
is a fraction of the checkpoint and loads with torch's weights-only unpickler:
`python -m vitac.evaluate ckpt=pretrained/<name>` evaluates it, `critic_ckpt=` and `init_ckpt=` start from it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from vitac.utils.checkpoint import export_policy
from vitac.utils.cli import output_file, refuse_bad_files, tool_entry


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m vitac.export", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("ckpt", type=Path, help="a training checkpoint")
    parser.add_argument("--out", type=output_file, required=True, help="the shipped file (pretrained/<name>.pt)")
    args = parser.parse_args(argv)
    with refuse_bad_files():
        shipped = export_policy(args.ckpt, args.out)
    size = args.out.stat().st_size / 1e6
    print(f"{args.out}: {len(shipped['state_dict'])} tensors, {size:.1f} MB, {shipped['env_steps']} env steps")


if __name__ == "__main__":
    tool_entry(main)()
