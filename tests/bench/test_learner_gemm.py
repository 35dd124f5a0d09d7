"""A tiny run of bench/learner_gemm.py so that it keeps working; its rates are never asserted
beyond being measured (BENCHMARKS.md has the figures)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "bench" / "learner_gemm.py"


def test_learner_gemm_times_every_shape_in_both_precisions() -> None:
    out = subprocess.run(
        [sys.executable, str(SCRIPT), "--calls", "5", "--json"],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    report = json.loads(out.stdout)
    assert len(report["products"]) == 5 and report["products"][0]["shape"] == [
        512,
        64,
        192,
    ]
    for r in report["products"]:
        assert r["float32_gflops"] > 0 and r["bfloat16_gflops"] > 0
