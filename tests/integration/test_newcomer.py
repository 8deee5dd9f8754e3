"""A newcomer's script: the README's second Python block, run as written on a CSV record.

The block loads ``record.csv``, fits the HHRA model, diagnoses it and prints both summaries
with the package's top-level names only (issue 34: at most 10 lines). Here the record is a
short simulated rig run with a dead zone the model does not declare, written as the CSV (with
its side-car) a user would have; the block runs in a process of its own from that folder with
this checkout first on the path. What is checked is what the newcomer reads: both summaries,
and a diagnosis that names an effect and lowers the selection error.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _newcomer_block() -> str:
    """The README's second ``python`` block (the first is the simulator's)."""
    blocks = (REPO / "README.md").read_text().split("```python\n")[1:]
    code = blocks[1].split("```", 1)[0]
    assert "hhra_phys.fit(" in code and "hhra_phys.diagnose(" in code
    return code


def test_the_readme_newcomer_script_is_short_and_uses_top_level_names() -> None:
    code = _newcomer_block()
    lines = [ln for ln in code.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    assert len(lines) <= 10
    imports = [ln for ln in lines if ln.startswith(("import ", "from "))]
    assert imports == ["import hhra_phys"]


def test_the_readme_newcomer_script_runs_on_a_csv_record(tmp_path) -> None:
    from hhra_phys.data import save
    from hhra_phys.effects import make_effect
    from hhra_phys.models.hhra.rig import simulate_rig

    data = simulate_rig(seed=2, duration=6.0, effects=[make_effect("valve_deadzone")],
                        effect_params={"i_dead": 0.15})
    save(data, tmp_path / "record.csv")
    run = subprocess.run([sys.executable, "-c", _newcomer_block()], cwd=tmp_path,
                         capture_output=True, text=True, timeout=1800,
                         env={**os.environ, "PYTHONPATH": str(REPO), "MPLBACKEND": "Agg"})
    assert run.returncode == 0, run.stderr[-3000:]
    out = run.stdout
    assert "chosen: " in out and "val: RMSE " in out, out
    chosen = next(ln for ln in out.splitlines() if ln.startswith("chosen: "))
    assert chosen != "chosen: none", out  # a 0.15 mA dead zone leaves a visible residual
    val = next(ln for ln in out.splitlines() if ln.startswith("val: RMSE "))
    before, after = re.match(r"val: RMSE (\S+) -> ([^,]+),", val).groups()
    assert float(after) < float(before), out
