"""The README's commands stay true: CI runs exactly the README's test command."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ci_runs_the_readme_test_command():
    ci_command = [line for line in (ROOT / ".ci" / "run").read_text().splitlines() if "pytest" in line]
    assert len(ci_command) == 1
    assert f"    {ci_command[0].strip()}" in (ROOT / "README.md").read_text().splitlines()


def test_readme_main_command_is_the_default_train_entry_point():
    assert "    pip install -e . && python -m vitac.train" in (ROOT / "README.md").read_text().splitlines()


def _pages() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "docs" / "notes").glob("*.md"))]


def test_docs_cite_existing_files():
    """Every path under docs/ a page names (data, figures, other pages) exists, so moving a file breaks a test."""
    for doc in _pages():
        for token in doc.read_text().replace("](", " ").split():
            token = token.strip("`()[],.:;\"'*")
            if token.startswith("docs/") and "<" not in token:
                found = list(ROOT.glob(token)) if "*" in token else [ROOT / token]
                assert found and all(f.exists() for f in found), f"{doc.name} cites missing {token}"


def test_docs_links_resolve():
    import re

    for doc in _pages():
        for target in re.findall(r"\]\(([^)\s]+)\)", doc.read_text()):
            if not target.startswith(("http://", "https://", "#")):
                assert (doc.parent / target.split("#")[0]).exists(), f"{doc.name} links to missing {target}"


def test_ruff_passes():
    import subprocess
    import sys

    result = subprocess.run([sys.executable, "-m", "ruff", "check", "vitac", "benchmarks", "tests"], cwd=ROOT,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def _results_table_rows() -> dict[str, list[str]]:
    """{row label: its cells} of docs/results.md's Table I (the first table of the page)."""
    lines = (ROOT / "docs" / "results.md").read_text().split("## Table I", 1)[1].split("\n\n", 2)[1].splitlines()
    return {cells[0]: cells for cells in ([c.strip() for c in line.strip("|").split("|")] for line in lines[2:])}


def test_results_page_shows_table_one_as_the_report_wrote_it():
    """Each row of docs/results.md's Table I carries docs/data/table1.json's per-seed successes, mean and seed count,
    so a hand edit cannot drift from the report (`python -m vitac.report docs/data/table1_runs`)."""
    import json

    rows = _results_table_rows()
    for row in json.loads((ROOT / "docs" / "data" / "table1.json").read_text())["rows"]:
        label = row["row"].split(" (lambda_sym")[0]
        [cells] = [cells for name, cells in rows.items() if name == label or name.startswith(f"{label} (shipped")]
        done = [s for s in row["seeds"].values() if s["status"] == "done" and s.get("success") is not None]
        assert cells[3] == str(row["seeds_counted"]) == str(len(done)), label
        ours = cells[2].strip("*")
        for seed in done:
            assert f"{100 * seed['success']:.1f}%" in ours, (label, seed["seed"], ours)
        if len(done) > 1:
            assert ours.startswith(f"{row['mean']:.2f} ± {row['std']:.2f}:"), (label, ours)


def test_results_page_shows_the_97_percent_teachers_table_as_the_report_wrote_it():
    """Every sensing row of docs/results.md's table of the 97% teacher's students (the privileged rows are the
    teachers) is versus_markdown() of the committed docs/data/versus_97_teacher.json, so a row pasted by hand after a
    new cell cannot drift from the data."""
    import json

    from vitac.analysis.table1 import ROWS, versus_markdown

    inputs = {r.label: r.inputs for r in ROWS}
    committed = json.loads((ROOT / "docs" / "data" / "versus_97_teacher.json").read_text())
    sensing = [row for row in committed["rows"] if "P" not in inputs[row["row"]]]
    page = (ROOT / "docs" / "results.md").read_text().splitlines()
    for line in versus_markdown(sensing).splitlines():
        assert line in page, f"docs/results.md lacks the report's row: {line}"


def test_docs_name_dates_and_machines_not_sessions():
    import re

    for doc in [*_pages(), ROOT / "docs" / "data" / "results" / "README.md"]:
        for n, line in enumerate(doc.read_text().splitlines(), 1):
            assert not re.search(r"\b(sessions?|sittings?)\b", line, re.I), f"{doc.name}:{n}: {line.strip()}"
