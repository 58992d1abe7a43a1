"""The symmetry prior put to the test: every evaluated wrist + tactile run grouped by what the prior's claims depend
on (the task, fusion, `reg.lambda_sym`, `reg.mirror`, `reg.weighting`, `reg.placement`, the training regime, the force-balance penalty, the teacher),
with each configuration's success, force asymmetry and steps per seed and its paired test against the same
configuration without the prior (`lambda_sym = 0`). `python -m vitac.report <dirs>` writes it as symmetry.json and symmetry.png
when the directories hold such runs.
"""

from __future__ import annotations

import json
from pathlib import Path

import yaml

from vitac.analysis.outcomes import mcnemar_exact
from vitac.analysis.table1 import mean_std, summed_discordant
from vitac.run_dirs import EVALUATION, TEACHER_RECORD, task_name
from vitac.utils.records import read_whole

FUSIONS = {"NaiveFusion": "naive", "GatedFusion": "gated", "CrossModalTransformer": "cmt"}
KEY = ("task", "fusion", "lambda_sym", "mirror", "weighting", "placement", "regime", "balance_penalty", "teacher")


def regime(cfg: dict) -> str:
    """How the run trained: dagger, ppo, or the fine-tune of a distilled student (aacd, kickstart, residual)."""
    algo = cfg["algo"]["_target_"]
    if algo.endswith("DAgger"):
        return "dagger"
    if (cfg.get("residual") or {}).get("_target_"):
        return "residual"
    if algo.endswith("KickstartPPO"):
        return "kickstart"
    return "aacd" if cfg.get("init_ckpt") and cfg.get("critic_ckpt") else "ppo"


def cell(status: dict, min_episodes: int) -> dict | None:
    """One run's configuration and its evaluation (`status`: its run_status()), or None if it is no evaluated
    wrist + tactile fusion run."""
    run = Path(status["run"])
    cfg = read_whole(run / "config.yaml", yaml.safe_load, "a run's config.yaml")
    modalities = set((cfg.get("obs") or {}).get("modalities", []))
    fusion = FUSIONS.get(str((cfg.get("fusion") or {}).get("_target_", "")).rsplit(".", 1)[-1])
    if fusion is None or not {"wrist", "tactile_left", "tactile_right"} <= modalities or not (run / EVALUATION).is_file():
        return None
    report = read_whole(run / EVALUATION, json.load, "a vitac.evaluate report")
    if report["episodes"] < min_episodes:
        return None
    teacher = teacher_name = None
    if (run / TEACHER_RECORD).is_file():  # by content; the name it was given is for the figure's legend
        record = read_whole(run / TEACHER_RECORD, json.load, "a distilled run's teacher record")
        teacher, teacher_name = record["sha256"][:8], Path(str(record.get("teacher_ckpt", ""))).stem or None
    elif cfg.get("critic_ckpt"):  # a fine-tune: its teacher is the critic's
        teacher = str(cfg["critic_ckpt"])
    balance = [e["field_contact"] for e in report.get("force_balance") or [] if e and e.get("field_contact") is not None]
    lambda_sym = float(cfg["reg"].get("lambda_sym", 0.0))
    return dict(task=task_name(cfg), fusion=fusion, lambda_sym=lambda_sym, mirror=cfg["reg"].get("mirror", "physical"),
                weighting=cfg["reg"].get("weighting", "absolute") if lambda_sym else "absolute",
                placement=cfg["reg"].get("placement", "encoder") if lambda_sym else "encoder", regime=regime(cfg),
                balance_penalty=float(cfg["task"].get("balance_penalty_scale", 0.0)), teacher=teacher,
                teacher_name=teacher_name,
                seed=cfg.get("seed"), run=str(run), env_steps=status["env_steps"], eval_seed=report["seed"],
                success=report["success_rate"], episode_success=report["episode_success"],
                steps_to_success=report.get("steps_to_success_mean"),
                field_asymmetry_in_contact=sum(balance) / len(balance) if balance else None)


def configurations(statuses: list[dict], min_episodes: int = 400) -> list[dict]:
    """Every configuration among the runs of `statuses` (analysis.status.run_statuses: one scan of the directories),
    its seeds' results, and its paired test against its lambda_sym = 0 twin (the same configuration otherwise, on
    the seeds and held-out episodes both have)."""
    cells = [c for status in statuses if (c := cell(status, min_episodes))]
    groups: dict[tuple, list[dict]] = {}
    for c in cells:
        groups.setdefault(tuple(c[k] for k in KEY), []).append(c)
    results = []
    for key, members in sorted(groups.items(), key=lambda kv: tuple(str(v) for v in kv[0])):
        members.sort(key=lambda c: (c["seed"] is None, c["seed"]))
        successes = [100 * c["success"] for c in members]
        mean, std = mean_std(successes)
        asym = [c["field_asymmetry_in_contact"] for c in members if c["field_asymmetry_in_contact"] is not None]
        results.append(dict(zip(KEY, key, strict=True), teacher_name=members[0]["teacher_name"], seeds=[c["seed"] for c in members], success=successes,
                            mean=mean, std=std, field_asymmetry_in_contact=[c["field_asymmetry_in_contact"] for c in members],
                            mean_field_asymmetry=mean_std(asym)[0],
                            steps_to_success=[c["steps_to_success"] for c in members],
                            env_steps=[c["env_steps"] for c in members], runs=[c["run"] for c in members],
                            against_lambda_0=_paired(members, groups.get(_twin(key, "lambda_sym"))),
                            against_no_penalty=_paired(members, groups.get(_twin(key, "balance_penalty")),
                                                       "balance_penalty")))
    return results


def _twin(key: tuple, setting: str) -> tuple:
    """The same configuration with `setting` (the prior's weight or the balance penalty) at 0 (at weight 0, how
    the weight is read and where do not matter: "absolute", "encoder")."""
    off = {setting: 0.0} | ({"weighting": "absolute", "placement": "encoder"} if setting == "lambda_sym" else {})
    return tuple(off.get(name, value) for name, value in zip(KEY, key, strict=True))


def _paired(members: list[dict], twins: list[dict] | None, setting: str = "lambda_sym") -> dict | None:
    """Exact McNemar, summed over the seeds both have (same held-out episodes): with `setting` on against off."""
    if not twins or members[0][setting] == 0:
        return None
    by_seed = {c["seed"]: c for c in twins}
    only_with, only_without, episodes = summed_discordant((c, by_seed[c["seed"]]) for c in members if c["seed"] in by_seed)
    if not episodes:
        return None
    return dict(episodes=episodes, only_with=only_with, only_without=only_without,
                p=mcnemar_exact(only_with, only_without))


def figure(results: list[dict], path: Path) -> Path:
    """Success and field asymmetry in contact against lambda_sym, one line per configuration family, a dot a seed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax_asym) = plt.subplots(1, 2, figsize=(11.5, 5))
    families: dict[tuple, list[dict]] = {}
    for r in results:
        families.setdefault(tuple(r[k] for k in KEY if k != "lambda_sym"), []).append(r)
    for i, (family, members) in enumerate(sorted(families.items(), key=lambda kv: str(kv[0]))):
        members.sort(key=lambda r: r["lambda_sym"])
        task, fusion, mirror, weighting, placement, how, balance, teacher = family
        teacher = f"{members[0].get('teacher_name')} ({teacher})" if members[0].get("teacher_name") else teacher
        label = (f"{task}: {fusion}, {mirror} mirror" + (", weight relative" if weighting == "relative" else "")
                 + (", after self-attention" if placement == "self_attention" else "")
                 + f", {how}" + (f", balance {balance}" if balance else "") + f", teacher {teacher}")
        lambdas = [r["lambda_sym"] for r in members]
        ax.plot(lambdas, [r["mean"] for r in members], "o-", color=f"C{i}", label=label)
        for r in members:
            ax.scatter([r["lambda_sym"]] * len(r["success"]), r["success"], color=f"C{i}", s=8, alpha=0.5)
        asym = [(r["lambda_sym"], r["mean_field_asymmetry"]) for r in members if r["mean_field_asymmetry"] is not None]
        if asym:
            ax_asym.plot(*zip(*asym, strict=True), "o-", color=f"C{i}")
    for a in (ax, ax_asym):
        a.set_xscale("symlog", linthresh=0.01)
        a.set_xlabel("lambda_sym")
    ax.set(ylabel="held-out success (%)", title="success against the prior's weight (dots: seeds)")
    # the measure's whole range: a difference in the third decimal must not fill the panel
    ax_asym.set(ylabel="field asymmetry in contact", title="0 balanced, 1 one pad alone", ylim=(0, 1))
    fig.legend(*ax.get_legend_handles_labels(), loc="lower center", ncol=2, fontsize=6.5)  # below both panels
    fig.tight_layout(rect=(0, 0.05 + 0.03 * ((len(families) + 1) // 2), 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
