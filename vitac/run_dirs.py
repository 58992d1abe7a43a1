"""A run directory over its attempts: whether it finished, resuming it in place (`resume=auto`), its metrics,
and what a finished run prints about where it left them.

A sweep re-run with `resume=auto` finds each cell's directory where the first attempt left it (Hydra names it
by its overrides): a finished cell is skipped, an interrupted one continues from its last checkpoint in the
same directory. Lightning's CSV logger deletes the metrics file of the directory it writes to, so each
earlier attempt's file is first kept as `csv/metrics_part<k>.csv`; `read_metrics` joins them.
"""

from __future__ import annotations

import csv
import hashlib
import json
import shutil
from pathlib import Path

import yaml

from vitac.utils.checkpoint import checkpoint_env_steps, load_checkpoint, resolve_checkpoint
from vitac.utils.records import check_writable_dir, read_whole, write_json

PART_PREFIX = "metrics_part"
EVALUATION = Path("checkpoints") / "last.eval.json"  # vitac.evaluate's report on the last checkpoint
# vitac.evaluate's report on 400 episodes whose seeds no run has used (seed=3000000), beside the held-out one
UNSEEN_EVALUATION = "unseen_seeds_eval.json"
UNSEEN_SEED = 3_000_000
TEACHER_RECORD = "teacher.json"  # a distilled run's teacher by content (write_teacher_record)
ARCHIVE_RECORD = "run.json"  # in a run's archive (vitac/analysis/archive.py): the iterations its checkpoint held
MIN_FREE_BYTES = 200 * 2**20  # a run's checkpoints (up to ~14 MB each), metrics and videos, with room to spare


def check_output_dir(out: Path, min_free: int = MIN_FREE_BYTES) -> None:
    """Refuse, before anything is built, a run directory that cannot be created or written or whose disk is
    nearly full: a run would otherwise fail at its first checkpoint, hours in."""
    out = Path(out)
    try:
        check_writable_dir(out)
    except OSError as err:
        raise OSError(f"output directory {str(out)!r} is not writable ({err.strerror or err}): choose another "
                      "with hydra.run.dir=<dir> (or hydra.sweep.dir=<dir> for a sweep)") from err
    free = shutil.disk_usage(out).free
    if free < min_free:
        raise OSError(f"output directory {str(out)!r} has {free / 2**20:.0f} MiB free, less than the "
                      f"{min_free / 2**20:.0f} MiB a run needs for its checkpoints and logs: free space or choose "
                      "another with hydra.run.dir=<dir>")


def last_checkpoint(run: Path) -> Path:
    return Path(run) / "checkpoints" / "last.ckpt"


def completed_iterations(run: Path) -> int:
    """Iterations the run's last checkpoint holds (0 without one): its env steps over the steps an iteration takes."""
    path = last_checkpoint(run)
    if not path.is_file():
        return 0
    checkpoint = load_checkpoint(path, key="resume")
    cfg = checkpoint["vitac_config"]
    return int(checkpoint["vitac"]["env_steps"]) // (int(cfg["envs"]["num_envs"]) * int(cfg["algo"]["horizon"]))


def auto_resume(out: Path, iterations: int) -> tuple[Path | None, bool]:
    """For `resume=auto` in run directory `out`: (the directory to resume from, or None for a fresh start;
    whether the run already finished its `iterations`)."""
    if not last_checkpoint(out).is_file():
        return None, False
    return Path(out), completed_iterations(out) >= iterations


def keep_metrics(out: Path) -> None:
    """Keep the metrics of the attempt that wrote `out/csv/metrics.csv` before another attempt in `out` starts."""
    current = Path(out) / "csv" / "metrics.csv"
    if current.is_file():
        parts = sorted(current.parent.glob(f"{PART_PREFIX}*.csv"))
        current.rename(current.parent / f"{PART_PREFIX}{len(parts):03d}.csv")


def recover_metrics_row(out: Path, resumed: Path, checkpoint: Path) -> None:
    """A run killed after `last.ckpt` recorded an iteration but before the logger wrote that iteration's row: the
    row, which the checkpoint carries, is written to `out` as a part of its own, so the resumed run's metrics have
    no hole (`read_metrics` reads it in order; an iteration logged twice counts once)."""
    row = load_checkpoint(checkpoint, key="resume")["vitac"].get("metrics_row")
    if row is None or any(r.get("epoch") == str(row["epoch"]) for r in read_metrics(resumed)):
        return
    folder = Path(out) / "csv"
    folder.mkdir(parents=True, exist_ok=True)
    parts = sorted(folder.glob(f"{PART_PREFIX}*.csv"))
    with open(folder / f"{PART_PREFIX}{len(parts):03d}.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=sorted(row))
        writer.writeheader()
        writer.writerow(row)


def read_metrics(run: Path, hint: str = "") -> list[dict]:
    """Every logged row of a run over its attempts, in order: an iteration an interrupted attempt logged and the
    next attempt repeated (the checkpoint was older than the log) counts once, from the later attempt."""
    files = sorted((Path(run) / "csv").glob(f"{PART_PREFIX}*.csv")) + [Path(run) / "csv" / "metrics.csv"]
    rows: list[dict] = []
    for path in (f for f in files if f.is_file()):
        new = read_whole(path, lambda f: list(csv.DictReader(f)), hint=hint)
        first = min((int(r["epoch"]) for r in new if r.get("epoch")), default=None)
        if first is not None:
            rows = [r for r in rows if not r.get("epoch") or int(r["epoch"]) < first]
        rows += new
    return rows


def write_teacher_record(out: Path, ckpt: str | Path) -> None:
    """Which file a distilled run learned from, by content: a shipped name (`pretrained/privileged`) may later point
    to a better teacher, and the run's config.yaml keeps only the name."""
    path = resolve_checkpoint(ckpt)
    env_steps = checkpoint_env_steps(load_checkpoint(path, key="teacher_ckpt"))
    write_json(Path(out) / TEACHER_RECORD, dict(teacher_ckpt=str(ckpt), file=str(path), env_steps=env_steps,
                                                sha256=teacher_sha256(ckpt)))


def teacher_sha256(ckpt: str | Path) -> str:
    """A teacher's identity by content: the sha256 of its file."""
    return hashlib.sha256(resolve_checkpoint(ckpt).read_bytes()).hexdigest()


def check_same_teacher(resume: str | Path, ckpt: str | Path) -> None:
    """Refuse to continue distilled run `resume` (a run directory) with another teacher than the one it learned
    from (its teacher record), e.g. when the default teacher changed between a sweep's sittings: the run would mix
    two teachers' labels."""
    run = Path(resume)
    if not (run / TEACHER_RECORD).is_file():
        return
    record = read_whole(run / TEACHER_RECORD, json.load, "a distilled run's teacher record")
    if teacher_sha256(ckpt) != record.get("sha256"):
        raise ValueError(f"teacher_ckpt={str(ckpt)!r} is not allowed with resume={str(resume)!r}: that run learned from "
                         f"another teacher ({record.get('teacher_ckpt')!r}, {record.get('file')!r}); resume with "
                         f"teacher_ckpt={record.get('teacher_ckpt')}, or start a new run from its weights with init_ckpt=")


def task_name(cfg: dict) -> str:
    """A run's task (insertion, screw, screw_offthread, screw_insert) from its config; runs composed before tasks
    carried their name read it from the config's class and start (an insert-then-screw one as screw_offthread)."""
    task = cfg.get("task") or {}
    if task.get("name"):
        return task["name"]
    family = str(task.get("_target_", "vitac.tasks.insertion")).split(".")[2]
    return "screw_offthread" if task.get("start") == "off_thread" else family


def run_status(run: Path) -> dict:
    """A run directory's (or its archive's) row, seed, task, status (done, partial, missing: no checkpoint yet), completed
    iterations of its budget, env steps, and the checkpoint it was warm-started from (None if it started fresh)."""
    cfg = read_whole(Path(run) / "config.yaml", yaml.safe_load)
    iterations = int(cfg["trainer"]["iterations"])
    if last_checkpoint(run).is_file() or not (Path(run) / ARCHIVE_RECORD).is_file():
        done = completed_iterations(run)
    else:  # an archived run: what its checkpoint held when it was archived
        done = int(read_whole(Path(run) / ARCHIVE_RECORD, json.load, "a run archive's record")["iterations"])
    steps = done * int(cfg["envs"]["num_envs"]) * int(cfg["algo"]["horizon"])
    status = "done" if done >= iterations else "partial" if done else "missing"
    return dict(run=str(run), row=cfg.get("row"), seed=cfg.get("seed"), task=task_name(cfg), status=status,
                iterations=done, budget=iterations, env_steps=steps, init_ckpt=cfg.get("init_ckpt"))


def report_run(out: Path, metrics: dict, env_steps: int, preset: str, wandb: bool) -> dict:
    """Print where a finished run left its checkpoint, metrics, last evaluation video and wandb run; return them."""
    result = dict(metrics=metrics, checkpoint=str(out / "checkpoints" / "last.ckpt"),
                  metrics_csv=str(out / "csv" / "metrics.csv"), wandb=str(out / "wandb") if wandb else None,
                  preset=preset)
    print(f"\nvitac: preset={preset}, {env_steps} env steps, "
          f"success (train episodes) {metrics.get('charts/success_rate', float('nan')):.3f}, "
          f"eval {metrics.get('eval/success_rate', float('nan')):.3f}")
    print(f"  checkpoint: {result['checkpoint']}\n  metrics:    {result['metrics_csv']}")
    videos = sorted((out / "videos").glob("*.mp4"))
    if videos:  # the last evaluation's episode: outside view, wrist camera, both force fields
        print(f"  video:      {videos[-1]}")
    if wandb:
        print(f"  wandb:      {result['wandb']}  (offline; `wandb sync {out}/wandb/offline-run-*` to upload)")
    return result
