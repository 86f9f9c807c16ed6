"""Typed errors of sapga_ros: each says what is wrong and where (file, field, value).

The root ``SapgaError`` and the configuration errors belong to the environment layer
(``sim_nodes.errors``) and are re-exported here.
"""
from sim_nodes.errors import ConfigError, SapgaError, UnknownProblemError

__all__ = ['SapgaError', 'ConfigError', 'UnknownProblemError', 'PolicyFileError',
           'CheckpointError', 'McapError', 'DataFileError']


class PolicyFileError(SapgaError):
    """A policy document fails to parse or validate."""


class CheckpointError(SapgaError):
    """A checkpoint is missing, malformed or belongs to another run."""


class McapError(SapgaError):
    """A recording cannot be read."""


class DataFileError(SapgaError):
    """A data file the package wrote earlier (a run, a summary, a limit) is malformed."""
