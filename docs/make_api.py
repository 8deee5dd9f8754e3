"""Write docs/api.md, the API reference, from the docstrings of the hhra_phys package.

Usage::

    python docs/make_api.py            # (re)write docs/api.md
    python docs/make_api.py --check    # exit 1 if docs/api.md is not current
    python docs/make_api.py --out FILE

Every public module of ``hhra_phys`` (not the ``cli`` package, whose reference is
``hhra-phys COMMAND --help``) gets a section with the first paragraph of its docstring,
then its public classes (with their public methods and properties) and functions, each
with its signature and the summary paragraph of its docstring: a map of the API to find
things in (:data:`MAX_LINES` at most); the whole docstrings, with parameters, shapes and
units, are one ``help(...)`` away. A module that is the first home of names now defined
elsewhere (``__moved_to__``, kept so that old imports work) lists them only. Public means:
listed in the module's curated ``__all__``; a module without one is an error, so that
nothing becomes public API by accident. The output depends only on the code, so ``--check`` (run by
``tests/integration/test_guide.py``) tells whether it was regenerated after the docstrings
changed, and fails when the reference grows past :data:`MAX_LINES`.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import pkgutil
import re
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: Longest reference: a map to find things in, not a copy of every docstring.
MAX_LINES = 3000
DEFAULT_OUT = HERE / "api.md"
PACKAGE = "hhra_phys"
SKIP = ("hhra_phys.cli", "hhra_phys.data.")  # data: documented once, via its __all__


def _modules() -> list[str]:
    pkg = importlib.import_module(PACKAGE)
    names = [PACKAGE]
    for info in pkgutil.walk_packages(pkg.__path__, PACKAGE + "."):
        parts = info.name.split(".")
        if any(p.startswith("_") for p in parts[1:]) or info.name.startswith(SKIP):
            continue
        names.append(info.name)
    return sorted(names)


def _public(module) -> list[tuple[str, object]]:
    names = getattr(module, "__all__", None)
    if names is None:
        raise SystemExit(f"{module.__name__} has no __all__: list its public API there")
    out = []
    for name in names:  # getattr, not vars(): hhra_phys loads FitResult on first use
        obj = getattr(module, name)
        if inspect.isclass(obj) or inspect.isfunction(obj):
            out.append((name, obj))
    return sorted(out, key=lambda item: item[0].lower())


def _signature(obj: object) -> str:
    try:
        sig = str(inspect.signature(obj))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return "(...)"
    return re.sub(r" at 0x[0-9a-fA-F]+", "", sig)


def _doc(obj: object) -> str:
    """The summary paragraph of ``obj``'s docstring (up to its first blank line)."""
    doc = (inspect.getdoc(obj) or "(no docstring)").strip()
    first = doc.split("\n\n", 1)[0]
    return " ".join(line.strip() for line in first.splitlines()) + "\n"


def _members(cls: type) -> list[tuple[str, object]]:
    """Public methods and properties of ``cls``, with those of its private bases from other
    modules of the package: a mixin ``_Name`` that a long class is split into so that its
    modules stay short (``Simulator``'s) is the class's own API."""
    out = []
    seen: set[str] = set()
    split = [b for b in cls.__mro__[1:] if b.__name__.startswith("_")
             and b.__module__ != cls.__module__ and b.__module__.startswith(PACKAGE + ".")]
    for klass in (cls, *split):
        for name, obj in vars(klass).items():
            if name.startswith("_") or name in seen:
                continue
            seen.add(name)
            if isinstance(obj, property) or inspect.isfunction(obj) or isinstance(
                    obj, (classmethod, staticmethod)):
                out.append((name, obj))
    return sorted(out, key=lambda item: item[0].lower())


def render() -> str:
    lines = [
        "# API reference",
        "",
        "Generated from the docstrings by `python docs/make_api.py`; do not edit by hand.",
        "Each entry is the summary line of its docstring; `help(name)` in Python shows the",
        "whole docstring (parameters with shapes and units, returns, notes).",
        "The user's guide is [guide.md](guide.md).",
        "",
    ]
    modules = _modules()
    lines += [f"- [`{m}`](#{m.replace('.', '')})" for m in modules] + [""]
    for mname in modules:
        module = importlib.import_module(mname)
        lines += [f"## {mname}", "", _doc(module)]
        moved = getattr(module, "__moved_to__", None)
        if moved:  # a first home kept for old imports: its names are documented once, there
            lines += [f"Its names: {', '.join(f'`{n}`' for n in module.__all__)}; documented "
                      f"at [`{moved}`](#{moved.replace('.', '')}).", ""]
            continue
        for name, obj in _public(module):
            if inspect.isclass(obj):
                if lines[-1]:
                    lines.append("")
                lines += [f"### class `{name}{_signature(obj)}`", "", _doc(obj)]
                for mem, val in _members(obj):
                    if isinstance(val, property):
                        lines.append(f"- property `{mem}`: {_doc(val).strip()}")
                    else:
                        fn = val.__func__ if isinstance(val, (classmethod, staticmethod)) else val
                        lines.append(f"- `{mem}{_signature(fn)}`: {_doc(fn).strip()}")
                lines.append("")
            else:
                lines.append(f"- `{name}{_signature(obj)}`: {_doc(obj).strip()}")
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="write the API reference from the docstrings")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output file (docs/api.md)")
    ap.add_argument("--check", action="store_true", help="exit 1 if the file is not current")
    args = ap.parse_args(argv)
    text = render()
    n = len(text.splitlines())
    if n > MAX_LINES:
        print(f"the API reference has {n} lines, more than {MAX_LINES}: the public API "
              "(__all__ of the modules) has grown too large", file=sys.stderr)
        return 1
    if args.check:
        current = args.out.read_text() if args.out.exists() else ""
        if current != text:
            print(f"{args.out} is out of date: run python docs/make_api.py", file=sys.stderr)
            return 1
        print(f"{args.out} is current")
        return 0
    args.out.write_text(text)
    print(f"wrote {args.out} ({len(text.splitlines())} lines)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
