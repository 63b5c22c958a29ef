"""The documents stay short, factual and in step with the parser."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# A work session or a scratch path is never the reason for a behaviour (git log keeps the history).
HISTORY = re.compile(r"sessions? [0-9]+|/tmp/", re.IGNORECASE)


def _gen_cli():
    spec = importlib.util.spec_from_file_location("gen_cli", ROOT / "docs" / "gen_cli.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_cli_reference_matches_the_parser():
    committed = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    fresh = _gen_cli().generate()
    assert "## `nerfkit train`" in fresh and "usage: nerfkit train" in fresh
    assert fresh == committed, "docs/cli.md is out of date with the parser: run python docs/gen_cli.py"


@pytest.mark.parametrize(("name", "limit"), [("README.md", 250), ("BENCHMARKS.md", 600)])
def test_documents_stay_short(name, limit):
    lines = (ROOT / name).read_text(encoding="utf-8").count("\n")
    assert lines < limit, f"{name} has {lines} lines (under {limit}): move depth into docs/"


def _texts():
    files = [ROOT / "README.md", ROOT / "BENCHMARKS.md"]
    files += sorted((ROOT / "docs").rglob("*.md")) + sorted((ROOT / "docs").rglob("*.py"))
    files += sorted((ROOT / "src").rglob("*.py"))
    return files


def test_no_work_sessions_or_scratch_paths():
    found = []
    for path in _texts():
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if HISTORY.search(line):
                found.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert not found, "say what the behaviour does and link the benchmark instead:\n" + "\n".join(found)


def test_the_pattern_finds_what_it_should():
    assert HISTORY.search("BENCHMARKS.md, Session 48") and HISTORY.search("sessions 21 and 23")
    assert HISTORY.search("--work /tmp/cr") and not HISTORY.search("a session's lock, tmp files")
