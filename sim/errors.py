"""User-facing errors of procam: the CLI prints their message and exits with status 2."""


class ProcamError(Exception):
    """Base of every error caused by the user's input rather than by a bug."""


class SetupError(ProcamError):
    """A setup file, key or value is missing, of the wrong type or out of range."""


class DatasetError(ProcamError):
    """A dataset folder is missing files, or its images do not match in count or size."""
