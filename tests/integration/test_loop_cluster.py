"""The loop's honest selection and its executors, on short records.

* the test part chooses nothing: corrupting it changes only the test scores;
* the same seed gives the same loop here, in local processes and on a Dask
  ``LocalCluster`` (2 worker processes);
* ``fit_many`` and the CLI's ``--workers``/``--dask`` run through the same executors.
"""

from __future__ import annotations

import json
import warnings
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest

from hhra_phys.data import Dataset
from hhra_phys.diagnosis.engine import augment
from hhra_phys.diagnosis.selection import split_record
from hhra_phys.reference import reference_record

#: A short record with a dead zone (8 s at 250 Hz: 1000 estimation, 500 selection
#: and 500 test samples) and a small loop: two candidates, one round.
LOOP = {"candidates": ["valve_deadzone", "input_delay"], "max_effects": 1, "pop_size": 20,
        "max_iter": 20, "discover": False}  # discovery has its own tests


def _record(seed: int = 1) -> Dataset:
    return reference_record(seed=seed, duration=8.0, effects={"valve_deadzone": {"i_dead": 0.1}})


def _run(ds: Dataset, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return augment(ds, **{**LOOP, **kw})


def _summary(res) -> dict:
    return {"chosen": res.chosen,
            "steps": [(s.effect, s.params, s.val["rmse"], s.accepted) for s in res.steps],
            "final": res.final.values}


def test_split_record_makes_three_parts_in_time_order():
    ds = _record()
    est, sel, test = split_record(ds, 0.5, 0.25)
    assert (est.n, sel.n, test.n) == (1000, 500, 500)
    assert est.t[-1] < sel.t[0] and sel.t[-1] < test.t[0]
    est2, sel2, none = split_record(ds, 0.5, 0.0)
    assert none is None and sel2.n == 1000
    with pytest.raises(Exception, match="test must be in"):
        split_record(ds, 0.5, 0.5)


def test_test_part_chooses_nothing():
    """Replace the test part's output by garbage: the choices must not move."""
    ds = _record()
    res = _run(ds)
    n_test = res.settings["data"]["n_test"]
    y = ds.y.copy()
    y[-n_test:] = np.random.default_rng(0).normal(0.0, 5.0, n_test)
    bad = Dataset.from_arrays(ds.u, y, fs=ds.fs, t=ds.t)
    res_bad = _run(bad)
    assert _summary(res_bad) == _summary(res)
    assert res.chosen == ["valve_deadzone"]
    assert res_bad.test["rmse"] > 10 * res.test["rmse"]
    js = res.to_json()
    assert set(js["test"]) >= {"rmse", "vaf"} and js["test"]["rmse"] == res.test["rmse"]
    assert js["base"]["test"]["rmse"] > js["final"]["test"]["rmse"]
    assert {"base", "final", "chosen", "steps", "skipped"} <= set(js)


@pytest.mark.slow
def test_serial_processes_and_dask_give_the_same_loop():
    distributed = pytest.importorskip("distributed")
    ds = _record(seed=2)
    serial = _summary(_run(ds, background=False))
    with ProcessPoolExecutor(2) as pool:
        assert _summary(_run(ds, executor=pool)) == serial
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        assert _summary(_run(ds, executor=client.get_executor())) == serial


@pytest.mark.slow
def test_cli_dask_and_workers(tmp_path):
    distributed = pytest.importorskip("distributed")
    from hhra_phys.cli import main
    from hhra_phys.data import save

    data = tmp_path / "rec.csv"
    save(_record(seed=3), data)
    common = [str(data), "--max-effects", "1", "--pop", "20", "--iters", "20",
              "--effects", "input_delay,valve_saturation", "--no-discover"]
    out_w, out_d = tmp_path / "w.json", tmp_path / "d.json"
    assert main(["diagnose", *common, "--workers", "2", "--json", str(out_w)]) == 0
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        assert main(["diagnose", *common, "--dask", cluster.scheduler_address,
                     "--json", str(out_d)]) == 0
        fit_json = tmp_path / "f.json"
        assert main(["fit", str(data), "--starts", "2", "--pop", "10", "--iters", "5",
                     "--dask", cluster.scheduler_address, "--json", str(fit_json)]) == 0
    w, d = json.loads(out_w.read_text()), json.loads(out_d.read_text())
    # Neither candidate is the record's dead zone (both are refitted, none settles the
    # round): the same steps, choice and scores from local processes and the cluster.
    assert [s["effect"] for s in w["steps"]] == [s["effect"] for s in d["steps"]]
    assert {s["effect"] for s in w["steps"]} == {"input_delay", "valve_saturation"}
    assert w["chosen"] == d["chosen"]
    assert w["test"]["rmse"] == d["test"]["rmse"] and {"rmse", "vaf"} <= set(w["test"])
    assert json.loads(fit_json.read_text())["seed"] in (0, 1)


def test_cli_refuses_workers_and_dask_together(tmp_path, capsys):
    from hhra_phys.cli import main

    assert main(["diagnose", "--workers", "2", "--dask", "tcp://127.0.0.1:1"]) == 2  # usage error
    assert "either --workers or --dask" in capsys.readouterr().err


def _without_times(obj):
    """A loop JSON without its wall times, the fits' creation stamps and the executor's
    name (the only fields where the jobs ran may change)."""
    if isinstance(obj, dict):
        return {k: _without_times(v) for k, v in obj.items()
                if k not in ("executor", "created")
                and not any(w in k for w in ("seconds", "time", "elapsed"))}
    if isinstance(obj, list):
        return [_without_times(v) for v in obj]
    return obj


def test_cli_default_workers_give_the_serial_json(tmp_path, monkeypatch, capfd):
    """``diagnose`` refits candidates in one process per core by default (``--workers
    auto``); its JSON is the serial run's (``--workers 0``) but for wall times. The workers
    ended at the end print nothing (no traceback of an inherited SIGTERM handler)."""
    from hhra_phys import cluster
    from hhra_phys.cli import main
    from hhra_phys.data import save

    monkeypatch.setattr(cluster, "auto_workers", lambda: 2)  # two workers on any machine
    data = tmp_path / "rec.csv"
    save(reference_record(seed=4, duration=6.0, effects={"valve_deadzone": {"i_dead": 0.1}}),
         data)
    common = [str(data), "--max-effects", "1", "--pop", "12", "--iters", "8",
              "--effects", "input_delay,valve_saturation", "--no-discover"]
    out_s, out_a = tmp_path / "s.json", tmp_path / "a.json"
    assert main(["diagnose", *common, "--workers", "0", "--json", str(out_s)]) == 0
    assert main(["diagnose", *common, "--json", str(out_a)]) == 0
    s, a = json.loads(out_s.read_text()), json.loads(out_a.read_text())
    # both candidates were refitted (neither explains the dead zone, so neither settles
    # the round and the second is not skipped)
    assert len(s["steps"]) >= 2
    assert a["settings"]["executor"] == "ProcessPoolExecutor"
    assert _without_times(a) == _without_times(s)
    assert "Traceback" not in capfd.readouterr().err


def test_auto_workers_is_one_per_core_and_none_on_one():
    from hhra_phys.cluster import auto_workers

    n = auto_workers()
    assert n is None or n >= 2


def _blas_threads() -> list[int]:
    from threadpoolctl import threadpool_info

    return [int(i["num_threads"]) for i in threadpool_info() if i["user_api"] == "blas"]


def test_local_workers_and_this_process_use_one_blas_thread_while_the_pool_runs():
    # Two processes on two cores each with a spinning BLAS pool took the cores from the
    # compiled simulations; inside the block every process has one BLAS thread, and this
    # process gets its own setting back afterwards.
    from threadpoolctl import threadpool_limits

    from hhra_phys.cluster import BLAS_THREADS_WITH_WORKERS, executor

    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        with executor(1) as ex:
            inside = _blas_threads()
            in_worker = ex.submit(_blas_threads).result()
        after = _blas_threads()
    assert before and set(before) == {2}
    assert set(inside) == {BLAS_THREADS_WITH_WORKERS}
    assert in_worker and set(in_worker) == {BLAS_THREADS_WITH_WORKERS}
    assert after == before


def _timeless(lines: list[str]) -> list[str]:
    # Seconds and the round's cost estimate depend on the machine, nothing else may.
    import re

    return [re.sub(r"\[[0-9.]+ s\]|about [0-9]+ s", "", line) for line in lines]


def test_discovery_refits_on_workers_say_and_decide_as_here():
    # Discovery's entries are refitted in the worker processes (discovery_jobs.py); the
    # lines, steps and choice must be those of the refits run here. "Here" is the path a
    # refit takes when it cannot run on the workers (a part that does not pickle): the
    # same Discovery.refit as without workers, on a pool where discovery's jobs fail, so
    # that both runs have one BLAS thread per process and the same arithmetic.
    from hhra_phys.cluster import executor, one_blas_thread

    ds = reference_record(seed=4, duration=6.0, effects={"valve_deadzone": {"i_dead": 0.1}})
    kw = {"candidates": ["input_delay"], "max_effects": 1, "pop_size": 16, "max_iter": 12,
          "discover": True, "background": False}
    here: list[str] = []
    limits = one_blas_thread()
    try:
        with _NoDiscoveryThere(2) as ex:
            res_here = _run(ds, progress=here.append, executor=ex, **kw)
    finally:
        limits.restore_original_limits()
    there: list[str] = []
    with executor(2) as ex:
        res_there = _run(ds, progress=there.append, executor=ex, **kw)
    assert any(s.discovered for s in res_here.steps)  # discovery did refit something
    assert _summary(res_there) == _summary(res_here)
    assert ([getattr(s, "expression", None) for s in res_there.steps]
            == [getattr(s, "expression", None) for s in res_here.steps])
    assert _timeless(there) == _timeless(here)


class _NoDiscoveryThere(ProcessPoolExecutor):
    """A pool on which discovery's refits fail as an unpicklable job would."""

    def submit(self, fn, /, *args, **kwargs):
        import pickle
        from concurrent.futures import Future

        from hhra_phys.diagnosis.discovery_jobs import refit_elsewhere

        if fn is refit_elsewhere:
            failed: Future = Future()
            failed.set_exception(pickle.PicklingError("cannot pickle a part"))
            return failed
        return super().submit(fn, *args, **kwargs)
