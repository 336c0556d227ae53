"""Package namespaces whose public objects load on first use, so that importing one light module
of a package (a config, an enum) does not import the heavy ones beside it (torch, onnxruntime)."""

import importlib
from collections.abc import Callable


def lazy_attributes(package: str, where: dict[str, str]) -> Callable[[str], object]:
    """A module `__getattr__` for PACKAGE: NAME comes from the submodule where[NAME], imported when
    NAME is first asked for (PEP 562)."""

    def __getattr__(name: str) -> object:
        if name in where:
            return getattr(importlib.import_module(f"{package}.{where[name]}"), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__
