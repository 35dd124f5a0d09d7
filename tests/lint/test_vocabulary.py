"""tools/lint_vocabulary.py: what it flags, what it leaves alone, its exit status."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _load() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "lint_vocabulary", ROOT / "tools" / "lint_vocabulary.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


lint = _load()


# The samples write the space of each flagged phrase as \x20, so that this file's source
# holds no hit of its own for a checker that reads it as text.
@pytest.mark.parametrize(
    ("line", "kind"),
    [
        ("Stop\x2031, `million bench learning` (seed 2, 30 min)", "work number"),
        ("the check stop\x2031 asked for", "work number"),
        ("Stops\x2027-29 (five runs) each learned a subset", "work number"),
        ("stops\x2027\u201329 left it open", "work number"),
        ("as in stops\x2024 and 33", "work number"),
        ("docs/learning/rung3-stop31-maps.png", "work number"),
        ("the earlier 0.8x (issue\x209) is gone", "issue number"),
        ("see issue\x20#12", "issue number"),
        ("Rung\x202's config is now", "ladder rung"),
        ("on rungs\x203 and 4", "ladder rung"),
        ("the floor every ladder rung must beat", "ladder rung"),
        ("docs/learning/rung2-seed1-ablation.png", "ladder rung"),
        ("the served rung-2 run", "ladder rung"),
        ("rerun this\x20session (same code)", "working period"),
        ("the next\x20session will tell", "working period"),
        ("found in an earlier\x20session", "working period"),
        ("the pair of the session before", "working period"),
        ("stopped by the session's end", "working period"),
        ("the run directory went with the session", "working period"),
        ("status (latest\x20session)", "working period"),
        ("this machine was faster today", "today"),
        ("most of today's margin is the machine", "today"),
    ],
)
def test_flags_development_vocabulary(line: str, kind: str) -> None:
    assert kind in lint.line_hits(line)


@pytest.mark.parametrize(
    "line",
    [
        "the run stops at the target success and prints a summary",
        "Ctrl-C stops with a final checkpoint",
        "stop_at_success = 0.95",
        "the run stops\x205 s after the signal",
        "stops\x202 runs at once",
        "success stops\x200.95 short",
        "`Session` bidirectional stream of resets/steps",
        "one gRPC session per pool shard",
        "a pool's session is reopened on the rebuilt server",
        "@pytest.fixture(scope='session')",
        "agent/env-client/src/session.rs",
        "use crate::train::session::{TrainOptions, train};",
        "tokio runs the actor loop; the learner thread stops when told",
        "configs/ladder/2-ml1-reach.toml",
        "bash bench/gpu/ladder.sh OUT 470",
        "the issue is that the buffer mixes actor versions",
        "a trial ends when its 200 env steps are up",
        "docs/experiments/2026-12-04-bench-learning.md",
    ],
)
def test_leaves_legitimate_uses_alone(line: str) -> None:
    assert lint.line_hits(line) == []


def test_scan_reports_lines_and_file_names(tmp_path: Path) -> None:
    (tmp_path / "notes.md").write_text("fine\nthis\x20session's runs\nfine again\n")
    (tmp_path / "rung2-curve.png").write_bytes(b"\x89PNG\0\0\0")
    (tmp_path / "clean.md").write_text("The run stops at 0.95.\n")
    hits = lint.scan(tmp_path, ["notes.md", "rung2-curve.png", "clean.md", "gone.md"])
    assert [str(h) for h in hits] == [
        "notes.md:2: this\x20session's runs (working period)",
        "rung2-curve.png: file name (ladder rung)",
    ]


def test_skips_itself_and_its_test(tmp_path: Path) -> None:
    for path in lint.SKIPPED:
        (tmp_path / path).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / path).write_text(
            "stop\x2031, issue\x208, rung\x202, this\x20session, today\n"
        )
    assert lint.scan(tmp_path, sorted(lint.SKIPPED)) == []


def test_exit_status(tmp_path: Path) -> None:
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    (tmp_path / "README.md").write_text("A clean document.\n")
    assert lint.main(["--root", str(tmp_path)]) == 0
    (tmp_path / "LOG.md").write_text("Measured today.\n")
    assert lint.main(["--root", str(tmp_path)]) == 1
