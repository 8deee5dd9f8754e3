"""A discovered term that only reparametrises the model, on a record of our own making.

A user's first-order RC circuit written with the public API (``dv/dt = (k_in*u - v)/tau``,
output ``v`` [V]), a record of it with 10 mV noise, and the term discovery would find
for a gain error: ``d v/dt += a*u``. The term duplicates ``k_in/tau``: the fit cannot
tell them apart. Printed: the weak direction of the fit with the term, the intervals
(none for the two, with the reason), the output change when ``k_in`` moves by 40 %
and the term compensates, the refusal of :func:`hhra_phys.result.redundant`, and the
same for a term the data can tell (``a*u^2``).

    python experiments/redundant_term.py [--seed 0]
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np

from hhra_phys import Model, Parameter, Part, Simulator, State, register_part
from hhra_phys.data import Dataset
from hhra_phys.fit import fit
from hhra_phys.result import redundant
from hhra_phys.terms import DiscoveredTerm


@register_part
@dataclass(frozen=True)
class RC(Part):
    """``dv/dt = (k_in*u - v)/tau``."""

    name = "rc_circuit"
    stage = "circuit"

    @property
    def parameters(self):
        return (Parameter("k_in", "V/V", 1.0, 0.1, 10.0, "log", "input gain"),
                Parameter("tau", "s", 0.05, 0.005, 0.5, "log", "time constant"))

    @property
    def states(self):
        return (State("v", "V", 0.0, "capacitor voltage", scale=1.0),)

    def apply(self, ctx):
        ctx.add_rate("v", (ctx.p["k_in"] * ctx.u - ctx.x["v"]) / ctx.p["tau"])


@register_part
@dataclass(frozen=True)
class Probe(Part):
    name = "probe"
    stage = "sensor"

    def apply(self, ctx):
        ctx.signals["y"] = ctx.x["v"]


def make_model() -> Model:
    model = Model([RC(), Probe()], name="rc")
    return model


def record(seed: int) -> Dataset:
    rng = np.random.default_rng(seed)
    n, fs = 1500, 200.0
    u = np.repeat(rng.uniform(-1.0, 1.0, n // 40 + 1), 40)[:n]
    m = make_model()
    p = np.array([{"k_in": 2.0, "tau": 0.04}.get(q.name, q.nominal) for q in m.params])
    y = Simulator(m, fs=fs).simulate(u, p, x0=np.zeros(1)) + 0.01 * rng.standard_normal(n)
    return Dataset(t=np.arange(n) / fs, u=u, y=y, name=f"rc seed {seed}", input_name="drive",
                   input_unit="V", output_name="capacitor voltage", output_unit="V")


def term(spec: str) -> DiscoveredTerm:
    return DiscoveredTerm(target="rate:v", index=1, terms=(spec,), variables=("u",),
                          scales=(1.0,), start=(0.0,), bound=(500.0,), knots=(0.0,),
                          knot_max=(0.0,), unit="V/s", var_units=("V",))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    ds = record(args.seed)
    for spec in ("lin(u)", "sq(u)"):
        t = term(spec)
        res = fit(ds, make_model().with_parts(t), pop_size=12, max_iter=15, seed=args.seed)
        new = [p.name for p in t.parameters]
        print(f"--- term {t.expression(res.values)}")
        for name in res.free:
            lo, hi = res.ci95[name]
            value = res.values.get(name, res.x0.get(name[3:], np.nan))
            print(f"  {name:10s} {value:+.5g}  95 % CI [{lo:.5g}, {hi:.5g}]"
                  + (f"  ({res.intervals['reasons'][name]})"
                     if name in res.intervals.get("reasons", {}) else ""))
        for d in res.intervals.get("weak_directions", []):
            print(f"  weak direction, condition {d['condition']:.3g}: {d['params']}")
        if spec == "lin(u)":
            # k_in up 40 %, the term takes back what k_in/tau added: the output barely moves.
            v = dict(res.values)
            y0 = res.simulate(ds.u, x0=res.x0)
            a = new[0]
            v2 = dict(v, k_in=1.4 * v["k_in"])
            v2[a] = v[a] - 0.4 * v["k_in"] / v["tau"]
            model = res.model
            sim = Simulator(model, fs=ds.fs)
            P2 = np.array([v2[n] for n in model.params.names])
            y2 = sim.simulate(ds.u, P2, x0=np.array([res.x0[s] for s in model.state_names]))
            print(f"  k_in +40 % with {a} compensating: output change RMS "
                  f"{np.sqrt(np.mean((y2 - y0) ** 2)):.3g} V (noise 0.01 V)")
        print(f"  redundant: {redundant(res, new)}")
        print("  warnings:\n    " + "\n    ".join(res.warnings))


if __name__ == "__main__":
    main()
