"""The public API's names and signatures, one a line: ``python tests/api_names.py`` prints
them, ``python tests/api_names.py --write`` writes ``tests/api_names.txt``.

The public API is each package's ``__all__`` (toggle, controllers, fmu_src, design, hil):
functions with their signatures, classes with theirs and their public methods and
properties. ``tests/test_api.py`` fails when this list and the committed file differ: a
change of the API is deliberate (run the script with ``--write`` and commit the file).
"""

from __future__ import annotations

import importlib
import inspect
import sys
from pathlib import Path

PACKAGES = ("toggle", "controllers", "fmu_src", "design", "hil")
LIST = Path(__file__).with_name("api_names.txt")


def _signature(obj: object) -> str:
    try:
        return str(inspect.signature(obj))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return "(...)"


def _members(qualified: str, cls: type) -> list[str]:
    """The public methods and properties a class itself defines (not object's)."""
    lines = []
    for name, value in sorted(vars(cls).items()):
        if name.startswith("_"):
            continue
        if isinstance(value, property) or hasattr(value, "__set_name__") and hasattr(
                value, "func"):  # property, functools.cached_property
            lines.append(f"{qualified}.{name} [property]")
        elif isinstance(value, (staticmethod, classmethod)) or inspect.isfunction(value):
            lines.append(f"{qualified}.{name}{_signature(getattr(cls, name))}")
    return lines


def api_lines() -> list[str]:
    """Every public name of every package, with its signature, sorted within a package."""
    lines = []
    for package in PACKAGES:
        module = importlib.import_module(package)
        for name in sorted(module.__all__):
            obj = getattr(module, name)
            qualified = f"{package}.{name}"
            if inspect.isclass(obj) and issubclass(obj, BaseException):
                lines.append(f"{qualified} [exception of {obj.__mro__[1].__name__}]")
            elif inspect.isclass(obj):
                lines.append(f"{qualified}{_signature(obj)} [class]")
                lines.extend(_members(qualified, obj))
            else:
                lines.append(f"{qualified}{_signature(obj)}")
    return lines


def main(argv: list[str]) -> int:
    text = "\n".join(api_lines()) + "\n"
    if argv == ["--write"]:
        LIST.write_text(text, encoding="utf-8")
        print(f"wrote {LIST} ({text.count(chr(10))} lines)")
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
