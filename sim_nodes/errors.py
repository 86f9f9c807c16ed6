"""Typed errors of the environment layer; the root of every sapga_ros error.

Each says what is wrong and where (file, field, value).  ``sapga_ros.errors`` re-exports
them beside the errors of the method's files.
"""


class SapgaError(Exception):
    """Base of every user-facing error; the CLI prints its message on one line."""


class ConfigError(SapgaError):
    """A problem configuration (msg_configs/*.yaml) is missing, malformed or inconsistent."""


class UnknownProblemError(ConfigError):
    """No configuration exists for the requested problem name."""
