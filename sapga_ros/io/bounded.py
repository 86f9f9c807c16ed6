"""Bounded input for the package's files: regular files only, bounded bytes and nesting.

The primitives live in the environment layer (``sim_nodes.files``), which reads the problem
YAML files with them; this module is where the rest of the package takes them from.
"""
from sim_nodes.files import (MAX_YAML_DEPTH, NotRegularFile, TooLarge, load_yaml,
                             open_regular, read_bounded)

__all__ = ['MAX_YAML_DEPTH', 'NotRegularFile', 'TooLarge', 'load_yaml', 'open_regular',
           'read_bounded']
