"""The station's exception root. Every message says what went wrong and what to do next."""

from __future__ import annotations


class StationError(Exception):
    """An error the user can act on; the CLI prints it without a traceback.

    ``exit_code`` follows the factory convention: 3 device or link, 4 usage or configuration.
    """

    exit_code = 4


class InputFileError(StationError):
    """A file the user gave cannot be read: names the file, line and field."""

    def __init__(self, path: object, problem: str, line: int | None = None, column: str | None = None):
        where = str(path)
        if line is not None:
            where += f", line {line}"
        if column is not None:
            where += f", column '{column}'"
        super().__init__(f"{where}: {problem}")
        self.path = path
        self.line = line
        self.column = column

    @classmethod
    def invalid_yaml(cls, path: object, exc: Exception) -> InputFileError:
        """The error for a file PyYAML could not parse, at the line of its problem mark if it has one."""
        mark = getattr(exc, "problem_mark", None)
        return cls(path, f"is not valid YAML: {getattr(exc, 'problem', exc)}",
                   line=mark.line + 1 if mark is not None else None)


class EngineInputError(StationError):
    """The data cannot determine what was asked (too few poses, rank deficiency, motion, ...)."""


class OutputFileError(StationError):
    """A file the station writes cannot be written (disk full, no permission): names the file."""

    def __init__(self, path: object, problem: str):
        super().__init__(f"{path}: {problem}")
        self.path = path
