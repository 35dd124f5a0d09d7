"""A tiny run of the env server's benchmark scripts (bench/env/, also run as `million bench
script NAME`), so that they keep working; the timing itself is never a test (BENCHMARKS.md
has the figures)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[2] / "bench" / "env"


def run_script(name: str, *args: str) -> dict:
    out = subprocess.run(
        [sys.executable, str(BENCHMARKS / name), *args],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    )
    return json.loads(out.stdout)


def test_fast_paths_bench_times_both_codes_per_class() -> None:
    report = run_script(
        "fast_paths.py", "--split", "test", "--steps", "5", "--resets", "2", "--repeats", "1"
    )
    assert report["split"] == "ML10-test"
    assert len(report["per_class"]) == 5
    for figures in report["per_class"].values():
        assert figures["metaworld_us_per_step"] > 0 and figures["fast_paths_us_per_step"] > 0
        assert figures["metaworld_us_per_reset"] > 0 and figures["fast_paths_us_per_reset"] > 0


def test_million_steprate_bench_compares_the_protocol_with_raw_metaworld() -> None:
    report = run_script(
        "million_steprate.py", "--episodes", "1", "--repeats", "1", "--metaworld-reset"
    )
    assert report["fast_reset_speedup_million"] > 0
    assert report["agent_steps"] > 0 and report["env_steps"] > report["agent_steps"]
    assert report["million_agent_steps_per_s"] > 0 and report["raw_metaworld_env_steps_per_s"] > 0
    assert report["unknown_words"] == 0
