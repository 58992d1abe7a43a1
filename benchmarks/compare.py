"""A base commit against this working tree, back to back in one command: the environment and policy benchmarks
run on both, each figure printed with its ratio, so a change to `vitac/sim/` or a task shows its cost before
it lands.

    python benchmarks/compare.py --base <commit> [--steps 1000] [--passes 300] [--rounds 5] [--json FILE]

The base is checked out in a temporary git worktree (removed afterwards). Each round runs the base's scripts,
then the head's, each in its own process importing its own tree's `vitac`: the environment benchmark (one
insertion environment, every observation on) and the policy benchmark (naive, gated and CMT at batch 1 and
256). A shared machine's speed drifts by tens of percent within minutes, every piece of a step together, so
each figure's ratio is the median over rounds of head against the base measured just before it; the figures
themselves are the medians of their rounds.
Either tree's scripts may live in `benchmarks/` or, before 2026-11-30, `tools/`. Pause training runs first:
a busy core makes every ratio meaningless.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from vitac.utils.cli import int_at_least, output_file, tool_entry
from vitac.utils.records import write_record

ROOT = Path(__file__).resolve().parents[1]
# The figures read from bench_env's one-environment record; rates are better higher, times (ms) lower.
ENV_FIGURES = ("steps_per_s", "step_ms", "physics_ms", "render_ms", "tactile_ms", "framework_ms",
               "tactile_pad_frames_per_s")
RATES = {"steps_per_s", "tactile_pad_frames_per_s"}


def script(tree: Path, name: str) -> Path:
    for folder in ("benchmarks", "tools"):
        if (tree / folder / name).is_file():
            return tree / folder / name
    raise SystemExit(f"{tree} has no benchmarks/{name} or tools/{name}")


def run_json(tree: Path, name: str, args: list, out: Path) -> dict:
    """Run `tree`'s benchmark `name` importing `tree`'s vitac, and read the record it writes to `out`."""
    path = script(tree, name)
    if name == "bench_env.py" and '"--single"' in path.read_text():
        args = [*args, "--single"]  # the vectorised rows are not compared; older scripts always run them
    env = dict(os.environ, PYTHONPATH=str(tree))
    done = subprocess.run([sys.executable, str(path), *args, "--json", str(out)], cwd=tree, env=env,
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if done.returncode:  # the profiler's chatter on stderr is shown only when something failed
        print(done.stderr, file=sys.stderr)
        raise SystemExit(f"{path} failed with status {done.returncode}")
    return json.loads(out.read_text())


def env_figures(record: dict) -> dict:
    single = record["single"]
    single = single.get("insertion", single)  # `--single` records keep one entry per task
    return {name: single[name] for name in ENV_FIGURES}


def policy_figures(record: dict) -> dict:
    rows = [r for r in record["rows"] if r["device"] == "cpu"]
    return {f"{r['fusion']}_{key}": r[key] for r in rows for key in ("latency_ms", "latency_b256_ms")}


def measure(tree: Path, steps: int, passes: int, scratch: Path) -> dict:
    env = run_json(tree, "bench_env.py", ["--steps", str(steps)], scratch / "env.json")
    policy = run_json(tree, "bench_policy.py", ["--passes", str(passes)], scratch / "policy.json")
    return {**env_figures(env), **policy_figures(policy)}


def commit_of(name: str) -> str | None:
    found = subprocess.run(["git", "rev-parse", "--verify", "--quiet", f"{name}^{{commit}}"], cwd=ROOT,
                           capture_output=True, text=True)
    return found.stdout.strip() if found.returncode == 0 else None


def compare(base: str, steps: int, passes: int, rounds: int) -> dict:
    """`base` (a full commit hash) and the working tree, `rounds` times each, alternating."""
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    dirty = bool(subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                                capture_output=True, text=True).stdout.strip())
    with tempfile.TemporaryDirectory(prefix="vitac-compare-") as tmp:
        tree = Path(tmp) / "base"
        subprocess.run(["git", "worktree", "add", "--detach", "--quiet", str(tree), base], cwd=ROOT,
                       check=True)
        try:
            results = {"base": [], "head": []}
            for i in range(rounds):
                for side, root in (("base", tree), ("head", ROOT)):
                    print(f"round {i + 1}/{rounds}: {side}", flush=True)
                    results[side].append(measure(root, steps, passes, Path(tmp)))
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=ROOT, check=True)
    figures = {k: dict(base=_median([r[k] for r in results["base"]]), head=_median([r[k] for r in results["head"]]),
                       head_vs_base=_median([_speedup(k, b[k], h[k])
                                             for b, h in zip(results["base"], results["head"], strict=True)]))
               for k in results["base"][0]}
    return dict(date=datetime.date.today().isoformat(), base=base, head=head + (" + uncommitted changes" if dirty else ""), steps=steps,
                passes=passes, rounds=rounds, figures=figures, per_round=results)


def _median(values: list) -> float:
    return float(statistics.median(values))


def _speedup(name: str, base: float, head: float) -> float:
    """Head's speed over base's: above 1 is faster, whatever the figure's unit."""
    return head / base if name in RATES else base / head


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--base", required=True, help="a commit, branch or tag")
    parser.add_argument("--steps", type=int_at_least(1), default=1000, help="environment steps a round")
    parser.add_argument("--passes", type=int_at_least(1), default=300, help="policy passes a round at batch 1")
    parser.add_argument("--rounds", type=int_at_least(1), default=5)
    parser.add_argument("--json", type=output_file, default=None)
    args = parser.parse_args()
    base = commit_of(args.base)
    if base is None:
        parser.error(f"argument --base: {args.base!r} is not allowed: not a commit of this repository")
    result = compare(base, args.steps, args.passes, args.rounds)
    print(f"\n| figure | base {result['base'][:7]} | head {result['head'][:7]} | head speed vs base (median of rounds) |\n|---|---|---|---|")
    for name, f in result["figures"].items():
        print(f"| {name} | {f['base']:.4g} | {f['head']:.4g} | {f['head_vs_base']:.2f}x |")
    if args.json:
        write_record(args.json, **result)


if __name__ == "__main__":
    tool_entry(main)()
