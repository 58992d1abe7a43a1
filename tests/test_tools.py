"""The command-line tools around training: benchmark records, plots, run summaries (outcomes: test_outcomes_cli.py)."""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import CONF
from vitac.envs.gym_env import TaskEnv
from vitac.utils.records import describe_cpu, write_json, write_record

ROOT = Path(CONF).parent


def _benchmark(name: str):
    """A script of benchmarks/ as a module (benchmarks/ is not a package)."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_benchmark_records_carry_the_command_that_reproduces_them(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["/somewhere/benchmarks/bench_train.py", "--only", "privileged", "algo.lr=1e-5"])
    monkeypatch.setattr("vitac.utils.records.describe_cpu", lambda: {"model": "some CPU", "cores": 2, "bfloat16": []})
    write_record(tmp_path / "new" / "record.json", rows=[{"env_steps_per_s": 1.0}], threads=2)
    assert json.loads((tmp_path / "new" / "record.json").read_text()) == {
        "rows": [{"env_steps_per_s": 1.0}], "threads": 2,
        "command": "python benchmarks/bench_train.py --only privileged algo.lr=1e-5",
        "cpu": {"model": "some CPU", "cores": 2, "bfloat16": []}}


def test_records_name_the_cpu_they_were_measured_on(tmp_path):
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("processor\t: 0\nmodel name\t: Intel(R) Xeon(R) Processor\n"
                       "flags\t\t: fpu avx512f avx512_bf16 amx_tile amx_bf16\n\nprocessor\t: 1\n")
    cpu = describe_cpu(cpuinfo)
    assert cpu["model"] == "Intel(R) Xeon(R) Processor" and cpu["bfloat16"] == ["amx_bf16", "avx512_bf16"]
    assert cpu["cores"] == len(os.sched_getaffinity(0))
    assert describe_cpu(tmp_path / "missing")["bfloat16"] == []  # no /proc/cpuinfo: still a record


def test_a_json_record_replaces_its_file_only_once_written_whole(tmp_path, monkeypatch):
    target = tmp_path / "last.eval.json"
    write_json(target, {"success_rate": 0.5})
    assert json.loads(target.read_text()) == {"success_rate": 0.5}

    def crash(src, dst):  # the process dies after writing the new report, before it takes the old one's place
        raise OSError("killed")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(OSError, match="killed"):
        write_json(target, {"success_rate": 0.9, "final_peg": [{"outcome": "inserted"}] * 1000})
    assert json.loads(target.read_text()) == {"success_rate": 0.5}  # the previous report, whole
    assert [p.name for p in tmp_path.iterdir()] == ["last.eval.json"]  # and no temporary file left behind


def test_reports_and_checkpoints_get_the_permissions_of_a_plainly_created_file(tmp_path):
    from vitac.utils.checkpoint import PortableCheckpointIO

    umask = os.umask(0o027)
    try:
        write_json(tmp_path / "report.json", {"success_rate": 0.5})
        PortableCheckpointIO().save_checkpoint({"state_dict": {}}, tmp_path / "last.ckpt")
        (tmp_path / "plain.txt").write_text("")
    finally:
        os.umask(umask)
    modes = {p.name: p.stat().st_mode & 0o777 for p in tmp_path.iterdir()}
    assert modes == {"report.json": 0o640, "last.ckpt": 0o640, "plain.txt": 0o640}  # mkstemp alone gives 0o600


def test_bench_physics_meter_counts_every_substep_and_restores_the_methods_it_patches():
    from vitac.tasks.insertion.task import InsertionTask

    bench = _benchmark("bench_physics")
    original_step, original_forces = InsertionTask.step_physics, InsertionTask._contact_forces
    env = TaskEnv({"observations": bench.OBSERVATIONS}, seed=0)
    env.reset(seed=0)
    meter = bench.PhysicsMeter()
    try:
        for _ in range(3):
            assert np.any(env.step(np.zeros(6))[0]["critic_state"] != 0)
    finally:
        meter.close()
        env.close()
    totals = meter.totals
    assert totals["calls"] == 3 and totals["substeps"] == 3 * env.task.physics_steps_per_control_step
    assert totals["contact_force_calls"] == 0  # the critic state's contact forces come from the last substep
    assert totals["collision"] > 0 and totals["constraint_solve"] > 0 and totals["contacts"] > 0
    assert InsertionTask.step_physics is original_step and InsertionTask._contact_forces is original_forces


def test_bench_env_oracle_driver_finishes_episodes_that_random_actions_do_not():
    bench = _benchmark("bench_env")
    oracle = bench.single_env(400, "screw_offthread", driver="oracle")
    random = bench.single_env(400, "screw_offthread", driver="random")
    # the oracle threads the nut on in about 140 steps, each episode ends on success; random actions end theirs
    # by dropping or leaving the nut
    assert oracle["driver"] == "oracle" and oracle["successes"] == oracle["resets_included"] >= 2
    assert random["successes"] == 0
    assert oracle["mean_contacts"] > random["mean_contacts"]  # the threads pressed together, as a trained policy does


def test_bench_physics_applies_mujoco_options_and_refuses_unknown_ones():
    import mujoco

    bench = _benchmark("bench_physics")
    env = TaskEnv({"observations": bench.OBSERVATIONS}, seed=0)
    env.reset(seed=0)
    meter = bench.PhysicsMeter(bench.parse_options(["cone=0", "tolerance=1e-6"]), bench.parse_disable(["MULTICCD"]))
    try:
        env.step(np.zeros(6))
    finally:
        meter.close()
    opt = env.physics.model.opt
    assert opt.cone == 0 and opt.tolerance == 1e-6 and opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_MULTICCD)
    env.close()
    for bad in ("gravity=1", "cone", "no_such_field=2"):
        with pytest.raises(SystemExit, match="is not allowed"):
            bench.parse_options([bad])
    with pytest.raises(SystemExit, match="is not allowed"):
        bench.parse_disable(["NO_SUCH_FLAG"])


def test_plot_run_places_a_warm_started_segment_after_the_previous_one_and_a_resumed_one_where_it_is(tmp_path):
    from vitac.analysis import curves as plot_run

    def write(name, steps):
        path = tmp_path / name
        path.write_text("charts/env_steps,charts/success_rate\n" + "".join(f"{s},0.5\n" for s in steps))
        return path

    first, resumed, warm = write("a.csv", [100, 200]), write("b.csv", [300, 400]), write("c.csv", [50, 150])
    rows, starts = plot_run.read_segments([first, resumed, warm])
    assert [float(r["charts/env_steps"]) for r in rows] == [100, 200, 300, 400, 450, 550]
    assert starts == [300, 450]
    rows, starts = plot_run.read_segments([first, resumed, warm], max_steps=400)  # one budget for every run
    assert [float(r["charts/env_steps"]) for r in rows] == [100, 200, 300, 400] and starts == [300]
    with pytest.raises(SystemExit, match="no rows up to 50 env steps"):
        plot_run.read_segments([first], max_steps=50)
    # `vitac.runs summary` reads segments the same way; the figures docs/results.md quotes for one segment:
    summary = subprocess.run([sys.executable, "-m", "vitac.runs", "summary",
                              "docs/data/results/privileged_cpu_shaped_bigbatch_metrics.csv"], check=True, cwd=ROOT,
                             capture_output=True, text=True).stdout.splitlines()
    assert summary[0] == "env steps: 9,576,448 -> 10,496,000 (450 iterations)"
    assert summary[1] == "median env steps/s: 1028; 0.25 hours of training"
    assert "overall 75%" in summary[5]
    assert summary[-2].startswith("learning rate range: ") and summary[-1].startswith("explained variance: first ")
    cut = subprocess.run([sys.executable, "-m", "vitac.runs", "summary", "--max-steps", "1e7",
                          "docs/data/results/privileged_cpu_shaped_bigbatch_metrics.csv"], check=True, cwd=ROOT,
                         capture_output=True, text=True).stdout.splitlines()
    assert cut[0] == "env steps: 9,576,448 -> 9,998,336 (207 iterations)"  # 2,048 env steps an iteration


def test_run_summary_names_the_columns_an_older_run_did_not_log_and_refuses_a_foreign_csv(tmp_path):
    older = tmp_path / "older.csv"
    older.write_text("charts/env_steps,charts/SPS,losses/loss,losses/approx_kl,losses/entropy,charts/success_rate\n"
                     "1000,900,0.1,0.02,3.0,0.25\n2000,1100,0.1,0.04,2.9,0.75\n")
    summary = subprocess.run([sys.executable, "-m", "vitac.runs", "summary", str(older)], check=True, cwd=ROOT,
                             capture_output=True, text=True).stdout.splitlines()
    assert summary[:2] == ["env steps: 1,000 -> 2,000 (2 iterations)", "median env steps/s: 1000; 0.00 hours of training"]
    assert summary[2] == "learning rate: not logged by this run (another algorithm or an older version)"
    assert summary[-1] == "explained variance: not logged by this run (another algorithm or an older version)"
    # a distillation run: no PPO statistics, its action error to the teacher instead
    dagger = subprocess.run([sys.executable, "-m", "vitac.runs", "summary",
                             "docs/data/results/dagger_privileged_metrics.csv"], check=True, cwd=ROOT,
                            capture_output=True, text=True).stdout
    assert "median approx KL: not logged by this run" in dagger
    assert "action error to the teacher (MSE per dimension, mean of 8 iterations): first 0.209, last 0.012" in dagger
    foreign = tmp_path / "foreign.csv"
    foreign.write_text("a,b\n1,2\n")
    result = subprocess.run([sys.executable, "-m", "vitac.runs", "summary", str(foreign)], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode != 0 and "not a vitac metrics CSV" in result.stderr


@pytest.mark.parametrize("command,message", [
    (["benchmarks/bench_train.py", "--iterations", "1"], "argument --iterations: 1 is not allowed: expected an integer >= 2"),
    (["-m", "vitac.runs", "log-std", "x.ckpt", "--episodes", "0"],
     "argument --episodes: 0 is not allowed: expected an integer >= 1"),
    (["benchmarks/bench_env.py", "--steps", "many"], "argument --steps: 'many' is not an integer"),
    (["benchmarks/compare.py", "--base", "no-such-commit"],
     "argument --base: 'no-such-commit' is not allowed: not a commit of this repository"),
    (["-m", "vitac.runs", "summary", "x.csv", "--window", "0"],
     "argument --window: 0.0 is not allowed: expected a number > 0"),
    (["benchmarks/bench_update.py", "--json", "README.md/bench.json"],
     "argument --json: README.md/bench.json is not allowed: the folder README.md cannot be created or written"),
    (["-m", "vitac.export", "x.ckpt", "--out", "docs"], "argument --out: docs is not allowed: it is a directory"),
    (["-m", "vitac.runs", "plot", "x.csv", "--out", "README.md/curves.png"], "argument --out: README.md/curves.png is"),
    (["-m", "vitac.report", "docs/data/table1_runs", "--out", "README.md/report", "--evaluate"],
     "argument --out: README.md/report is not allowed: the folder README.md/report cannot be created or written"),
    (["-m", "vitac.report", "docs/data/table1_runs", "--unseen"],
     "argument --unseen: it is not allowed without --evaluate"),
    (["-m", "vitac.report", "docs/data/table1_runs", "--evaluate", "--qual", "Naive"],
     "argument --qual: 'Naive' is not allowed: expected NAME=CKPT"),
    (["-m", "vitac.report", "docs/data/table1_runs", "--evaluate", "--qual", "Naive=missing.ckpt"],
     "argument --qual: 'Naive=missing.ckpt' is not allowed: missing.ckpt is no checkpoint file"),
])
def test_tools_refuse_a_bad_argument_naming_the_flag_before_any_work(command, message):
    result = subprocess.run([sys.executable, *command], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and message in result.stderr and result.stdout == ""


def test_compare_runs_the_benchmarks_of_a_base_commit_and_of_the_working_tree_and_removes_its_worktree(tmp_path):
    out = tmp_path / "compare.json"
    subprocess.run([sys.executable, "benchmarks/compare.py", "--base", "HEAD", "--steps", "20", "--passes", "2",
                    "--rounds", "1", "--json", str(out)], cwd=ROOT, check=True, capture_output=True, timeout=600)
    record = json.loads(out.read_text())
    figures = record["figures"]
    assert {"steps_per_s", "tactile_ms", "cmt_latency_ms", "naive_latency_b256_ms"} <= figures.keys()
    for f in figures.values():
        assert f["base"] > 0 and f["head"] > 0 and f["head_vs_base"] > 0
    assert len(record["per_round"]["base"]) == len(record["per_round"]["head"]) == 1
    worktrees = subprocess.run(["git", "worktree", "list"], cwd=ROOT, capture_output=True, text=True).stdout
    assert "vitac-compare-" not in worktrees


def test_bench_physics_refuses_a_missing_checkpoint_before_its_scripted_drivers_run(tmp_path):
    # 1,000 episodes of each scripted driver would outlast the timeout: the checkpoint is read first.
    result = subprocess.run([sys.executable, "benchmarks/bench_physics.py", "--episodes", "1000", "--ckpt",
                             str(tmp_path / "missing.ckpt")], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and "missing.ckpt': no such checkpoint file" in result.stderr
    assert "Traceback" not in result.stderr and result.stdout == ""


def test_plot_and_summary_tools_refuse_a_file_that_is_not_a_metrics_csv_naming_it(tmp_path):
    from vitac.analysis.curves import read_segments

    good = tmp_path / "good.csv"
    good.write_text("charts/env_steps,charts/success_rate\n1000,0.5\n")
    foreign, header_only, binary = tmp_path / "foreign.csv", tmp_path / "header.csv", tmp_path / "binary.csv"
    foreign.write_text("a,b\n1,2\n")
    header_only.write_text("charts/env_steps,charts/success_rate\n")
    binary.write_bytes(b"\x80\x81\xfe\xff" * 64)
    for bad, reason in ((foreign, "not a vitac metrics CSV"), (header_only, "not a vitac metrics CSV"),
                        (binary, "cannot be read as a metrics CSV"), (tmp_path / "missing.csv", "cannot be read")):
        with pytest.raises(SystemExit, match=f"{bad.name}: .*{reason}"):
            read_segments([good, bad])  # the bad one named, even after a good segment
    plot = subprocess.run([sys.executable, "-m", "vitac.runs", "plot", str(foreign), "--out", str(tmp_path / "p.png")],
                          cwd=ROOT, capture_output=True, text=True)
    assert plot.returncode != 0 and "not a vitac metrics CSV" in plot.stderr and not (tmp_path / "p.png").exists()


@pytest.mark.parametrize("args", [
    ["-m", "vitac.runs", "summary", "docs/data/results/privileged_32envs_seed1_metrics.csv"],
    ["-m", "vitac.runs", "outcomes", "docs/data/results/privileged_32envs_seed1_eval_paper.json"],
])
def test_printing_tools_stop_quietly_when_their_reader_has_gone(args):
    # `tool ... | head`: the reader closes early. Here it is gone before the tool writes at all.
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        tool = subprocess.run([sys.executable, *args], cwd=ROOT, stdout=write_end, stderr=subprocess.PIPE, text=True)
    finally:
        os.close(write_end)
    assert "BrokenPipeError" not in tool.stderr and "Traceback" not in tool.stderr, tool.stderr
    assert tool.returncode == -signal.SIGPIPE  # ended by the signal, as `head`'s other writers are


def test_runs_help_lists_every_command_and_an_unknown_command_names_the_allowed_ones(capsys):
    from vitac import runs

    runs.main(["--help"])  # returns: help is not an error
    listed = capsys.readouterr().out
    assert all(f"python -m vitac.runs {name}" in listed for name in runs.COMMANDS)
    with pytest.raises(SystemExit) as refused:
        runs.main(["plott"])
    assert "command='plott' is not allowed" in str(refused.value) and "'plot'" in str(refused.value)


def test_export_refuses_a_missing_or_corrupt_checkpoint_by_name_and_keeps_the_shipped_file_whole(tmp_path,
                                                                                                   monkeypatch):
    import torch

    from vitac import export

    shipped = tmp_path / "p.pt"
    shipped.write_bytes(b"the previous export")
    with pytest.raises(SystemExit, match="no such checkpoint file"):
        export.main([str(tmp_path / "missing.ckpt"), "--out", str(shipped)])
    (tmp_path / "torn.ckpt").write_bytes(b"PK\x03\x04 half a zip")
    with pytest.raises(SystemExit, match="torn.ckpt.* is not a readable vitac checkpoint"):
        export.main([str(tmp_path / "torn.ckpt"), "--out", str(shipped)])
    checkpoint = tmp_path / "last.ckpt"
    torch.save({"vitac_config": {}, "state_dict": {"policy.w": torch.ones(3)}, "vitac": {"env_steps": 5}}, checkpoint)

    def killed(obj, f):  # the process dies halfway through writing the new file
        Path(f).write_bytes(b"half")
        raise OSError("killed")

    monkeypatch.setattr(torch, "save", killed)
    with pytest.raises(SystemExit, match="killed"):
        export.main([str(checkpoint), "--out", str(shipped)])
    assert shipped.read_bytes() == b"the previous export" and [p.name for p in tmp_path.glob("*p.pt*")] == ["p.pt"]
    monkeypatch.undo()
    export.main([str(checkpoint), "--out", str(shipped)])
    assert torch.load(shipped, weights_only=True)["env_steps"] == 5


@pytest.mark.parametrize("tool, flag", [("vitac.analysis.log_std", []), ("vitac.video", ["--ckpt"])])
def test_tools_reading_a_policy_refuse_a_missing_or_corrupt_checkpoint_in_one_line(tmp_path, tool, flag):
    main = importlib.import_module(tool).main
    with pytest.raises(SystemExit, match=r"missing.ckpt'?: no such checkpoint file"):
        main([*flag, str(tmp_path / "missing.ckpt")])
    (tmp_path / "torn.ckpt").write_bytes(b"PK\x03\x04 half a zip")
    with pytest.raises(SystemExit, match="torn.ckpt.* is not a readable vitac checkpoint"):
        main([*flag, str(tmp_path / "torn.ckpt")])


def test_no_benchmark_script_imports_an_entry_point_module():
    import ast

    entry_points = {"vitac.train", "vitac.evaluate", "vitac.report", "vitac.runs", "vitac.export", "vitac.video"}
    for script in (ROOT / "benchmarks").glob("*.py"):
        for node in ast.walk(ast.parse(script.read_text())):
            names = [node.module] if isinstance(node, ast.ImportFrom) else [
                a.name for a in node.names] if isinstance(node, ast.Import) else []
            assert not set(names) & entry_points, f"{script.name} imports {names}: import the library module instead"
