"""The recorder node's parameters: one table for their declaration with ranges, their checks
and ``recorder_node --help`` (``sim_nodes/ros/params.py``).  All are read-only: restart the
recorder to change one.  The recorder node's docstring explains each.
"""
from __future__ import annotations

from dataclasses import replace

from sapga_ros.recording.chunks import MAX_CHUNK_SIZE
from sapga_ros.recording.session import SPLITS
from sapga_ros.recording.writer import COMPRESSIONS, DEFAULT_CHUNK_SIZE
from sim_nodes.ros.params import Param, Row

PARAMETERS = (
    Param('problem', 'acrobot', 'msg_configs/<problem>.yaml: topics, QoS, state layout'),
    Param('output_dir', 'recordings', 'directory the bag directory is made in (created if '
          'missing)'),
    Param('bag', '', "name of the bag directory ('' = <problem>_<UTC time>); never reused"),
    Param('split', 'run', 'run: one storage file; episode: a new one at each episode start',
          choices=SPLITS),
    Param('chunk_size', DEFAULT_CHUNK_SIZE, '[bytes] uncompressed MCAP chunk', 1,
          MAX_CHUNK_SIZE),
    Param('flush_period', 1.0, '[s] close the chunk in progress this often (the most a '
          'SIGKILL loses); 0: by size only', 0.0, 3600.0),
    Param('compression', 'zstd', 'MCAP chunk compression', choices=tuple(COMPRESSIONS)),
    Param('queue_depth', 1000, 'subscription history depth (keep_last)', 1, 1_000_000),
    Param('delta', 0.0, 'goal delta written to the bag metadata; 0: the problem default', 0.0,
          1e9),
    Param('topics', [], 'topics to record: name or name:pkg/msg/Type (default: the '
          "problem's contract topics)", shown="the problem's"),
)
PARAMETERS = tuple(replace(p, read_only=True) for p in PARAMETERS)


def help_rows() -> list[Row]:
    """The rows of ``recorder_node --help``."""
    return [p.row() for p in PARAMETERS]
