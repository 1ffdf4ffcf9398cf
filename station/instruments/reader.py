"""Reading instrument description files (schema ``imu-station/instrument/1``).

The shipped protocols are description files in ``descriptions/`` beside this module, named as
their URL schemes name them (``votsch``, ``espec``, ``watlow-f4``, ``binder``, ``acutrol``,
``aerosmith``, ``scpi``, ``korad``). A user's own file is read the same way, through the station's
bounded YAML reader; a refusal names the file, the line and the key
(``mine.yaml:14: commands.set_setpoint.send: field {val} is not one of {value}, {axis}, {channel}``).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from drivers.instruments.description import DescriptionError, InstrumentDescription, describe
from station.common.yaml_file import read_yaml
from station.errors import InputFileError

MAX_BYTES = 64 * 1024
"""A description is a few kilobytes; a larger file is not one."""


def shipped_descriptions() -> dict[str, Path]:
    """The shipped descriptions, by name (the URL scheme that uses each)."""
    folder = resources.files("station.instruments") / "descriptions"
    return {Path(entry.name).stem: Path(str(entry)) for entry in folder.iterdir()
            if entry.name.endswith(".yaml")}


def load_description(path: str | Path) -> InstrumentDescription:
    """Read and check a description file, or a shipped one by name.

    Parameters
    ----------
    path : str or Path
        A YAML file, or the name of a shipped description (``votsch``).

    Returns
    -------
    InstrumentDescription

    Raises
    ------
    InputFileError
        Missing, not YAML, too large, or breaking a rule of the schema: file, line and key.
    """
    given = Path(path)
    shipped = shipped_descriptions()
    by_name = not given.exists() and given.name in shipped and given.suffix == ""
    file = shipped[given.name] if by_name else given
    doc = read_yaml(file, "does not exist; give an instrument description (schema imu-station/instrument/1) "
                          f"or a shipped one: {', '.join(sorted(shipped))}", MAX_BYTES)
    try:
        return describe(doc.construct())
    except DescriptionError as exc:
        where = ".".join(map(str, exc.path)) or "(document)"
        raise InputFileError(file, f"{where}: {exc.message}", line=doc.line_of(exc.path)) from None
