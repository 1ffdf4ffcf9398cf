"""A package's public names, imported from its modules on first use (PEP 562).

A subject package (``station.engines.allan``) names its public functions in its ``__init__``, yet
importing one light module of it (the noise terms' names that ``--help`` shows) must not load the
others (scipy, numba). The package lists ``{module: names}`` once; :func:`lazy_exports` gives it the
module ``__getattr__`` and ``__dir__`` that import a name's module when the name is first read, and
the ``__all__`` that lists them. The same names are imported under ``TYPE_CHECKING`` in the package
so that type checkers and editors see them (``tests/test_packages.py`` keeps the two in step).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping


def lazy_exports(package: str, exports: Mapping[str, tuple[str, ...]]
                 ) -> tuple[Callable[[str], object], Callable[[], list[str]], list[str]]:
    """``(__getattr__, __dir__, __all__)`` for ``package``, whose modules export ``exports``.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    exports : mapping of str to tuple of str
        Module name within the package (``"deviation"``) to the public names it provides.

    Returns
    -------
    tuple
        The module-level ``__getattr__`` (imports ``package.module`` and returns the name), ``__dir__``
        and the sorted ``__all__``.
    """
    where = {name: module for module, names in exports.items() for name in names}

    def __getattr__(name: str) -> object:
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{module}"), name)

    def __dir__() -> list[str]:
        return sorted(where)

    return __getattr__, __dir__, sorted(where)
