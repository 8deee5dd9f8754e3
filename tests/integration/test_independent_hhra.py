"""The package's HHRA against a third implementation written here, at large currents.

A probe outside the project found the package 0.02 deg (40 % of the rig's 0.05 deg noise)
away from an independent implementation on a set with inertia and damping up and bulk
modulus and rated flow up, at about 60 deg swings, where step doubling put the package's
integration error at 2e-5 deg (issue 35). ``_own`` below is that independent implementation
once more: the three equations of docs/model.md ("Equations") in plain NumPy, integrated by
SciPy's DOP853 at rtol 1e-11 with an exact zero-order hold (one ``solve_ivp`` call per run of
equal input samples, restarted at every change), sign and square root either exact or the
package's documented smoothing.

What it shows (``PYTHONPATH=$PWD python tests/integration/test_independent_hhra.py`` prints
the table; docs/model.md, "Numerical choices", has the numbers):

* with the package's smoothing the two agree to the package's integration error, on every
  set (hydraulic resonance 0.4x to 2.5x the rig's, 60 deg swings): equations, hold and
  integrator are right;
* against the exact orifice law the package differs by up to 0.013 deg: the smoothed
  signed root ``(sqrt(|z| + delta) - sqrt(delta))/(sqrt(1 + delta) - sqrt(delta))`` is off by
  about ``sqrt(delta) (sqrt(z) - 1)``, i.e. up to 1e-3 of the full-drop flow ``g_valve |I|``
  when the drop ``z`` is small (a heavily damped actuator moving fast runs near the supply
  pressure), and the angle integrates that bias. It scales as ``sqrt(delta)``: the package's
  own valve with ``sqrt_delta=1e-10`` is within about 1e-4 deg of the exact law;
* the smoothed sign (``eps`` = 1e-3 mA) contributes at most 3e-5 deg at these currents.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from hhra_phys import Model
from hhra_phys.models.hhra import (
    HHRA_STAGES,
    NOMINAL_GROUPS,
    AngleOutput,
    ChamberPressure,
    CurrentCommand,
    OrificeValve,
    RotaryMotion,
)
from hhra_phys.models.hhra.rig import default_input
from hhra_phys.reference import simulate_reference
from hhra_phys.simulate import Simulator

FS = 250.0
NOISE_DEG = 0.05  # the rig's encoder noise
#: The issue's target: the package within 10 % of the noise of an independent implementation.
TARGET_DEG = 0.1 * NOISE_DEG
#: The package's smoothed root (delta = 1e-6) against the exact orifice law: measured up to
#: 1.1e-2 deg on these sets (docs/model.md); bounded at twice that.
SMOOTHING_BOUND_DEG = 0.025
N = dict(NOMINAL_GROUPS)


def _groups(torque=1.0, damping=1.0, oil=1.0, flow=1.0) -> dict[str, float]:
    """The rig's groups scaled as physical changes scale them: ``torque`` 1/(inertia),
    ``damping`` the viscous rate B_e/M_e, ``oil`` the bulk modulus (4 beta_e/V_t scales the
    displacement, leakage and valve groups), ``flow`` the valve's rated flow."""
    return dict(N, g_torque=N["g_torque"] * torque, g_damping=N["g_damping"] * damping,
                g_compress=N["g_compress"] * oil, g_leak=N["g_leak"] * oil,
                g_valve=N["g_valve"] * oil * flow)


#: Hydraulic resonance sqrt(g_torque g_compress) from 0.4x to 2.5x the rig's 15 Hz.
SETS: dict[str, dict[str, float]] = {
    "nominal": _groups(),
    # Heavy load on soft oil: 6 Hz.
    "soft-0.4x": _groups(torque=0.4, damping=0.4, oil=0.4),
    # Light load on stiff oil: 38 Hz.
    "stiff-2.5x": _groups(torque=2.5, damping=2.5, oil=2.5),
    # The kind of set: inertia and damping up, bulk modulus and rated flow up (15 Hz).
    "large-current": _groups(torque=0.5, damping=4.0, oil=2.0, flow=2.0),
    # Heavier still and more damped: the pressure runs near the supply while moving (12 Hz).
    "heavy-damped": _groups(torque=1 / 3, damping=16.0, oil=2.0, flow=2.0),
    # Soft and damped (6 Hz), stiff and damped (38 Hz), at large currents.
    "soft-damped": _groups(torque=0.4, damping=6.0, oil=0.4, flow=2.0),
    "stiff-damped": _groups(torque=2.5, damping=10.0, oil=2.5, flow=0.5),
}
SWING_DEG = 60.0
SECONDS = 8.0


def resonance_hz(g: dict[str, float]) -> float:
    return math.sqrt(g["g_torque"] * g["g_compress"]) / (2 * math.pi)


def _input(g: dict[str, float]) -> np.ndarray:
    """The rig's input family scaled so that the angle swings about 60 deg.

    First by the linear estimate (the velocity gain per mA at steady state with the valve
    linearised at rest, omega = g_valve g_torque I / (g_torque g_compress + g_damping g_leak):
    docs/model.md, the transfer function's kv/c), then once more by the swing of
    :func:`_own` (the orifice saturates the speed of the damped sets near the supply pressure).
    """
    u = default_input(SECONDS, FS, seed=1, amplitude=1.0)
    gain = g["g_valve"] * g["g_torque"] / (g["g_torque"] * g["g_compress"]
                                           + g["g_damping"] * g["g_leak"])
    u = u * SWING_DEG / float(np.ptp(np.degrees(np.cumsum(u) / FS * gain)))
    return u * SWING_DEG / float(np.ptp(_own(u, g)[0]))


def _own(u: np.ndarray, g: dict[str, float], delta: float | None = None,
         eps: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Angle [deg] and load pressure [-] at the samples, from rest.

    ``delta``/``eps``: the smoothing widths of the signed root and the sign (None: exact).
    """
    def signed_root(z: float) -> float:
        if delta is None:
            return math.copysign(math.sqrt(abs(z)), z)
        return math.copysign((math.sqrt(abs(z) + delta) - math.sqrt(delta))
                             / (math.sqrt(1 + delta) - math.sqrt(delta)), z)

    def sign(i: float) -> float:
        return float(np.sign(i)) if eps is None else i / math.sqrt(i * i + eps * eps)

    def rhs(_t: float, x: np.ndarray, i: float) -> list[float]:
        theta, omega, p = x
        q = g["g_valve"] * i * signed_root(1.0 - sign(i) * p)
        return [omega,
                g["g_torque"] * p - g["g_damping"] * omega - g["g_spring"] * theta - g["g_load"],
                q - g["g_compress"] * omega - g["g_leak"] * p]

    dt = 1.0 / FS
    x = np.zeros(3)
    X = np.empty((u.size, 3))
    X[0] = x
    k = 0
    while k < u.size - 1:
        j = k
        while j + 1 < u.size - 1 and u[j + 1] == u[k]:
            j += 1
        ts = np.arange(k, j + 2) * dt  # u[k] held from t_k to t_{j+1}
        sol = solve_ivp(rhs, (ts[0], ts[-1]), x, method="DOP853", t_eval=ts, rtol=1e-11,
                        atol=1e-12, args=(float(u[k]),))
        assert sol.success, sol.message
        X[k + 1:j + 2] = sol.y[:, 1:].T
        x = sol.y[:, -1]
        k = j + 1
    return np.degrees(X[:, 0]), X[:, 2]


def _package(u: np.ndarray, g: dict[str, float], sqrt_delta: float | None = None,
             ) -> tuple[np.ndarray, float, str]:
    """The package's output (automatic method and substeps for ``g``) and its step-doubling
    estimate; ``sqrt_delta`` builds the same model with another root width."""
    if sqrt_delta is None:
        from hhra_phys.models.hhra import HHRAModel
        model: Model = HHRAModel()
    else:
        model = Model([RotaryMotion(), ChamberPressure(), CurrentCommand(),
                       OrificeValve(sqrt_delta=sqrt_delta), AngleOutput()],
                      stages=HHRA_STAGES, pinned=("omega", "p"))
    sim = Simulator(model, FS, backend="casadi")
    p = np.array([g[n] for n in model.params.names])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # refined substeps are said here
        y = sim.simulate(u, p)
    est = sim.integration_error(u, p, substeps=sim.last_substeps, method=sim.last_method)
    return y, est, f"{sim.last_method} x{sim.last_substeps}"


def measure(name: str) -> dict[str, float | str]:
    """Every comparison of one set (deg, largest absolute difference over the record)."""
    g = SETS[name]
    u = _input(g)
    exact, p_exact = _own(u, g)
    smooth, _ = _own(u, g, delta=1e-6, eps=1e-3)
    root_only, _ = _own(u, g, delta=1e-6)  # exact sign, smoothed root
    y, est, how = _package(u, g)
    y_tight, _, _ = _package(u, g, sqrt_delta=1e-10)
    ref_exact = simulate_reference(u, FS, g, smooth=False)
    return {
        "set": name, "resonance_hz": resonance_hz(g), "current_ma": float(np.max(np.abs(u))),
        "swing_deg": float(np.ptp(exact)), "p_max": float(np.max(np.abs(p_exact))),
        "integrator": how, "step_doubling": est,
        "pkg_vs_own_smoothed": float(np.max(np.abs(y - smooth))),
        "pkg_vs_own_exact": float(np.max(np.abs(y - exact))),
        "own_smoothed_vs_exact": float(np.max(np.abs(smooth - exact))),
        "sign_smoothing": float(np.max(np.abs(smooth - root_only))),
        "pkg_delta_1e-10_vs_own_exact": float(np.max(np.abs(y_tight - exact))),
        "own_vs_reference_exact": float(np.max(np.abs(exact - ref_exact))),
    }


@pytest.fixture(scope="module")
def table() -> dict[str, dict[str, float | str]]:
    return {name: measure(name) for name in SETS}


def test_the_sets_span_the_resonances_and_swing_60_deg(table) -> None:
    hz = [r["resonance_hz"] for r in table.values()]
    nominal = table["nominal"]["resonance_hz"]
    assert min(hz) <= 0.41 * nominal and max(hz) >= 2.49 * nominal
    for row in table.values():
        assert 45.0 <= row["swing_deg"] <= 75.0, row
    # Large currents: some sets drive the load pressure to the supply pressure.
    assert max(r["p_max"] for r in table.values()) > 0.95


@pytest.mark.parametrize("name", sorted(SETS))
def test_own_implementation_agrees_with_the_reference(table, name) -> None:
    """Two independent exact implementations (mine, hhra_phys.reference's LSODA) agree far
    below anything measured here, so the comparisons below test the package."""
    assert table[name]["own_vs_reference_exact"] < 1e-5


@pytest.mark.parametrize("name", sorted(SETS))
def test_package_equals_its_documented_equations_to_a_tenth_of_the_noise(table, name) -> None:
    """The same equations and smoothing, integrated independently: what is left is the
    package's integration error (below a tenth of the noise, the issue's target)."""
    row = table[name]
    assert row["pkg_vs_own_smoothed"] < TARGET_DEG, row


@pytest.mark.parametrize("name", sorted(SETS))
def test_the_difference_from_the_exact_law_is_the_smoothed_root(table, name) -> None:
    row = table[name]
    # Bounded (docs/model.md) ...
    assert row["pkg_vs_own_exact"] < SMOOTHING_BOUND_DEG, row
    # ... and it is the root's smoothing: the sign's is negligible, and the package with
    # the root 100 times narrower (sqrt(delta) 10 times smaller) meets the target.
    assert row["sign_smoothing"] < 1e-4, row
    assert row["pkg_delta_1e-10_vs_own_exact"] < TARGET_DEG, row


def test_the_smoothing_shows_where_the_pressure_runs_near_the_supply(table) -> None:
    """The bias is about sqrt(delta) (1 - sqrt(z)) of g_valve |I|: largest on the damped
    sets, where the drop z is small while the shaft moves; there it exceeds the target (so
    the exact-law comparison above really sees it) and is 10 times the tight root's."""
    heavy = table["heavy-damped"]
    assert heavy["own_smoothed_vs_exact"] > TARGET_DEG
    assert heavy["pkg_vs_own_exact"] > 10 * heavy["pkg_delta_1e-10_vs_own_exact"]
    assert heavy["pkg_vs_own_exact"] > 2 * table["nominal"]["pkg_vs_own_exact"]


if __name__ == "__main__":
    keys = ["resonance_hz", "current_ma", "swing_deg", "p_max", "integrator", "step_doubling",
            "pkg_vs_own_smoothed", "pkg_vs_own_exact", "own_smoothed_vs_exact",
            "sign_smoothing", "pkg_delta_1e-10_vs_own_exact", "own_vs_reference_exact"]
    print("| set | " + " | ".join(keys) + " |")
    print("|---" * (len(keys) + 1) + "|")
    for set_name in SETS:
        r = measure(set_name)
        cells = [f"{r[k]:.3g}" if isinstance(r[k], float) else str(r[k]) for k in keys]
        print(f"| {set_name} | " + " | ".join(cells) + " |", flush=True)
