"""Typed errors of sapga_ros: each says what is wrong and where (file, field, value)."""


class SapgaError(Exception):
    """Base of every user-facing error; the CLI prints its message on one line."""


class ConfigError(SapgaError):
    """A problem configuration (msg_configs/*.yaml) is missing, malformed or inconsistent."""


class UnknownProblemError(ConfigError):
    """No configuration exists for the requested problem name."""


class PolicyFileError(SapgaError):
    """A policy document fails to parse or validate."""


class CheckpointError(SapgaError):
    """A checkpoint is missing, malformed or belongs to another run."""


class McapError(SapgaError):
    """A recording cannot be read."""
