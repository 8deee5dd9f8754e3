"""A second, independent implementation of the HHRA and its effects (NumPy/SciPy only).

The package's model (:mod:`hhra_phys.model`, :mod:`hhra_phys.parts`,
:mod:`hhra_phys.effects`) is assembled from CasADi parts and integrated with a
fixed-step RK4 (:mod:`hhra_phys.simulate`). A simulated rig built from that same
code cannot reveal an error in its equations: the data would carry the error too
(see ``docs/model.md``). This module writes the model a second time, from the
equations in ``docs/model.md`` and the documented formulas of the effects, and
integrates it with :func:`scipy.integrate.solve_ivp` at tight tolerances under an
exact zero-order hold. It imports nothing from the package's model code; only
:class:`hhra_phys.data.Dataset` (to return records) and
:mod:`hhra_phys.excitation` (input signals).

The model (``docs/model.md``; states ``theta`` [rad], ``omega`` [rad/s],
``p = P_L/p_s`` [-])::

    dtheta/dt = omega
    domega/dt = g_torque*p - g_damping*omega - g_spring*theta - g_load   (+ motion effects)
    dp/dt     = q - g_compress*omega - g_leak*p
    q         = g_valve*c*sqrt(1 - sign(c)*p)       (orifice valve)
              = g_valve*c - g_kp*p                  (linear valve)

with ``c`` the valve command: the input current [mA], after the optional spool
lag ``tau_v*dxs/dt = c - xs`` and the input-stage effects. Output: the angle in
degrees, or ``p_gain*p + p_offset``.

State vector: ``[theta, omega, p]``, then ``xs`` (``spool_lag=True``), then
``x_spool`` (effect ``valve_dynamics``), then ``gap`` (effect ``backlash``), then
``y_drift`` (effect ``sensor_drift``): the package's order for the same model.

Effects (argument ``effects``: a mapping from the library name to its parameter
values and optional settings; parameter values not given there are taken from
``params``)::

    coulomb_friction  domega/dt -= level*sgn(omega) [+ g_viscous*omega],
                      level = g_coulomb [+ g_stribeck*exp(-(omega/v_stribeck)^2)]
                      (Stribeck term when g_stribeck is given); settings width [rad/s]
                      (or the parameter v_switch)
    valve_deadzone    c -> max(c - i_dead, 0) - max(-c - i_dead, 0); settings u_scale,
                      width
    valve_saturation  c -> clip(c, -i_sat, i_sat); settings u_scale, width
    input_delay       c from u(t - delay*dt): (1-f)*u[n-k] + f*u[n-k-1], delay = k + f [samples]
    valve_dynamics    tau_spool*dx_spool/dt = c - x_spool, c -> x_spool
    gravity_load      domega/dt -= g_grav_cos*cos(theta) + g_grav_sin*sin(theta)
    backlash          gap [rad] = shaft minus encoder angle, |gap| <= play/2 [deg], y -= gap;
                      settings width [deg] (or the parameter w_contact)
    sensor_offset     y += y_offset
    sensor_drift      y += y_drift, dy_drift/dt = drift_rate [deg/s] (y_drift from 0)
    asymmetric_valve  q *= 1 + asym*sgn(c); settings u_scale, eps
    input_offset      c -> c + u_offset (in the input stage's order, after the delay)
    constant_force    domega/dt += g_const (before friction: part of what drives it)

Smoothing. With ``smooth=True`` (default) the documented smoothings of the
package are used, so that a comparison with it can be tight:
``sgn(v) ~ v/sqrt(v^2 + eps^2)``; the orifice's signed root
``sign(z)*(sqrt(|z| + delta) - sqrt(delta))/(sqrt(1 + delta) - sqrt(delta))``;
``max(v, 0)`` of the dead zone and saturation with a quadratic corner,
``(v + w)^2/(4w)`` for ``|v| < w`` and exact beyond, ``w = width*u_scale``; friction
width ``width`` (0.005 rad/s unless given, or ``v_switch``);
backlash ``dgap/dt = max(omega, 0)*f((h - gap)/w) + min(omega, 0)*f((h + gap)/w)``
with ``h = play/2``, ``f(z) = z`` up to 0.5, ``z - (z - 0.5)^2/2`` up to 1.5, then 1,
and the contact width ``w`` (``width``, 0.01 deg unless given, or
``w_contact``). With
``smooth=False`` every switch is exact (``sign``, ``sqrt``, ``clip``, ``max``, an ideal
play operator, and Coulomb friction that sticks: within ``stick_band`` of zero velocity
the friction cancels the rest of the acceleration up to its level, Karnopp's model, so
that the integrator does not chatter across ``omega = 0``).

Exact backlash (``smooth=False``). The encoder does not act back on the shaft, so
the ideal play operator is applied to the integrated shaft angle after the
integration rather than integrated as a discontinuous rate (which takes a stiff
solver minutes per record). The operator is rate independent: on a monotone
stretch of the angle the gap moves by the change of angle, clipped to ``+-h``
(``gap <- clip(gap + dtheta, -h, h)``). So it is exact when applied to the angle at
the sample instants and at every reversal in between; the reversals (``omega = 0``)
are located by :func:`~scipy.integrate.solve_ivp` events to the integration tolerance.

The module is in three: :mod:`hhra_phys.reference.hhra_equations` (the right-hand side and
output at one point), :mod:`hhra_phys.reference.hhra_simulation` (the integration over a
record, :func:`simulate_reference`) and this one (records with excitation and sensor,
:func:`reference_record`). Every name stays importable from here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from scipy import signal as sps

from hhra_phys.data import Dataset
from hhra_phys.excitation import irregular_steps, samples
from hhra_phys.reference.hhra_equations import (
    _EFFECT_PARAMS,
    _OPTIONAL_PARAMS,
    EFFECT_NAMES,
    REFERENCE_GROUPS,
    reference_output,
    reference_rhs,
    reference_state_names,
)
from hhra_phys.reference.hhra_equations import RAD2DEG as RAD2DEG
from hhra_phys.reference.hhra_equations import SIGN_EPS as SIGN_EPS
from hhra_phys.reference.hhra_equations import SQRT_DELTA as SQRT_DELTA
from hhra_phys.reference.hhra_simulation import (
    SOLVE_IVP_METHODS,
    SolverOptions,
    _check_number,
    _solver_options,
    _with_overrides,
    simulate_reference,
)

__all__ = [
    "reference_state_names",
    "reference_rhs",
    "reference_output",
    "simulate_reference",
    "velocity_gain",
    "reference_record",
    "RecordOptions",
    "SolverOptions",
    "SOLVE_IVP_METHODS",
    "REFERENCE_GROUPS",
    "EFFECT_NAMES",
]


# --- records ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class RecordOptions:
    """How :func:`reference_record` makes a record: its excitation, its sensor, its solver.

    Every field (and every field of :class:`SolverOptions`) is also a keyword of
    :func:`reference_record`, overriding the options it is given.

    Attributes
    ----------
    amplitude : float
        Largest current [mA] of the default excitation (> 0).
    levels : int
        Number of levels of the default excitation (>= 1).
    angle_limit_deg : float
        Half range [deg] the linear angle estimate may reach before the input is scaled.
    quantization : float, optional
        Encoder resolution [deg] (a 12-bit encoder: ``360 / 4096``).
    noise_ar : float
        Coefficient ``a`` of first-order autoregressive (coloured) sensor noise,
        ``n[k] = a n[k-1] + sqrt(1 - a^2) noise_deg w[k]`` with white ``w`` and a
        stationary start; 0 (default): white noise. ``|a| < 1``.
    drift_deg : float
        A slow sensor drift [deg]: the output moves by this much, linearly in time,
        over the record (0: none).
    solver : SolverOptions
        How the plant is integrated.
    """

    amplitude: float = 1.0
    levels: int = 4
    angle_limit_deg: float = 80.0
    quantization: float | None = None
    noise_ar: float = 0.0
    drift_deg: float = 0.0
    solver: SolverOptions = SolverOptions()

    def validate(self) -> RecordOptions:
        """Check every setting; returns ``self``.

        Raises
        ------
        ValueError
            Naming the setting and what is wrong with it.
        """
        _check_number("amplitude", self.amplitude, "> 0", lambda v: v > 0)
        if isinstance(self.levels, bool) or not isinstance(self.levels, int | np.integer) \
                or self.levels < 1:
            raise ValueError(f"levels must be an integer >= 1, got {self.levels!r}")
        _check_number("angle_limit_deg", self.angle_limit_deg, "> 0", lambda v: v > 0)
        if self.quantization is not None:
            _check_number("quantization", self.quantization, ">= 0", lambda v: v >= 0)
        _check_number("noise_ar", self.noise_ar, "in (-1, 1)", lambda v: abs(v) < 1)
        _check_number("drift_deg", self.drift_deg, "", lambda v: True)
        if not isinstance(self.solver, SolverOptions):
            raise ValueError(f"solver must be a SolverOptions, got {self.solver!r}")
        self.solver.validate()
        return self


def _record_options(options: RecordOptions | None, settings: Mapping[str, Any]
                    ) -> RecordOptions:
    """``options`` with ``settings`` (its fields and :class:`SolverOptions`'s) applied."""
    base = options if options is not None else RecordOptions()
    solver_names = {f.name for f in fields(SolverOptions)}
    record_names = {f.name for f in fields(RecordOptions)}
    unknown = sorted(set(settings) - solver_names - record_names)
    if unknown:
        raise ValueError(f"unknown reference record setting(s) {', '.join(unknown)}; "
                             f"settings: {', '.join(sorted(record_names | solver_names))}")
    solver = {k: v for k, v in settings.items() if k in solver_names}
    own = {k: v for k, v in settings.items() if k not in solver_names}
    if solver:
        own["solver"] = _solver_options(own.get("solver", base.solver), solver)
    return _with_overrides(base, own, "reference record").validate()


def velocity_gain(params: Mapping[str, float], valve: str = "orifice") -> float:
    """Steady angular velocity per valve current at rest [rad/s per mA].

    ``kv/c`` of the linearisation at rest, ``g_torque*g_valve / (g_damping*(g_leak +
    g_kp) + g_torque*g_compress)`` (``g_kp = 0`` for the orifice valve at zero current).
    """
    kp = params.get("g_kp", 0.0) if valve == "linear" else 0.0
    den = params["g_damping"] * (params["g_leak"] + kp) + params["g_torque"] * params["g_compress"]
    return params["g_torque"] * params["g_valve"] / den


def reference_record(
    seed: int = 0,
    duration: float = 20.0,
    fs: float = 250.0,
    noise_deg: float = 0.05,
    params: Mapping[str, float] | None = None,
    effects: Mapping[str, Mapping[str, float]] | None = None,
    *,
    valve: str = "orifice",
    spool_lag: bool = False,
    u: Sequence[float] | np.ndarray | None = None,
    smooth: bool = True,
    intersample: str = "zoh",
    options: RecordOptions | None = None,
    **settings: Any,
) -> Dataset:
    """A simulated rig record generated by the reference implementation.

    The counterpart of :func:`hhra_phys.models.hhra.rig.simulate_rig` written without the
    package's model: the same input family (the paper's irregular multi-level steps
    of :func:`hhra_phys.excitation.irregular_steps`, one M-sequence period per 20 s,
    scaled down if a linear estimate of the angle would leave +-``angle_limit_deg``),
    the shaft started so the linear estimate's stroke is centred on 0 deg, Gaussian
    angle noise (white, or coloured: first-order autoregressive), an optional slow
    drift of the sensor and optional quantisation.

    Parameters
    ----------
    seed : int
        Seeds the excitation and then the noise.
    duration : float
        Record length [s].
    fs : float
        Sample rate [Hz].
    noise_deg : float
        Standard deviation of the angle noise [deg] (of the noise process itself, also
        when it is coloured).
    params : mapping, optional
        Groups (and effect parameters) by name; missing groups take
        :data:`REFERENCE_GROUPS` (the rig's values as printed in ``docs/model.md``).
    effects : mapping, optional
        Effects in the plant (see :func:`simulate_reference`).
    valve : {"orifice", "linear"}
        Valve law.
    spool_lag : bool
        Spool lag (then ``params`` needs ``tau_v``).
    u : array, optional
        Valve current [mA] instead of the default excitation.
    smooth, intersample
        As in :func:`simulate_reference`; the record carries ``intersample`` (what its
        input did between samples).
    options : RecordOptions, optional
        The excitation, the sensor and the solver (default :class:`RecordOptions`'s).
    **settings
        Any field of :class:`RecordOptions` (``amplitude``, ``levels``,
        ``angle_limit_deg``, ``quantization``, ``noise_ar``, ``drift_deg``) or of
        :class:`SolverOptions` (``method``, ``rtol``, ``atol``, ``stick_band``), overriding
        ``options``.

    Returns
    -------
    Dataset
        ``t`` [s], ``u`` [mA], ``y`` [deg]. ``metadata``: ``generator`` (``"reference"``),
        ``seed``, ``noise_deg``, ``noise_ar``, ``drift_deg``, ``quantization_deg``, ``valve``,
        ``true_params``
        (every parameter by name), ``effects`` (names), ``x0`` (by state name), and
        ``truth``: everything :func:`simulate_reference` needs to reproduce the
        noise-free output (``params``, ``effects`` with settings, ``valve``,
        ``spool_lag``, ``smooth``, ``x0``, ``integrator``: the :class:`SolverOptions`).
        No ``physical`` entry: the reference works in groups only.

    Raises
    ------
    ValueError
        A bad setting (or a negative ``noise_deg``), naming it.
    """
    o = _record_options(options, settings)
    if not (math.isfinite(noise_deg) and noise_deg >= 0):
        raise ValueError(f"noise_deg must be >= 0, got {noise_deg}")
    p = dict(REFERENCE_GROUPS)
    if valve == "orifice":
        p.pop("g_kp")
    p.update({k: float(v) for k, v in (params or {}).items()})
    rng = np.random.default_rng(seed)
    gain = velocity_gain(p, valve)
    u = _excitation(duration, fs, gain, rng, o) if u is None else u
    u = np.asarray(u, dtype=float)
    names = reference_state_names(spool_lag=spool_lag, effects=effects)
    x0 = np.zeros(len(names))
    x0[0] = _centred_angle(u, fs, gain)
    y_true = simulate_reference(u, fs, p, valve=valve, spool_lag=spool_lag, effects=effects,
                                x0=x0, smooth=smooth, intersample=intersample, solver=o.solver)
    y = _sensor(y_true, noise_deg, rng, o)
    eff = {k: dict(v) for k, v in (effects or {}).items()}
    true_params = dict(p)
    for vals in eff.values():
        true_params.update({k: v for k, v in vals.items() if k in _ALL_EFFECT_PARAMS})
    meta: dict[str, Any] = {
        "generator": "reference",
        "seed": seed,
        "noise_deg": noise_deg,
        "noise_ar": o.noise_ar,
        "drift_deg": o.drift_deg,
        "quantization_deg": o.quantization,
        "valve": valve,
        "intersample": intersample,
        "true_params": true_params,
        "effects": list(eff),
        "x0": dict(zip(names, x0.tolist(), strict=True)),
        "truth": {
            "params": dict(p),
            "effects": eff,
            "valve": valve,
            "spool_lag": spool_lag,
            "smooth": smooth,
            "x0": x0.tolist(),
            "integrator": {f.name: getattr(o.solver, f.name) for f in fields(SolverOptions)},
        },
    }
    return Dataset.from_arrays(
        u, y, fs=fs, metadata=meta, name=f"reference-seed{seed}",
        input_name="current", input_unit="mA", output_name="angle", output_unit="deg",
    )


def _excitation(duration: float, fs: float, gain: float, rng: np.random.Generator,
                o: RecordOptions) -> np.ndarray:
    """The default input: irregular steps, scaled down if the linear estimate of the angle
    (``gain`` [rad/s per mA]) would span more than ``2 * angle_limit_deg``."""
    n = samples(duration, fs)
    periods = max(1, int(round(duration / 20.0)))
    u = irregular_steps(n, levels=o.levels, amplitude=o.amplitude, n_periods=periods, seed=rng)
    est = np.degrees(np.cumsum(u) / fs * gain)
    half = 0.5 * float(est.max() - est.min())
    return u * (o.angle_limit_deg / half) if half > o.angle_limit_deg else u


def _centred_angle(u: np.ndarray, fs: float, gain: float) -> float:
    """Initial angle [rad] that centres the linear estimate's stroke on 0."""
    est = np.degrees(np.cumsum(u) / fs * gain)
    est -= est[0]
    return -math.radians(0.5 * float(est.max() + est.min()))


def _sensor(y_true: np.ndarray, noise_deg: float, rng: np.random.Generator,
            o: RecordOptions) -> np.ndarray:
    """The measured angle: noise (white or AR(1)), drift and quantisation added."""
    w = noise_deg * rng.standard_normal(y_true.size)
    if o.noise_ar:
        # Stationary AR(1) with the standard deviation noise_deg: first sample at the
        # stationary spread, then innovations scaled by sqrt(1 - a^2).
        w[1:] *= math.sqrt(1.0 - o.noise_ar ** 2)
        w = sps.lfilter([1.0], [1.0, -o.noise_ar], w)
    y = y_true + w
    if o.drift_deg:
        y = y + o.drift_deg * np.arange(y.size) / max(y.size - 1, 1)
    if o.quantization:
        y = np.round(y / o.quantization) * o.quantization
    return y


_ALL_EFFECT_PARAMS = ({k for v in _EFFECT_PARAMS.values() for k in v}
                      | {k for v in _OPTIONAL_PARAMS.values() for k in v})
