"""The recorder node's parameters: one table for their declaration with ranges, their checks
and ``recorder_node --help`` (``sim_nodes/params.py``).  All are read-only (restart the
recorder to change one) but for a ``managed`` recorder, whose parameters after the first two
are read at each configure.  The recorder node's docstring explains each.
"""
from __future__ import annotations

from dataclasses import replace

from sapga_ros.recording.chunks import MAX_CHUNK_SIZE
from sapga_ros.recording.session import SPLITS
from sapga_ros.recording.writer import COMPRESSIONS, DEFAULT_CHUNK_SIZE
from sim_nodes.params import DELTA, Param

PARAMETERS = (
    Param('problem', 'acrobot', 'msg_configs/<problem>.yaml: topics, QoS, state layout'),
    Param('managed', False, 'wait for lifecycle transitions (configure, activate, ...) '
          'instead of recording at once'),
    Param('output_dir', 'recordings', 'directory the bag directory is made in (created if '
          'missing)'),
    Param('bag', '', "name of the bag directory ('' = <problem>_<UTC time>); never reused"),
    Param('split', 'run', 'run: one storage file; episode: a new one at each episode start',
          choices=SPLITS),
    Param('chunk_size', DEFAULT_CHUNK_SIZE, 'uncompressed MCAP chunk', 1, MAX_CHUNK_SIZE,
          unit='bytes'),
    Param('flush_period', 1.0, 'close the chunk in progress this often (the most a SIGKILL '
          'loses); 0: by size only', 0.0, 3600.0, unit='s'),
    Param('compression', 'zstd', 'MCAP chunk compression', choices=tuple(COMPRESSIONS)),
    Param('queue_depth', 1000, 'subscription history depth (keep_last; per publisher of a '
          'contract role: markers x2)', 1, 1_000_000),
    replace(DELTA, help='goal delta the run uses, written to the bag metadata'),
    Param('topics', [], 'topics to record: name or name:pkg/msg/Type (default: the '
          "problem's contract topics)"),
)
PARAMETERS = tuple(replace(p, read_only=True) for p in PARAMETERS)
