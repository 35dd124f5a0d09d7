"""Lint: development vocabulary in the repository's text and file names.

The documents, comments and file names speak of the software. History is told by
dates and commit hashes, never by work numbers (a stop, issue or rung and its number),
working periods (this or the next session) or "today". This script reads every
file git knows of (tracked, and untracked files that are not ignored), skips binary
ones, and prints `path:line: text` for every line that uses such words, and
`path: file name` for a file whose name does. It exits 1 if anything was found.

Usage: python3 tools/lint_vocabulary.py [--root DIR]
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

# The checker and its test must contain the patterns they look for.
SKIPPED = frozenset({"tools/lint_vocabulary.py", "tests/lint/test_vocabulary.py"})

# A number that is a quantity, not a label: "stops" followed by "5 s later" or "2 runs".
_QUANTITY = (
    r"(?![\d.]|\s*(?:s|ms|min|minutes?|seconds?|hours?|%|k|M|times?|runs?|steps?"
    r"|agent|env|updates?|episodes?|trials?)\b)"
)

# (what the words are, the pattern), each matched against one line at a time.
PATTERNS: tuple[tuple[str, re.Pattern[str]], ...] = (
    # "stop" or "Stops" and a label number, a range or two joined by "and"; names like stop31.
    ("work number", re.compile(r"\bstops? #?\d+" + _QUANTITY, re.IGNORECASE)),
    ("work number", re.compile(r"(?<![A-Za-z])stop[-_]?\d+(?![\d.])", re.IGNORECASE)),
    # "issue" or "issues" and a number, "#" and a number, or two joined by "and".
    ("issue number", re.compile(r"\bissues? #?\d+" + _QUANTITY, re.IGNORECASE)),
    # "rung 2", "rungs 3 and 4", "ladder rung", and names like "rung2-seed1.png".
    (
        "ladder rung",
        re.compile(r"\brungs?\b|(?<![A-Za-z])rung[-_ ]?\d", re.IGNORECASE),
    ),
    # A session as a working period; not a gRPC session, a `Session` stream, a pytest
    # fixture's scope or a module named session.
    (
        "working period",
        re.compile(
            r"\b(?:this|next|earlier|previous|last|latest|later|prior|same|that|another|one"
            r"|whole)\s+sessions?\b"
            r"|\bsessions?\s+(?:before|after)\b"
            r"|\bsession's\s+(?:end|machine|time|runs?|figures?)\b"
            r"|\bwith\s+the\s+session\b"
            r"|\bthe\s+session\s+(?:had|ended|was\s+over)\b",
            re.IGNORECASE,
        ),
    ),
    ("today", re.compile(r"\btoday(?:'s)?\b", re.IGNORECASE)),
)


@dataclass(frozen=True)
class Hit:
    """One use of development vocabulary: where it is and what it says."""

    path: str
    line: int  # 0 for the file's name
    kind: str
    text: str

    def __str__(self) -> str:
        if self.line == 0:
            return f"{self.path}: file name ({self.kind})"
        return f"{self.path}:{self.line}: {self.text} ({self.kind})"


def line_hits(text: str) -> list[str]:
    """The kinds of development vocabulary `text` uses, in pattern order, each once."""
    kinds: list[str] = []
    for kind, pattern in PATTERNS:
        if kind not in kinds and pattern.search(text):
            kinds.append(kind)
    return kinds


def scan_text(path: str, text: str) -> Iterator[Hit]:
    """Every line of `text` (the contents of `path`) using development vocabulary."""
    for number, line in enumerate(text.splitlines(), start=1):
        for kind in line_hits(line):
            yield Hit(path, number, kind, line.strip())


def scan_name(path: str) -> Iterator[Hit]:
    """`path` itself (file name and folders), if it uses development vocabulary."""
    for kind in line_hits(path.replace("/", " ")):
        yield Hit(path, 0, kind, path)


def listed_files(root: Path) -> list[str]:
    """The files git knows of under `root`: tracked, and untracked ones not ignored."""
    out = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=root,
        check=True,
        capture_output=True,
    ).stdout
    return sorted({p for p in out.decode().split("\0") if p})


def read_text(file: Path) -> str | None:
    """The file's text, or None when it is binary or gone (deleted, still tracked)."""
    try:
        data = file.read_bytes()
    except (FileNotFoundError, IsADirectoryError):
        return None
    if b"\0" in data[:8192]:
        return None
    return data.decode("utf-8", errors="replace")


def scan(root: Path, paths: Iterable[str]) -> list[Hit]:
    """Every hit in the given repository-relative paths under `root`."""
    hits: list[Hit] = []
    for path in paths:
        if path in SKIPPED:
            continue
        text = read_text(root / path)
        if text is None and not (root / path).exists():
            continue
        hits.extend(scan_name(path))
        if text is not None:
            hits.extend(scan_text(path, text))
    return hits


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    root = Path(__file__).resolve().parent.parent
    parser.add_argument("--root", type=Path, default=root, help="the repository")
    args = parser.parse_args(argv)
    hits = scan(args.root, listed_files(args.root))
    for hit in hits:
        print(hit)
    if hits:
        print(f"{len(hits)} use(s) of development vocabulary", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
