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


def test_docs_cite_existing_data_files():
    for doc in (ROOT / "docs").glob("*.md"):
        for token in doc.read_text().split():
            token = token.strip("`(),.:;")
            if token.startswith("docs/data/") or token.startswith("docs/media/"):
                found = list(ROOT.glob(token)) if "*" in token else [ROOT / token]
                assert found and all(f.exists() for f in found), f"{doc.name} cites missing {token}"


def test_ruff_passes():
    import subprocess
    import sys

    result = subprocess.run([sys.executable, "-m", "ruff", "check", "vitac", "benchmarks", "tests"], cwd=ROOT,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
