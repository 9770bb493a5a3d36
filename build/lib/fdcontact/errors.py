"""Errors the command line reports as one clear line with an exit code."""


class DriverError(Exception):
    """An error with a message meant for the user and a process exit code."""

    exit_code = 1

    def __init__(self, message, exit_code=None):
        super().__init__(message)
        if exit_code is not None:
            self.exit_code = exit_code


class SceneError(DriverError):
    """Bad input: malformed scene file, unknown key, wrong type, out of range."""

    exit_code = 2


class NewtonError(DriverError):
    """The semi-smooth Newton did not converge within its iteration limit."""

    exit_code = 3


class FreeFemError(DriverError):
    """FreeFEM failed (script error, crash, missing output)."""

    exit_code = 4
