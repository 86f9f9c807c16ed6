"""The policy node's parameters: one table for their declaration with ranges, their checks
and ``policy_node --help`` (``sim_nodes/params.py``).

================  ========  ============  ================================================
name              type      default       meaning
================  ========  ============  ================================================
problem           string    acrobot       msg_configs/<problem>.yaml (read-only)
policy_file       string    ''            a policy JSON file, loaded at start (a bad one:
                                          exit 2); setting it loads that file or is refused
trainer_service   string    trainer_node/ the trainer's std_srvs/Trigger (read-only)
                            get_policy
load_timeout      double    5.0           [s] wait for the trainer's answer at most
markers           bool      true          publish the exemplar ghost on ``markers``
qos_profile       string    reliable      ``reliable`` (the problem's ``ros.qos``) |
                                          ``sensor_data`` (best effort; read-only)
================  ========  ============  ================================================

(``policy_node --help`` prints the ranges too.)
"""
from __future__ import annotations

from typing import Any

from sim_nodes.params import Param
from sim_nodes.ros.common import QOS_PROFILES
from sim_nodes.ros.params import check

PARAMETERS = (
    Param('problem', 'acrobot', 'msg_configs/<problem>.yaml', read_only=True),
    Param('policy_file', '', 'policy JSON file loaded at start (a bad one: exit 2); setting '
          "it loads that file ('' = none)"),
    Param('trainer_service', 'trainer_node/get_policy', "the trainer's std_srvs/Trigger that "
          'load_policy calls', read_only=True),
    Param('load_timeout', 5.0, 'how long load_policy waits for the trainer', 1e-3, 86400.0,
          unit='s'),
    Param('markers', True, 'publish the exemplar in use as a ghost on markers'),
    Param('qos_profile', 'reliable', 'reliable (the problem ros.qos) | sensor_data (best '
          'effort)', choices=QOS_PROFILES, read_only=True),
)


def check_setting(name: str, value: Any) -> str | None:
    """Why ``value`` is not acceptable for parameter ``name``, or None (files: the node)."""
    return check(PARAMETERS, name, value)
