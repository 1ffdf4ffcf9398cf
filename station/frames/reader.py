"""Reading a frame description file (``--protocol frame:FILE.yaml``, schema ``imu-station/frame/1``).

The file is read by the station's one bounded YAML reader (``station.common.yaml_file``) and checked by
``protocols.frame_description.describe``; a broken rule becomes an
:class:`~station.errors.InputFileError` naming the file, the line, the key and the field. Importing
this module installs :func:`load_description` as the reader ``protocols.frame`` uses for
``frame:FILE``, so every command that takes ``--protocol`` (and the Python API after
``import station.frames.reader``) accepts frame descriptions.

The descriptions shipped with the station (``station/frames/``) are found by name too:
``frame:witmotion`` is ``station/frames/witmotion.yaml``.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from protocols.frame import FrameDecoder, set_description_reader
from protocols.frame_description import FrameDescription, FrameDescriptionError, describe
from station.common.yaml_file import read_yaml
from station.errors import InputFileError

MAX_BYTES = 64 * 1024
"""A frame description is a few hundred bytes; a larger file is not one."""


def shipped_descriptions() -> dict[str, Path]:
    """The example descriptions shipped with the station, by name (``witmotion``, ``mpu6050_dump``).

    Returns
    -------
    dict
        Name to file.
    """
    folder = resources.files("station.frames")
    return {Path(entry.name).stem: Path(str(entry)) for entry in folder.iterdir()
            if entry.name.endswith(".yaml")}


def resolve(path: str | Path) -> Path:
    """The file ``path`` names: itself, or a shipped description when it is a bare name that is no file.

    Parameters
    ----------
    path : str or Path
        As the user gave it.

    Returns
    -------
    Path
    """
    given = Path(path)
    if not given.exists() and given.suffix == "" and given.parent == Path("."):
        shipped = shipped_descriptions().get(given.name)
        if shipped is not None:
            return shipped
    return given


def load_description(path: str | Path) -> FrameDescription:
    """Read and check a frame description file.

    Parameters
    ----------
    path : str or Path
        The YAML file, or the name of a shipped description.

    Returns
    -------
    FrameDescription

    Raises
    ------
    InputFileError
        The file is missing, not YAML, too large, gives a key twice, or breaks a rule of the schema:
        the message names the file, the line and the key (and the field).
    """
    file = resolve(path)
    known = ", ".join(sorted(shipped_descriptions()))
    doc = read_yaml(file, f"does not exist; give a frame description file (schema imu-station/frame/1) or "
                          f"a shipped one: {known}", MAX_BYTES, unique_keys=True)
    try:
        return describe(doc.construct(), default_name=file.stem)
    except FrameDescriptionError as exc:
        raise InputFileError(file, f"{exc.where}: {exc.problem}", line=doc.line_of(exc.keys)) from None


def load_decoder(path: str | Path) -> FrameDecoder:
    """The decoder of a frame description file (see :func:`load_description`).

    Parameters
    ----------
    path : str or Path
        The YAML file or a shipped description's name.

    Returns
    -------
    FrameDecoder
    """
    return FrameDecoder(load_description(path))


set_description_reader(load_description)
