"""The built-in simulated test rig.

It reproduces the reference paper's identification experiment (section 4.3):
250 Hz sampling for 20 s, the valve driven by the "irregular continuous step"
signal built from the 4th-order inverse-repeat M-sequence (here with several
amplitude levels, see :func:`hhra_phys.excitation.irregular_steps`), the shaft
angle measured in degrees by an encoder with seeded Gaussian noise and optional
quantisation. The plant is the HHRA with the physical parameters of
:class:`~hhra_phys.models.hhra.physical.PhysicalParameters` (a mid-size actuator on an
inertial load), optionally with undeclared effects added.

The truth is simulated with four times the substeps the fitting simulator
uses, so the rig's integration error stays far below its noise and fits are
not judged on the simulator's own discretisation.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.errors import ParameterError
from hhra_phys.excitation import irregular_steps, samples
from hhra_phys.models.hhra.model import HHRAModel
from hhra_phys.models.hhra.physical import PhysicalParameters
from hhra_phys.models.hydraulics import perturb_fields
from hhra_phys.parts import Part
from hhra_phys.simulate import Simulator

__all__ = [
    "default_input",
    "angle_estimate",
    "perturbed_physical",
    "rig_model",
    "simulate_rig",
    "DEFAULT_AMPLITUDE_MA",
    "DEFAULT_NOISE_DEG",
]

#: Default measurement noise of the rig's angle (standard deviation) [deg].
DEFAULT_NOISE_DEG = 0.05
#: Largest valve current step of the default experiment [mA].
DEFAULT_AMPLITUDE_MA = 1.0
#: The input is scaled down if a linear estimate of the angle exceeds this [deg].
ANGLE_LIMIT_DEG = 80.0


def default_input(
    duration: float = 20.0,
    fs: float = 250.0,
    seed: int | np.random.Generator | None = 0,
    amplitude: float = DEFAULT_AMPLITUDE_MA,
    levels: int = 4,
    physical: PhysicalParameters | None = None,
) -> np.ndarray:
    """The rig's valve current [mA]: irregular multi-level steps, angle kept in range.

    One period of the paper's inverse-repeat M-sequence per 20 s (so holds of
    about 0.67 s, varied by +-50 %), ``levels`` amplitude levels up to
    ``amplitude``. The inverse-repeat form has zero mean, so the shaft returns
    to its start; if a linear estimate of the angle (steady-state velocity gain
    times the integral of the current) would exceed +-80 deg, the whole signal is
    scaled down so it does not.

    Parameters
    ----------
    duration : float
        Record length [s].
    fs : float
        Sample rate [Hz].
    seed : int, Generator or None
        Drives hold lengths and level order.
    amplitude : float
        Largest current [mA].
    levels : int
        Number of amplitude levels (at least 2 recommended: a binary signal cannot
        tell a dead zone from a gain change).
    physical : PhysicalParameters, optional
        Plant used for the angle estimate (default: the rig's).

    Returns
    -------
    ndarray, shape (round(duration*fs),)
    """
    n = samples(duration, fs)
    periods = max(1, int(round(duration / 20.0)))
    u = irregular_steps(n, levels=levels, amplitude=amplitude, n_periods=periods, seed=seed)
    angle = angle_estimate(u, fs, physical)
    half_range = 0.5 * float(angle.max() - angle.min())
    if half_range > ANGLE_LIMIT_DEG:
        u = u * (ANGLE_LIMIT_DEG / half_range)
    return u


def angle_estimate(
    u: np.ndarray, fs: float, physical: PhysicalParameters | None = None
) -> np.ndarray:
    """Linear estimate of the angle [deg] a current record drives, starting from 0.

    Steady-state velocity gain ``kv/c`` of the paper's transfer function times
    the running integral of the current.
    """
    tf = (physical or PhysicalParameters()).tf_coefficients()
    gain = tf["kv"] / tf["c"]  # steady velocity per current [rad/s/mA]
    angle = np.degrees(np.cumsum(u) / fs * gain)
    return angle - angle[0]


def perturbed_physical(
    seed: int | np.random.Generator | None = 0,
    spread: float = 2.5,
    min_factor: float = 1.3,
    base: PhysicalParameters | None = None,
) -> PhysicalParameters:
    """A rig whose truth lies away from the model's nominal values and box centre.

    The fitting box of every group is centred (in log scale) on the nominal
    value, and H-GWO favours its coordinate origin, so recovery tests with the
    truth at the nominal values would flatter the method. This multiplies the
    inertia ``J``, the rotary damping ``B_m``, the bulk modulus ``beta_e``, the
    valve gain ``k_x`` and the leakage ``C_t`` by log-uniform factors in
    ``[1/spread, spread]`` whose magnitude is at least ``min_factor``.

    Parameters
    ----------
    seed : int, Generator or None
        Seed of the factors.
    spread : float
        Largest factor (> min_factor).
    min_factor : float
        Smallest factor magnitude (>= 1).
    base : PhysicalParameters, optional
        Rig to perturb (default: the built-in one).
    """
    return perturb_fields(base or PhysicalParameters(), ("J", "B_m", "beta_e", "k_x", "C_t"),
                          seed, spread, min_factor)


def rig_model(
    physical: PhysicalParameters | None = None,
    valve: str = "orifice",
    effects: Sequence[Part] = (),
    effect_params: Mapping[str, float] | None = None,
) -> tuple[HHRAModel, np.ndarray]:
    """The rig's true model and parameter vector.

    Parameters
    ----------
    physical : PhysicalParameters, optional
        Physical truth (default: the built-in rig).
    valve : {"orifice", "linear"}
        Valve law of the truth.
    effects : sequence of Part
        Undeclared effects of the plant (e.g. from :mod:`hhra_phys.effects`).
    effect_params : dict, optional
        True values of the effects' parameters (default: their nominal values).
    """
    phys = physical or PhysicalParameters()
    groups = {k: v for k, v in phys.groups().items() if k != "g_kp"}
    model = HHRAModel(valve=valve, effects=effects)  # type: ignore[arg-type]
    values = {k: v for k, v in groups.items() if k in model.params}
    values.update(effect_params or {})
    model = model.with_nominal(values)  # type: ignore[assignment]
    return model, model.nominal()  # type: ignore[return-value]


def simulate_rig(
    seed: int = 0,
    noise: float = DEFAULT_NOISE_DEG,
    duration: float = 20.0,
    fs: float = 250.0,
    amplitude: float = DEFAULT_AMPLITUDE_MA,
    levels: int = 4,
    u: np.ndarray | None = None,
    quantization: float | None = None,
    physical: PhysicalParameters | None = None,
    valve: str = "orifice",
    effects: Sequence[Part] = (),
    effect_params: Mapping[str, float] | None = None,
) -> Dataset:
    """Run the simulated rig and return the measured record.

    Parameters
    ----------
    seed : int
        Seeds the excitation (hold lengths, levels) and the measurement noise.
    noise : float
        Standard deviation of the Gaussian angle noise [deg] (0 for noise-free).
    duration : float
        Record length [s] (paper: 20 s).
    fs : float
        Sample rate [Hz] (paper: 250 Hz).
    amplitude : float
        Largest valve current [mA].
    levels : int
        Number of amplitude levels of the excitation.
    u : array, optional
        Use this valve current [mA] instead of the default excitation.
    quantization : float, optional
        Encoder resolution [deg] (e.g. ``360/2**13``); the angle is rounded to it
        after the noise is added.
    physical : PhysicalParameters, optional
        Physical truth (default: the built-in rig).
    valve : {"orifice", "linear"}
        Valve law of the truth.
    effects : sequence of Part
        Undeclared effects in the plant.
    effect_params : dict, optional
        True values of the effects' parameters.

    Returns
    -------
    Dataset
        ``t`` [s], ``u`` [mA], ``y`` [deg]; ``metadata`` holds the truth:
        ``true_params`` (identifiable groups and effect parameters by name),
        ``physical`` (SI symbols), ``effects``, ``noise_deg``, ``seed`` and the
        substeps used.
    """
    if not (math.isfinite(noise) and noise >= 0):
        raise ParameterError(f"noise must be a non-negative standard deviation in deg, got {noise}")
    if quantization is not None and not quantization > 0:
        raise ParameterError(
            f"quantization must be a positive resolution in deg, got {quantization}"
        )
    phys = physical or PhysicalParameters()
    rng = np.random.default_rng(seed)
    if u is None:
        u = default_input(duration, fs, rng, amplitude, levels, phys)
    else:
        u = np.asarray(u, dtype=float)
    model, truth = rig_model(phys, valve, effects, effect_params)
    fit_sim = Simulator(model, fs=fs)
    sim = Simulator(model, fs=fs, substeps=4 * fit_sim.substeps)
    # Start the shaft so that the stroke is centred on 0 deg (the paper's -90..90 range).
    est = angle_estimate(u, fs, phys)
    theta0 = -math.radians(0.5 * float(est.max() + est.min()))
    x0 = model.x0()
    x0[model.state_names.index("theta")] = theta0
    y_true = sim.simulate(u, truth, x0=x0)
    if not np.isfinite(y_true).all():
        raise ParameterError("the rig's truth could not be simulated stably; check the parameters")
    y = y_true + noise * rng.standard_normal(u.size)
    if quantization:
        y = np.round(y / quantization) * quantization
    meta: dict[str, Any] = {
        "generator": "hhra_phys.models.hhra.rig.simulate_rig",
        "seed": seed,
        "noise_deg": noise,
        "quantization_deg": quantization,
        "valve": valve,
        "true_params": model.params.as_dict(truth),
        "physical": phys.to_dict(),
        "effects": [type(e).__name__ for e in effects],
        "substeps": sim.substeps,
        "x0": dict(zip(model.state_names, x0.tolist(), strict=True)),
    }
    return Dataset.from_arrays(
        u, y, fs=fs, metadata=meta, name=f"rig-seed{seed}",
        input_name="current", input_unit="mA", output_name="angle", output_unit="deg",
    )
