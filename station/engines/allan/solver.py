"""Whether the model selection's compiled solver is ready, and compiling it ahead of use.

The trust-region solve of each candidate model (:mod:`station.engines.allan._trf`) is compiled by numba
at its first use and cached on disk: about 25 s of CPU once per installation (more on a busy machine),
then a fraction of a second to load. ``./scripts/setup`` compiles it as it installs, so that nobody's first
``imu-station allan`` waits for it; a command that finds the cache empty says why it waits.
"""

from __future__ import annotations


def solver_ready() -> bool:
    """True when the compiled solver is in numba's cache (the model selection then starts at once)."""
    from station.engines.allan import _trf

    return _trf.cached()


def prepare_solver() -> None:
    """Compile the solver now (and cache it), so that a later model selection does not wait for it."""
    from station.engines.allan import _trf

    _trf.compile_now()
