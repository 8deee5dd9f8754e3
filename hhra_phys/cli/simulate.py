"""``hhra-phys simulate``: write a record of the built-in simulated rig."""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

from hhra_phys.cli._common import report_error
from hhra_phys.cli._guards import all_or_nothing, check_size, output_path, seed
from hhra_phys.data import Dataset, check_save_path, save, sidecar_path
from hhra_phys.errors import HHRAError, ParameterError
from hhra_phys.models.hhra.rig import DEFAULT_AMPLITUDE_MA, DEFAULT_NOISE_DEG, simulate_rig


def register(subparsers: Any) -> None:
    """Add the ``simulate`` sub-command."""
    p = subparsers.add_parser(
        "simulate",
        help="simulate the paper's experiment on the built-in rig and write CSV",
        description=(
            "Run the simulated rig (250 Hz, irregular multi-level steps of valve current from the "
            "inverse-repeat M-sequence, angle in degrees) and write columns t,u,y plus a JSON "
            "side-car with the true parameters."
        ),
    )
    p.add_argument("--out", type=output_path, required=True, metavar="FILE.csv",
                   help="output file (.csv with a .json side-car, or .npz)")
    p.add_argument("--seed", type=seed, default=0, help="seed of excitation and noise (default 0)")
    p.add_argument("--noise", type=float, default=DEFAULT_NOISE_DEG, metavar="DEG",
                   help=f"angle noise standard deviation in deg (default {DEFAULT_NOISE_DEG})")
    p.add_argument("--duration", type=float, default=20.0, metavar="S",
                   help="record length in s (default 20)")
    p.add_argument("--fs", type=float, default=250.0, help="sample rate in Hz (default 250)")
    p.add_argument("--amplitude", type=float, default=DEFAULT_AMPLITUDE_MA, metavar="MA",
                   help=f"largest valve current in mA (default {DEFAULT_AMPLITUDE_MA})")
    p.add_argument("--quantization", type=float, default=None, metavar="DEG",
                   help="encoder resolution in deg (default: none)")
    p.add_argument("--generator", choices=("model", "reference"), default="model",
                   help="'model': the package's compiled model (default); 'reference': the "
                        "independent NumPy/SciPy implementation (hhra_phys.reference), so that "
                        "a fit is not the model checked against itself")
    p.add_argument("--effect", action="append", default=None, metavar="NAME[:PARAM=VALUE,...]",
                   help="with --generator reference: hide a library effect in the record, "
                        "e.g. --effect coulomb_friction:g_coulomb=8 (repeatable, each effect "
                        "once)")
    p.add_argument("--intersample", choices=("zoh", "foh"), default=None,
                   help="with --generator reference: what the valve current does between "
                        "samples, 'zoh' held (default, a DAC) or 'foh' linear to the next "
                        "sample; the side-car records it")
    p.add_argument("--noise-ar", type=float, default=0.0, metavar="A",
                   help="with --generator reference: coloured (AR(1)) angle noise with this "
                        "coefficient in (-1, 1), --noise its standard deviation (default 0: white)")
    p.add_argument("--drift", type=float, default=0.0, metavar="DEG",
                   help="with --generator reference: a sensor drift of DEG over the record, "
                        "linear in time (default 0)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.set_defaults(func=run)


def _parse_effects(items: list[str] | None) -> dict[str, dict[str, float]]:
    """``["name:param=value,param=value", ...]`` -> ``{name: {param: value}}``."""
    from hhra_phys.effects import LIBRARY

    out: dict[str, dict[str, float]] = {}
    for item in items or []:
        name, _, rest = item.partition(":")
        if name in out:  # the second would silently replace the first
            first = next(i for i in items or [] if i.partition(":")[0] == name)
            raise ParameterError(f"--effect {name} is given twice ({first!r} and {item!r}); "
                                 "an effect acts once: give it once")
        if name not in LIBRARY:
            raise ParameterError(f"--effect {item!r}: unknown effect {name!r}; library: "
                                 f"{', '.join(LIBRARY)}")
        values: dict[str, float] = {}
        for pair in filter(None, rest.split(",")):
            key, eq, value = pair.partition("=")
            try:
                values[key.strip()] = float(value)
            except ValueError:
                raise ParameterError(
                    f"--effect {item!r}: expected PARAM=VALUE, got {pair!r}") from None
            if not eq:
                raise ParameterError(f"--effect {item!r}: expected PARAM=VALUE, got {pair!r}")
        check_effect_values(item, name, values)
        out[name] = values
    return out


def check_effect_values(item: str, name: str, values: dict[str, float]) -> None:
    """Every parameter of ``--effect NAME:...`` is one the effect has, inside its box.

    Raises
    ------
    ParameterError
        Naming the ``--effect`` item, the parameter and its box (or the parameters
        the effect has).
    """
    import math

    from hhra_phys.effects import make_effect

    params = {p.name: p for p in make_effect(name).parameters}
    for key, value in values.items():
        if key not in params:
            raise ParameterError(f"--effect {item!r}: {name} has no parameter {key!r}; its "
                                 f"parameters: {', '.join(params) or 'none'}")
        par = params[key]
        if not (math.isfinite(value) and par.lower <= value <= par.upper):
            raise ParameterError(
                f"--effect {item!r}: {key}={value:g} is outside its box "
                f"[{par.lower:g}, {par.upper:g}] {par.unit} (the values the library fits)")
    lacking = [k for k in params if k not in values]
    if lacking:
        raise ParameterError(f"--effect {item!r}: give every parameter of {name}; missing: "
                             f"{', '.join(f'{k}=VALUE' for k in lacking)}")


#: Records longer than this [samples] get a time estimate before the reference run.
ESTIMATE_ABOVE = 100_000


def say_time_estimate(args: argparse.Namespace, effects: dict[str, dict[str, float]]) -> None:
    """Time the reference implementation on 2000 samples and print the estimate for the
    whole record when it is over a minute (it integrates in Python, about 0.1 ms a sample,
    and prints nothing while it runs)."""
    import time

    from hhra_phys.reference import reference_record

    n = args.duration * args.fs
    if n <= ESTIMATE_ABOVE:
        return
    short = 2000 / args.fs
    start = time.perf_counter()
    reference_record(seed=args.seed, noise_deg=args.noise, duration=short, fs=args.fs,
                     amplitude=args.amplitude, effects=effects or None)
    seconds = (time.perf_counter() - start) * n / 2000
    if seconds > 60:
        print(f"simulate: {n:.3g} samples with the reference implementation, estimated "
              f"{seconds / 60:.0f} min on this machine now (--duration and --fs set it; "
              "Ctrl-C stops it, writing nothing)", file=sys.stderr, flush=True)


def check_settings(args: argparse.Namespace) -> None:
    """The numbers of a simulated record, before anything is simulated.

    Raises
    ------
    ParameterError
        A value outside what the rig can mean (naming the flag and the range), or a
        record whose memory would exceed the budget (:func:`check_size`).
    """
    import math

    from hhra_phys.models.hhra.defaults import PLAUSIBLE, PLAUSIBLE_FS

    for flag, value in (("--duration", args.duration), ("--fs", args.fs),
                        ("--amplitude", args.amplitude)):
        if not (math.isfinite(value) and value > 0):
            raise ParameterError(f"{flag} must be a finite number > 0, got {value:g}")
    if not (math.isfinite(args.noise) and args.noise >= 0):
        raise ParameterError(f"--noise must be a standard deviation >= 0 in deg, got "
                             f"{args.noise:g}")
    if args.quantization is not None and not (math.isfinite(args.quantization)
                                              and args.quantization > 0):
        raise ParameterError(f"--quantization must be a resolution > 0 in deg, got "
                             f"{args.quantization:g}")
    lo, hi = PLAUSIBLE_FS
    if not lo <= args.fs <= hi:
        raise ParameterError(f"--fs {args.fs:g} Hz: the rig is sampled between {lo:g} and "
                             f"{hi:g} Hz (the paper's 250 Hz)")
    top = PLAUSIBLE["input"].high
    if args.amplitude > top:
        raise ParameterError(f"--amplitude {args.amplitude:g} mA: above the {top:g} mA of the "
                             "largest servo-valve rated currents")
    check_size(args.duration * args.fs, f"--duration {args.duration:g} s at --fs {args.fs:g} Hz")


def run(args: argparse.Namespace) -> int:
    """Simulate and write the record; returns the exit code."""
    try:
        check_save_path(args.out, args.overwrite)  # before simulating
        check_settings(args)
        if args.effect and args.generator != "reference":
            raise ParameterError("--effect needs --generator reference")
        effects = _parse_effects(args.effect)
        _check_noise_model(args)
        if args.generator == "reference":
            ds = _reference(args, effects)
        else:
            ds = _builtin(args, effects)
        # Ctrl-C or SIGTERM between the CSV and its side-car: neither stays.
        with all_or_nothing([args.out, sidecar_path(args.out)]):
            path = save(ds, args.out, overwrite=args.overwrite)
    except ParameterError as exc:
        if "cannot hold" not in str(exc):  # the excitation's words for too few samples
            return report_error("simulate", exc)
        return report_error("simulate", ParameterError(
            f"--duration {args.duration:g} s at --fs {args.fs:g} Hz gives "
            f"{round(args.duration * args.fs)} samples, too few for the excitation ({exc}); "
            "lengthen --duration or raise --fs"))
    except (HHRAError, OSError) as exc:
        return report_error("simulate", exc)
    except ValueError as exc:  # the reference implementation's own checks
        return report_error("simulate", ParameterError(f"--generator reference: {exc}"))
    peak = float(abs(ds.u).max())
    if peak < 0.999 * args.amplitude:
        print(f"note: --amplitude {args.amplitude:g} mA would turn the shaft past its stroke; "
              f"the current was scaled to {peak:.4g} mA", file=sys.stderr)
    print(f"wrote {path} ({len(ds)} samples, {ds.duration:.2f} s, angle "
          f"{ds.y.min():.1f}..{ds.y.max():.1f} deg)")
    return 0


def _check_noise_model(args: argparse.Namespace) -> None:
    """Refuse an AR(1) factor outside (-1, 1) (not stationary) and a drift that is not finite."""
    if not (math.isfinite(args.noise_ar) and abs(args.noise_ar) < 1):
        raise ParameterError(f"--noise-ar must lie in (-1, 1), got {args.noise_ar}")
    if not math.isfinite(args.drift):
        raise ParameterError(f"--drift must be finite, got {args.drift}")


def _reference(args: argparse.Namespace, effects: dict[str, dict[str, float]]) -> Dataset:
    """The record of the independently written reference rig (``--generator reference``)."""
    from hhra_phys.reference import reference_record

    say_time_estimate(args, effects)
    return reference_record(seed=args.seed, noise_deg=args.noise, duration=args.duration,
                            fs=args.fs, amplitude=args.amplitude,
                            quantization=args.quantization, effects=effects or None,
                            intersample=args.intersample or "zoh",
                            noise_ar=args.noise_ar, drift_deg=args.drift)


def _builtin(args: argparse.Namespace, effects: dict[str, dict[str, float]]) -> Dataset:
    """The record of the built-in rig, refusing the reference rig's own options."""
    if effects or args.noise_ar or args.drift:
        raise ParameterError("--effect, --noise-ar and --drift need --generator "
                             "reference")
    if args.intersample not in (None, "zoh"):
        raise ParameterError("--intersample foh needs --generator reference (the "
                             "built-in rig's valve current is held by its DAC)")
    return simulate_rig(seed=args.seed, noise=args.noise, duration=args.duration,
                        fs=args.fs, amplitude=args.amplitude,
                        quantization=args.quantization)
