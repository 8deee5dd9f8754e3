"""``hhra-phys simulate``: write a record of the built-in simulated rig."""

from __future__ import annotations

import argparse
from typing import Any

from hhra_phys.cli._common import report_error
from hhra_phys.cli._guards import seed
from hhra_phys.data import check_save_path, save
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
    p.add_argument("--out", required=True, metavar="FILE.csv",
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
                        "e.g. --effect coulomb_friction:g_coulomb=8 (repeatable)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.set_defaults(func=run)


def _parse_effects(items: list[str] | None) -> dict[str, dict[str, float]]:
    """``["name:param=value,param=value", ...]`` -> ``{name: {param: value}}``."""
    from hhra_phys.effects import LIBRARY

    out: dict[str, dict[str, float]] = {}
    for item in items or []:
        name, _, rest = item.partition(":")
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
        out[name] = values
    return out


def run(args: argparse.Namespace) -> int:
    """Simulate and write the record; returns the exit code."""
    try:
        check_save_path(args.out, args.overwrite)  # before simulating
        effects = _parse_effects(args.effect)
        if args.generator == "reference":
            from hhra_phys.reference import reference_record

            ds = reference_record(seed=args.seed, noise_deg=args.noise, duration=args.duration,
                                  fs=args.fs, amplitude=args.amplitude,
                                  quantization=args.quantization, effects=effects or None)
        else:
            if effects:
                raise ParameterError("--effect needs --generator reference")
            ds = simulate_rig(seed=args.seed, noise=args.noise, duration=args.duration,
                              fs=args.fs, amplitude=args.amplitude,
                              quantization=args.quantization)
        path = save(ds, args.out, overwrite=args.overwrite)
    except (HHRAError, OSError) as exc:
        return report_error("simulate", exc)
    print(f"wrote {path} ({len(ds)} samples, {ds.duration:.2f} s, angle "
          f"{ds.y.min():.1f}..{ds.y.max():.1f} deg)")
    return 0
