"""experiments/intersample.py end to end on one short record.

The full study (seeds 1-5, 240 resonance periods) is in ``docs/measuring.md``; here one
short record checks that the script runs, writes its JSON, and that the first-order hold
beats the zero-order one on a continuous input with the loop's signature present.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


@pytest.mark.slow
def test_the_experiment_script_runs_small(tmp_path, repo_root) -> None:
    out = tmp_path / "study.json"
    proc = subprocess.run([sys.executable, str(repo_root / "experiments" / "intersample.py"),
                           "--seeds", "3", "--periods", "80", "--pop", "8", "--iters", "6",
                           "--json", str(out)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    fits = json.loads(out.read_text())["results"][0]["records"]["cubic"]["fits"]
    assert fits["cubic/foh"]["test_rmse"] < 0.5 * fits["cubic/zoh"]["test_rmse"]
    assert fits["cubic/cubic"]["test_rmse"] < fits["cubic/foh"]["test_rmse"]
    assert fits["cubic/zoh"]["candidate"]["suspected"]
