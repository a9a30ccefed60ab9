"""Errors of the recording layer."""


class RecordingError(Exception):
    """A recording is missing, corrupt or does not fit the schema; the message names the file."""
