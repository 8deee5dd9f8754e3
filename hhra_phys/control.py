"""Controller design on fitted models: linearisation, closed-loop checks, uncertainty.

A fitted model becomes a `python-control <https://python-control.readthedocs.io>`_
system::

    from hhra_phys import control as hc
    plant = hc.linearize(result)                 # continuous StateSpace, mA -> deg
    G = hc.to_tf(result)                         # the paper's kv/(s^3 + b s^2 + c s), in deg
    Pd = hc.discretize(plant, 0.004)             # zero-order hold ("foh", "tustin")

and a controller designed on it is checked on the *nonlinear* fitted model, with
every part and effect the model has, by :class:`ClosedLoop`::

    loop = hc.ClosedLoop(result, controller, dt=0.004, current_limit=1.0)
    resp = loop.step(10.0, duration=1.0)         # 10 deg step
    resp.step_info()                             # rise time, overshoot, error

Units (HHRA): input valve current [mA], output shaft angle [deg] (the model's
measured output; a pressure-output model gives its pressure units), states
``theta`` [rad], ``omega`` [rad/s], ``p`` [-] (load pressure over supply
pressure) and, with a spool lag, ``xs`` [mA]; effects may add states.

Linearisation is exact: the Jacobians of the CasADi model
(:meth:`hhra_phys.model.Model.linearize`). At rest it reproduces the paper's
``G(s) = kv/(a s^3 + b s^2 + c s)`` (:meth:`HHRAModel.tf_coefficients`), times
``180/pi`` because the output is in degrees.

Identified ARX models (:class:`hhra_phys.arx.ARXModel`) are discrete; their
continuous form is the inverse Tustin image (``s = (2/T)(z-1)/(z+1)``), so
``discretize(linearize(arx, dt=T), T, "tustin")`` returns the ARX model again.

Uncertainty: :func:`sample_parameters` draws parameter vectors from the fit's
Gauss-Newton covariance (in fitting coordinates, so log-scaled groups stay
positive), :func:`sample_models` linearises each draw, and :func:`loop_margins`
evaluates a controller's gain and phase margins across the family.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import casadi as ca
import control as ct
import numpy as np
import scipy.signal

from hhra_phys.arx import ARXFit, ARXModel
from hhra_phys.errors import ModelError, ParameterError
from hhra_phys.integrate import rk4
from hhra_phys.model import Model
from hhra_phys.models.hhra.model import RAD2DEG, HHRAModel
from hhra_phys.result import FitResult

__all__ = [
    "ClosedLoop",
    "ClosedLoopResponse",
    "OperatingPoint",
    "discretize",
    "linearize",
    "loop_margins",
    "paper_tf",
    "sample_models",
    "sample_parameters",
    "to_tf",
]

#: RK4 substeps of :class:`ClosedLoop` are chosen so that spectral radius times
#: substep stays below this (the rule of :class:`hhra_phys.simulate.Simulator`).
RK4_RHO_H = 0.25

Source = FitResult | Model | ARXModel | ARXFit


# --- operating point ---------------------------------------------------------------


@dataclass(frozen=True)
class OperatingPoint:
    """Where a model is linearised (default: rest).

    Parameters
    ----------
    current : float
        Valve current I0 [mA].
    angle : float
        Shaft angle theta0 [deg].
    pressure : float
        Load pressure P_L/p_s [-], in (-1, 1).
    velocity : float
        Shaft angular velocity [deg/s] (0: a holding point).
    states : dict, optional
        Values of further states by name, in the model's state units (e.g. an
        effect's state). A spool-lag state ``xs`` defaults to ``current``.

    Notes
    -----
    The point need not be an equilibrium; the linear model then describes
    deviations around a moving point. Rest (all zero) is an equilibrium. A
    load held at pressure ``p0`` is an equilibrium when the valve current
    supplies the leakage, ``q(I0, p0) = g_leak*p0``. The orifice valve's sign is
    smoothed, so at ``current = 0`` and ``pressure != 0`` its flow gain is the
    average of the two sides' (``g_valve``), not either one-sided value.
    """

    current: float = 0.0
    angle: float = 0.0
    pressure: float = 0.0
    velocity: float = 0.0
    states: Mapping[str, float] | None = None

    def state_vector(self, model: Model) -> np.ndarray:
        """The state vector of ``model`` at this point (model units).

        ``angle``, ``pressure`` and ``velocity`` are read by models that define
        them (:meth:`Model.operating_state <hhra_phys.model.Model.operating_state>`,
        the HHRA's); any model takes ``states`` by name.
        """
        for name in ("current", "angle", "pressure", "velocity"):
            if not math.isfinite(getattr(self, name)):
                raise ParameterError(f"operating_point.{name} must be finite")
        x = model.operating_state(model.x0(), current=self.current, angle=self.angle,
                                  pressure=self.pressure, velocity=self.velocity)
        names = model.state_names
        for name, value in (self.states or {}).items():
            if name not in names:
                raise ParameterError(
                    f"operating_point.states names unknown state {name!r}; "
                    f"the model's states are {', '.join(names)}"
                )
            x[names.index(name)] = float(value)
        return x


# --- sources ------------------------------------------------------------------------


def _physical(
    source: FitResult | Model, params: np.ndarray | Mapping[str, float] | None
) -> tuple[Model, np.ndarray, float]:
    """(model, parameter vector, sample period) of a physical source."""
    if isinstance(source, FitResult):
        model = source.model
        p = source.parameter_vector()
        dt = 1.0 / float(source.settings.get("fs", 250.0))
    else:
        model, p, dt = source, source.nominal(), 0.004
    if params is not None:
        if isinstance(params, Mapping):
            d = model.params.as_dict(p)
            for name in params:
                model.params.index(name)  # clear error for unknown names
            d.update({k: float(v) for k, v in params.items()})
            p = np.array([d[n] for n in model.params.names])
        else:
            p = np.asarray(params, dtype=float)
            if p.shape != (model.n_params,):
                raise ParameterError(
                    f"params must have shape ({model.n_params},) for this model, got {p.shape}"
                )
    return model, p, dt


def linearize(
    source: Source,
    operating_point: OperatingPoint | None = None,
    *,
    params: np.ndarray | Mapping[str, float] | None = None,
    dt: float | None = None,
) -> ct.StateSpace:
    """Continuous linear model of a fitted physical model or an ARX model.

    Parameters
    ----------
    source : FitResult, Model, ARXModel or ARXFit
        A physical fit (its fitted parameters), a model (its nominal parameters
        unless ``params``), or an identified ARX model (needs ``dt``).
    operating_point : OperatingPoint, optional
        Where to linearise (default: rest). Not used for ARX models, which are
        linear already.
    params : array or dict, optional
        Parameter vector (model order) or ``{name: value}`` replacing some
        values of a physical source.
    dt : float, optional
        Sample period [s]: required for an ARX model (its sample time); for a
        physical model it is passed to discrete-time input parts (delays) and
        defaults to the fit's ``1/fs`` (0.004 s for a bare model).

    Returns
    -------
    control.StateSpace
        Continuous system ``dx/dt = A x + B u``, ``y = C x + D u`` in deviations
        from the operating point. Input ``current`` [mA]; output ``angle``
        [deg] (``pressure`` for a pressure-output model); states named as the
        model's (``theta`` [rad], ``omega`` [rad/s], ``p`` [-], ``xs`` [mA] ...)
        or ``x[i]`` for an ARX model (a realisation without physical meaning).

    Raises
    ------
    ParameterError
        Missing ``dt`` for an ARX model, a bad ``params`` vector or an invalid
        operating point.

    Notes
    -----
    Input delays of a model (parts with input lags) enter as their static gain;
    add the delay to the discrete design model if it matters.
    """
    if isinstance(source, ARXFit):
        source = source.model
    if isinstance(source, ARXModel):
        if dt is None or not (math.isfinite(dt) and dt > 0):
            raise ParameterError(
                f"dt (the ARX model's sample period in s) is required and must be positive, "
                f"got {dt!r}"
            )
        num, den = _inverse_tustin(*_arx_z_polys(source), float(dt))
        sys = ct.ss(ct.tf(num, den))
        return ct.ss(sys.A, sys.B, sys.C, sys.D, inputs=["current"], outputs=["y"],
                     states=[f"x[{i}]" for i in range(sys.nstates)], name="arx")
    if not isinstance(source, (FitResult, Model)):
        raise ParameterError(
            f"source must be a FitResult, Model, ARXModel or ARXFit, got {type(source).__name__}"
        )
    model, p, dt_fit = _physical(source, params)
    op = operating_point or OperatingPoint()
    x = op.state_vector(model)
    A, B, C, D = model.linearize(p, x, u=op.current, dt=dt if dt is not None else dt_fit)
    return ct.ss(A, B, C, D, inputs=[model.input_name], outputs=[model.output_name],
                 states=model.state_names, name=model.name)


def to_tf(
    source: Source | ct.StateSpace,
    operating_point: OperatingPoint | None = None,
    **kwargs: Any,
) -> ct.TransferFunction:
    """Transfer function of :func:`linearize` (or of a given state-space system).

    Parameters
    ----------
    source : FitResult, Model, ARXModel, ARXFit or control.StateSpace
        As for :func:`linearize`; a ``StateSpace`` is converted as it is.
    operating_point : OperatingPoint, optional
        Where to linearise (default: rest).
    **kwargs
        ``params`` and ``dt`` of :func:`linearize`.

    Returns
    -------
    control.TransferFunction
        Output over input (the HHRA at rest: ``(180/pi) kv / (s^3 + b s^2 + c s)``
        deg/mA, see :func:`paper_tf`).
    """
    sys = source if isinstance(source, ct.StateSpace) else linearize(
        source, operating_point, **kwargs)
    return ct.tf(sys)


def paper_tf(
    source: FitResult | HHRAModel, unit: Literal["deg", "rad"] = "deg"
) -> ct.TransferFunction:
    """The paper's ``kv/(a s^3 + b s^2 + c s)`` from the identifiable groups.

    Parameters
    ----------
    source : FitResult or HHRAModel
        A fit of the HHRA (its ``tf``) or an HHRA model (nominal parameters).
    unit : {"deg", "rad"}
        Unit of the angle (the model output is in deg; the paper's ``kv`` in rad).
    """
    if unit not in ("deg", "rad"):
        raise ParameterError(f"unit must be 'deg' or 'rad', got {unit!r}")
    if isinstance(source, FitResult):
        tf = source.tf
        if not tf:
            raise ModelError("this fit's model is not an HHRA model: it has no paper TF")
    elif isinstance(source, HHRAModel):
        tf = source.tf_coefficients()
    else:
        raise ParameterError(f"source must be a FitResult or HHRAModel, got {type(source)}")
    gain = RAD2DEG if unit == "deg" else 1.0
    return ct.tf([gain * tf["kv"]], [tf["a"], tf["b"], tf["c"], 0.0],
                 inputs=["current"], outputs=["angle"], name="paper")


def discretize(
    sys: ct.StateSpace | ct.TransferFunction,
    dt: float,
    method: Literal["zoh", "foh", "tustin"] = "zoh",
) -> ct.StateSpace | ct.TransferFunction:
    """Discrete-time version of a continuous system.

    Parameters
    ----------
    sys : control.StateSpace or control.TransferFunction
        Continuous system (e.g. from :func:`linearize`).
    dt : float
        Sample period [s].
    method : {"zoh", "foh", "tustin"}
        Zero-order hold (exact for a piecewise-constant valve current, the
        right model of a digital controller's output), first-order hold (exact
        for an input linear between samples: the discrete model of a record whose
        inter-sample behaviour is ``"foh"``, ``result.settings["intersample"]``,
        as the simulator integrates it), or Tustin (bilinear; the paper's ARX
        discretisation).

    Returns
    -------
    Same type as ``sys`` with sample time ``dt``; signal names are kept.
    """
    if method not in ("zoh", "foh", "tustin"):
        raise ParameterError(f"method must be 'zoh', 'foh' or 'tustin', got {method!r}")
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise ParameterError(f"dt must be a positive sample period in s, got {dt!r}")
    if not ct.isctime(sys, strict=True):
        raise ParameterError("sys must be a continuous-time system (dt = 0)")
    return sys.sample(float(dt), method="bilinear" if method == "tustin" else method)


# --- ARX: inverse Tustin -----------------------------------------------------------


def _arx_z_polys(model: ARXModel) -> tuple[np.ndarray, np.ndarray]:
    b_full, a_full = model.filter_coefficients()
    n = max(b_full.size, a_full.size)
    return (np.concatenate([b_full, np.zeros(n - b_full.size)]),
            np.concatenate([a_full, np.zeros(n - a_full.size)]))


def _inverse_tustin(num: np.ndarray, den: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Continuous num/den (descending powers of s) of a discrete num/den in powers of z^-1.

    ``z^-k -> (1 - sT/2)^k (1 + sT/2)^(N-k) / (1 + sT/2)^N``; the common factor
    cancels. A discrete pole or zero at ``z = -1`` (no continuous image) lowers
    the degree; the vanishing leading coefficients are dropped.
    """
    n = num.size - 1
    plus, minus = np.array([dt / 2, 1.0]), np.array([-dt / 2, 1.0])

    def power(p: np.ndarray, k: int) -> np.ndarray:
        out = np.array([1.0])
        for _ in range(k):
            out = np.polymul(out, p)
        return out

    def image(c: np.ndarray) -> np.ndarray:
        out = np.zeros(n + 1)
        for k, ck in enumerate(c):
            out += ck * np.polymul(power(minus, k), power(plus, n - k))
        return out

    def trim(p: np.ndarray, scale: float) -> np.ndarray:
        i = 0
        while i < p.size - 1 and abs(p[i]) <= 1e-9 * scale:
            i += 1
        return p[i:]

    num_s, den_s = image(num), image(den)
    scale = float(np.max(np.abs(np.concatenate([num_s, den_s]))))
    num_s, den_s = trim(num_s, scale), trim(den_s, scale)
    if num_s.size > den_s.size:
        raise ParameterError("the ARX model's continuous image is improper (a pole at z = -1)")
    return num_s / den_s[0], den_s / den_s[0]


# --- uncertainty --------------------------------------------------------------------


def sample_parameters(
    result: FitResult, n: int = 50, seed: int | np.random.Generator | None = 0
) -> np.ndarray:
    """Parameter vectors drawn from a fit's Gauss-Newton covariance.

    The free parameters are drawn from ``N(z_hat, D R D)`` in fitting
    coordinates (``z = log10(value)`` for log-scaled groups, ``value/s`` for
    linear ones with ``s`` half their box width; ``D = diag(std)``, ``R`` the
    correlation matrix) and mapped back, so log-scaled groups stay positive.
    Fixed parameters keep their values; a fitted initial state is ignored.

    Parameters
    ----------
    result : FitResult
        A physical fit.
    n : int
        Number of draws.
    seed : int, Generator or None
        Seeds the draws (same seed, same draws).

    Returns
    -------
    ndarray, shape (n, n_params)
        Parameter vectors in the model's order (physical units).

    Raises
    ------
    ParameterError
        If a free parameter's standard deviation is missing or not finite (not
        identifiable from the fit's data: fix it, or widen the record).
    """
    if not isinstance(result, FitResult):
        raise ParameterError(f"result must be a FitResult, got {type(result).__name__}")
    if int(n) < 1:
        raise ParameterError(f"n must be a positive number of draws, got {n!r}")
    model = result.model
    names = [f for f in result.free if f in model.params]
    idx_free = [result.free.index(f) for f in names]
    std = []
    for name in names:
        s = result.std.get(name)
        if s is None or not math.isfinite(s):
            raise ParameterError(
                f"parameter {name!r} has no finite standard deviation in this fit "
                "(not identifiable): fix it or fit a richer record before sampling"
            )
        std.append(float(s))
    sd = np.array(std)
    corr = np.asarray(result.correlation, dtype=float)
    corr = corr[np.ix_(idx_free, idx_free)] if corr.size else np.eye(len(names))
    cov = corr * np.outer(sd, sd)
    # Eigen-factor rather than Cholesky: near-singular covariances stay usable.
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    factor = v * np.sqrt(np.clip(w, 0.0, None))

    bounds = result.settings.get("bounds", {})
    is_log = np.array([model.params[nm].scale == "log" for nm in names])
    scale = np.array([
        (bounds[nm][1] - bounds[nm][0]) / 2 if nm in bounds
        else (model.params[nm].upper - model.params[nm].lower) / 2
        for nm in names
    ])
    values = np.array([result.values[nm] for nm in names])
    with np.errstate(divide="ignore"):
        z_hat = np.where(is_log, np.log10(np.abs(values)), values / scale)
    rng = np.random.default_rng(seed)
    Z = z_hat + rng.standard_normal((int(n), len(names))) @ factor.T
    V = np.where(is_log, 10.0 ** Z, Z * scale)
    P = np.tile(result.parameter_vector(), (int(n), 1))
    for j, nm in enumerate(names):
        P[:, model.params.index(nm)] = V[:, j]
    return P


def sample_models(
    result: FitResult,
    n: int = 50,
    seed: int | np.random.Generator | None = 0,
    operating_point: OperatingPoint | None = None,
) -> list[ct.StateSpace]:
    """Linear models of parameter draws from the fit's covariance.

    Parameters
    ----------
    result : FitResult
        A physical fit.
    n : int
        Number of models.
    seed : int, Generator or None
        Seeds the draws (:func:`sample_parameters`).
    operating_point : OperatingPoint, optional
        Where to linearise (default: rest).

    Returns
    -------
    list of control.StateSpace
        As :func:`linearize` returns, one per draw (plot them with
        ``control.bode_plot(models)`` or ``control.step_response``).
    """
    P = sample_parameters(result, n, seed)
    return [linearize(result, operating_point, params=p) for p in P]


def loop_margins(
    plants: ct.LTI | Sequence[ct.LTI], controller: ct.LTI
) -> dict[str, np.ndarray]:
    """Stability margins of ``controller * plant`` for each plant.

    Parameters
    ----------
    plants : control system or sequence of them
        Continuous plants (discretised with zero-order hold at the controller's
        sample time when the controller is discrete) or discrete ones with the
        controller's sample time.
    controller : control system
        SISO controller acting on the error ``r - y``.

    Returns
    -------
    dict of ndarray, one entry per plant
        ``gm`` gain margin [dB] (inf if none), ``pm`` phase margin [deg] (the
        worst gain crossover's), ``sm`` stability (vector) margin ``min |1 + L|``
        [-] (unambiguous when the loop crosses 0 dB several times), ``wcg``
        phase-crossover and ``wcp`` gain-crossover frequencies [rad/s],
        ``stable`` whether the closed loop is stable.
    """
    plants = [plants] if isinstance(plants, ct.LTI) else list(plants)
    cdt = controller.dt
    out: dict[str, list[float]] = {k: [] for k in ("gm", "pm", "sm", "wcg", "wcp", "stable")}
    for plant in plants:
        if cdt and ct.isctime(plant, strict=True):
            plant = discretize(ct.ss(plant), float(cdt), "zoh")
        loop = controller * plant
        with warnings.catch_warnings():
            # python-control notes when it falls back to its frequency-response method.
            warnings.filterwarnings("ignore", message="stability_margins: Falling back")
            # ... and scipy warns about the conditioning of the high-order polynomials.
            warnings.filterwarnings("ignore", category=scipy.signal.BadCoefficients)
            gm, pm, sm, wcg, wcp, _ = ct.stability_margins(loop, method="best")
        cl = ct.feedback(loop, 1)
        poles = cl.poles()
        stable = bool(np.all(np.abs(poles) < 1.0)) if cdt else bool(np.all(poles.real < 0))
        out["gm"].append(20 * math.log10(gm) if np.isfinite(gm) and gm > 0 else math.inf)
        out["pm"].append(float(pm))
        out["sm"].append(float(sm))
        out["wcg"].append(float(wcg))
        out["wcp"].append(float(wcp))
        out["stable"].append(stable)
    return {k: np.array(v) for k, v in out.items()}


# --- closed loop ----------------------------------------------------------------------


@dataclass
class ClosedLoopResponse:
    """Time histories of a closed-loop run.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Sample instants [s].
    r : ndarray, shape (N,)
        Reference [output unit, deg for the angle].
    y : ndarray, shape (N,)
        Measured output at the sample instants (noise included) [output unit].
    u : ndarray, shape (N,)
        Valve current applied over each sample (after the limits) [mA].
    u_demand : ndarray, shape (N,)
        Controller output before the limits [mA].
    x : ndarray, shape (N, nx)
        Plant state at the sample instants.
    state_names : list of str
        Names of the columns of ``x``.
    """

    t: np.ndarray
    r: np.ndarray
    y: np.ndarray
    u: np.ndarray
    u_demand: np.ndarray
    x: np.ndarray
    state_names: list[str] = field(default_factory=list)

    def step_info(self, settling: float = 0.02, tail: float = 0.1) -> dict[str, float]:
        """Step-response figures, for a reference that steps once at the start.

        Parameters
        ----------
        settling : float
            Settling band as a fraction of the step size.
        tail : float
            Fraction of the record at its end over which the steady-state error
            is averaged.

        Returns
        -------
        dict
            ``rise_time`` 10-90 % [s], ``overshoot`` [% of the step],
            ``settling_time`` [s] (last exit from the band), ``steady_state_error``
            ``mean(r - y)`` over the tail [output unit], ``peak_current`` max
            ``|u|`` [mA]. NaN where undefined (e.g. never reaching 90 %).
        """
        y0, r1 = float(self.y[0]), float(self.r[-1])
        step = r1 - y0
        if step == 0:
            raise ParameterError("step_info needs a reference that differs from the start")
        frac = (self.y - y0) / step
        t = self.t - self.t[0]
        i10 = np.flatnonzero(frac >= 0.1)
        i90 = np.flatnonzero(frac >= 0.9)
        rise = float(t[i90[0]] - t[i10[0]]) if i90.size and i10.size else math.nan
        overshoot = max(0.0, float(frac.max() - 1.0) * 100.0)
        outside = np.flatnonzero(np.abs(frac - 1.0) > settling)
        if outside.size == 0:
            settle = 0.0
        elif outside[-1] == frac.size - 1:
            settle = math.nan
        else:
            settle = float(t[outside[-1] + 1])
        k = max(1, int(round(tail * self.t.size)))
        return {
            "rise_time": rise,
            "overshoot": overshoot,
            "settling_time": settle,
            "steady_state_error": float(np.mean(self.r[-k:] - self.y[-k:])),
            "peak_current": float(np.max(np.abs(self.u))),
        }

    def tracking_error(self, skip: float = 0.0) -> dict[str, float]:
        """RMS and largest absolute ``r - y`` [output unit] after ``skip`` seconds."""
        m = (self.t - self.t[0]) >= skip
        e = self.r[m] - self.y[m]
        return {"rms": float(np.sqrt(np.mean(e**2))), "max": float(np.max(np.abs(e)))}


ControllerFn = Callable[[float, float, float], float]


class ClosedLoop:
    """A plant under a discrete controller with actuator limits, simulated sample by sample.

    Parameters
    ----------
    plant : FitResult, Model, or control system
        The nonlinear fitted model (a :class:`FitResult`, with all its parts and
        effects), a model (nominal parameters unless ``params``), or a linear
        python-control system (continuous: discretised with zero-order hold at
        ``dt``; discrete: its sample time must be ``dt``), e.g. the design model,
        so both are run by the same loop.
    controller : control system or callable
        A discrete python-control system with sample time ``dt``: one input (the
        error ``r - y``) or two (``[r, y]``, e.g. an observer-based state
        feedback), one output (the current demand [mA]); or a callable
        ``controller(t, r, y) -> u`` [s, deg, deg -> mA] called once per sample
        (keep its state in a closure or object).
    dt : float
        Controller sample period [s]; the current is held over each period.
    params : array or dict, optional
        Parameters of a physical plant (as in :func:`linearize`).
    current_limit : float or (float, float), optional
        Saturation of the applied current [mA]: ``I_max`` (symmetric) or
        ``(I_min, I_max)``.
    rate_limit : float, optional
        Largest change of the current per second [mA/s].
    noise : float
        Standard deviation of Gaussian noise on the measured output [deg].
    seed : int or None
        Seeds the measurement noise.
    substeps : int or "auto"
        RK4 steps per sample for a physical plant (``"auto"``: spectral radius
        at rest times substep <= 0.25, as :class:`hhra_phys.simulate.Simulator`).

    Notes
    -----
    At sample ``k`` the output ``y[k]`` is measured, the controller computes
    ``u[k]``, the limits are applied, and the plant is integrated over
    ``[t_k, t_k + dt]`` with ``u[k]`` held. A linear controller does not know
    about the limits (no anti-windup): give a callable if you need one.
    """

    def __init__(
        self,
        plant: FitResult | Model | ct.LTI,
        controller: ct.LTI | ControllerFn,
        dt: float,
        *,
        params: np.ndarray | Mapping[str, float] | None = None,
        current_limit: float | tuple[float, float] | None = None,
        rate_limit: float | None = None,
        noise: float = 0.0,
        seed: int | None = 0,
        substeps: int | str = "auto",
    ) -> None:
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise ParameterError(f"dt must be a positive sample period in s, got {dt!r}")
        self.dt = float(dt)
        if current_limit is None:
            self.limits = (-math.inf, math.inf)
        elif np.ndim(current_limit) == 0:
            lim = float(current_limit)  # type: ignore[arg-type]
            if not lim > 0:
                raise ParameterError(f"current_limit must be positive, got {lim}")
            self.limits = (-lim, lim)
        else:
            lo, hi = (float(v) for v in current_limit)  # type: ignore[union-attr]
            if not lo < hi:
                raise ParameterError(f"current_limit (lo, hi) needs lo < hi, got {(lo, hi)}")
            self.limits = (lo, hi)
        if rate_limit is not None and not rate_limit > 0:
            raise ParameterError(f"rate_limit must be positive in mA/s, got {rate_limit!r}")
        self.rate_limit = rate_limit
        if not (math.isfinite(noise) and noise >= 0):
            raise ParameterError(f"noise must be a non-negative standard deviation, got {noise}")
        self.noise = float(noise)
        self.seed = seed
        self._setup_controller(controller)
        if isinstance(plant, ct.LTI):
            self._setup_linear(plant)
        elif isinstance(plant, (FitResult, Model)):
            self._setup_physical(plant, params, substeps)
        else:
            raise ParameterError(
                f"plant must be a FitResult, Model or python-control system, "
                f"got {type(plant).__name__}"
            )

    # -- set-up ------------------------------------------------------------------------
    def _setup_controller(self, controller: ct.LTI | ControllerFn) -> None:
        self._ctrl_fn: ControllerFn | None = None
        if isinstance(controller, ct.LTI):
            if ct.isctime(controller, strict=True):
                raise ParameterError(
                    "controller is continuous-time: discretize it first, e.g. "
                    "hhra_phys.control.discretize(controller, dt, 'tustin')"
                )
            if controller.dt is not True and abs(float(controller.dt) - self.dt) > 1e-12:
                raise ParameterError(
                    f"controller sample time {controller.dt} s differs from dt = {self.dt} s"
                )
            c = ct.ss(controller)
            if c.noutputs != 1 or c.ninputs not in (1, 2):
                raise ParameterError(
                    "controller must have one output (current) and one input (error r - y) "
                    f"or two ([r, y]); got {c.ninputs} inputs, {c.noutputs} outputs"
                )
            self._ctrl = (np.asarray(c.A), np.asarray(c.B), np.asarray(c.C), np.asarray(c.D))
        elif callable(controller):
            self._ctrl_fn = controller
        else:
            raise ParameterError(
                "controller must be a discrete python-control system or a callable "
                f"(t, r, y) -> u; got {type(controller).__name__}"
            )

    def _setup_linear(self, plant: ct.LTI) -> None:
        sys = ct.ss(plant)
        if sys.ninputs != 1 or sys.noutputs != 1:
            raise ParameterError("a linear plant must be SISO (current -> output)")
        if ct.isctime(sys, strict=True):
            sys = sys.sample(self.dt, method="zoh")
        elif sys.dt is not True and abs(float(sys.dt) - self.dt) > 1e-12:
            raise ParameterError(f"plant sample time {sys.dt} s differs from dt = {self.dt} s")
        Ad, Bd, Cd, Dd = (np.asarray(m) for m in (sys.A, sys.B, sys.C, sys.D))
        self.state_names = list(sys.state_labels)
        self.nx = Ad.shape[0]
        self.model = None

        def step(x: np.ndarray, ulags: np.ndarray) -> np.ndarray:
            return Ad @ x + Bd[:, 0] * ulags[0]

        def out(x: np.ndarray, ulags: np.ndarray) -> float:
            return float(Cd[0] @ x + Dd[0, 0] * ulags[0])

        self._step, self._out, self._x0 = step, out, np.zeros(self.nx)
        self._n_lags = 0

    def _setup_physical(
        self,
        plant: FitResult | Model,
        params: np.ndarray | Mapping[str, float] | None,
        substeps: int | str,
    ) -> None:
        model, p, _ = _physical(plant, params)
        self.model = model
        self.params = p
        self.state_names = model.state_names
        self.nx = model.nx
        fns = model.functions(self.dt)
        if substeps == "auto":
            jac = np.array(fns["jac"](model.x0(), np.zeros(model.n_lags + 1), p))
            rho = float(np.max(np.abs(np.linalg.eigvals(jac)))) if jac.size else 0.0
            m = max(2, math.ceil(rho * self.dt / RK4_RHO_H))
        elif isinstance(substeps, (int, np.integer)) and substeps >= 1:
            m = int(substeps)
        else:
            raise ParameterError(f"substeps must be a positive integer or 'auto', got {substeps!r}")
        self.substeps = m
        f, hfun = fns["f"], fns["h"]
        x = ca.SX.sym("x", model.nx)
        u = ca.SX.sym("u", model.n_lags + 1)
        h = self.dt / m
        xk = rk4(f, x, u, p, h, m)
        step_fn = ca.Function("cl_step", [x, u], [xk], {"cse": True})
        out_fn = ca.Function("cl_out", [x, u], [hfun(x, u, p)])
        self._n_lags = model.n_lags
        self._step = lambda xv, ulags: np.asarray(step_fn(xv, ulags)).ravel()
        self._out = lambda xv, ulags: float(out_fn(xv, ulags))
        self._x0 = model.x0()

    # -- running -------------------------------------------------------------------------
    def run(
        self,
        reference: np.ndarray | Callable[[np.ndarray], np.ndarray],
        duration: float | None = None,
        x0: np.ndarray | Mapping[str, float] | None = None,
    ) -> ClosedLoopResponse:
        """Simulate the loop for a reference.

        Parameters
        ----------
        reference : array or callable
            Reference at the sample instants [deg]: an array (its length sets the
            run length) or a function of the time array [s] (needs ``duration``).
        duration : float, optional
            Run length [s] for a callable reference.
        x0 : array or dict, optional
            Initial plant state (model units; default rest, or the linear plant's
            zero state); a dict sets states by name.

        Returns
        -------
        ClosedLoopResponse
        """
        t, r = self._reference(reference, duration)
        n = t.size
        x = self._initial_state(x0)

        rng = np.random.default_rng(self.seed)
        noise = self.noise * rng.standard_normal(n) if self.noise else np.zeros(n)
        lo, hi = self.limits
        du_max = self.rate_limit * self.dt if self.rate_limit else math.inf
        ulags = np.zeros(self._n_lags + 1)
        xc = np.zeros(self._ctrl[0].shape[0]) if self._ctrl_fn is None else None
        Y, U, Ud, X = np.empty(n), np.empty(n), np.empty(n), np.empty((n, self.nx))
        u_prev = 0.0
        for k in range(n):
            X[k] = x
            yk = self._out(x, ulags) + noise[k]
            if not math.isfinite(yk):
                raise ParameterError(f"the closed loop diverged at t = {t[k]:.4g} s")
            if self._ctrl_fn is not None:
                ud = float(self._ctrl_fn(float(t[k]), float(r[k]), yk))
            else:
                Ac, Bc, Cc, Dc = self._ctrl
                v = np.array([r[k] - yk]) if Bc.shape[1] == 1 else np.array([r[k], yk])
                ud = float(Cc[0] @ xc + Dc[0] @ v)
                xc = Ac @ xc + Bc @ v
            uk = min(max(ud, lo), hi)
            uk = min(max(uk, u_prev - du_max), u_prev + du_max)
            ulags = np.concatenate([[uk], ulags[:-1]])
            x = self._step(x, ulags)
            Y[k], U[k], Ud[k] = yk, uk, ud
            u_prev = uk
        return ClosedLoopResponse(t, r, Y, U, Ud, X, list(self.state_names))

    def _reference(
        self, reference: np.ndarray | Callable[[np.ndarray], np.ndarray], duration: float | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Sample instants [s] and reference [deg] of :meth:`run` (at least 2 finite samples)."""
        if callable(reference):
            if duration is None or not duration > 0:
                raise ParameterError("duration [s] is required with a callable reference")
            n = int(round(duration / self.dt)) + 1
            t = np.arange(n) * self.dt
            r = np.asarray(reference(t), dtype=float) * np.ones(n)
        else:
            r = np.asarray(reference, dtype=float).ravel()
            n = r.size
            t = np.arange(n) * self.dt
        if n < 2 or not np.isfinite(r).all():
            raise ParameterError("reference must have at least 2 finite samples")
        return t, r

    def _initial_state(self, x0: np.ndarray | Mapping[str, float] | None) -> np.ndarray:
        """The plant's initial state of :meth:`run`: rest, set by name, or a whole vector."""
        x = self._x0.copy()
        if isinstance(x0, Mapping):
            for name, value in x0.items():
                if name not in self.state_names:
                    raise ParameterError(
                        f"x0 names unknown state {name!r}; states: {', '.join(self.state_names)}"
                    )
                x[self.state_names.index(name)] = float(value)
        elif x0 is not None:
            x = np.asarray(x0, dtype=float).ravel().copy()
            if x.shape != (self.nx,):
                raise ParameterError(f"x0 must have shape ({self.nx},), got {x.shape}")
        return x

    def step(
        self, amplitude: float, duration: float, x0: np.ndarray | Mapping[str, float] | None = None
    ) -> ClosedLoopResponse:
        """Response to a reference step of ``amplitude`` [deg] at t = 0 lasting ``duration`` [s].

        The plant starts at rest (or ``x0``); the step is relative to zero.
        """
        n = int(round(duration / self.dt)) + 1
        return self.run(np.full(n, float(amplitude)), x0=x0)
