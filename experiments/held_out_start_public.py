"""The public record's final fit scored with each start of the held-out parts (issue 33).

Reads a JSON of ``experiments/public_case.py`` (its final fit), rebuilds the fit's problem
on the estimation part (samples 1-512) and scores the selection (513-768) and test
(769-1024) parts with the fitted values, each part started

``alone``
    at its own first sample, the input before it held, the state fitted on the part
    (main's rule before issue 33);
``window``
    through an unscored leading window (input memory and a quarter of the part), the state
    fitted on it (``problem.HELD_OUT_STATE = "window"``);
``part``
    through its input memory, the state fitted on the part (``"part"``, the default).

    HHRA_SHARED_DATA=/work/shared/data PYTHONPATH=$PWD python experiments/held_out_start_public.py
        RESULT.json [--out FILE.json]
"""

from __future__ import annotations

import argparse
import json
import warnings

import numpy as np

import hhra_phys.problem as problem_module
from hhra_phys.data import Dataset, load_public_actuator
from hhra_phys.diagnosis.result import LoopResult
from hhra_phys.diagnosis.selection import split_record
from hhra_phys.outputs import atomic_write_text, jsonable
from hhra_phys.problem import Problem


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("result")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    warnings.simplefilter("ignore", RuntimeWarning)
    with open(args.result) as fh:
        loop = LoopResult.from_json(json.load(fh))
    res = loop.final
    est, sel, test = split_record(load_public_actuator(), 0.5, 0.25)
    free = list(res.free)
    pr = Problem(res.model, [est], free=[n for n in free if not n.startswith("x0_")],
                 fixed={k: v for k, v in res.values.items() if k not in free},
                 initial_state="fit",
                 start={**res.values,
                        **{n: res.x0_param(n) for n in free if n.startswith("x0_")}},
                 allow_outside_box=True)
    v = np.array([res.values[n] if n in res.values else res.x0_param(n) for n in pr.free_names])
    keep = problem_module.HELD_OUT_STATE
    row = {"result": args.result, "chosen": list(loop.chosen)}
    try:
        for name, part in (("sel", sel), ("test", test)):
            alone = Dataset(t=part.t, u=part.u, y=part.y, metadata=part.metadata, name=part.name)
            row[name] = {"alone": float(np.sqrt(np.mean((part.y - pr.simulate_values(
                v, data=alone)) ** 2)))}
            for mode in ("window", "part"):
                problem_module.HELD_OUT_STATE = mode
                y = pr.simulate_values(v, data=part)
                row[name][mode] = float(np.sqrt(np.mean((part.y - y) ** 2)))
    finally:
        problem_module.HELD_OUT_STATE = keep
    print(json.dumps(row, indent=1))
    if args.out:
        atomic_write_text(args.out, json.dumps(jsonable(row), indent=1))


if __name__ == "__main__":
    main()
