"""Former home of the self-describing config fields; they are ``sim_nodes.params`` now.

Kept for one release so that code written against it still imports: ``setting`` is
``sim_nodes.params.param``; ``check``, ``build`` and ``MAX_INT`` are the same functions and
constant.  New code imports ``sim_nodes.params``.
"""
from sim_nodes.params import MAX_INT, build, check, param as setting

__all__ = ['MAX_INT', 'build', 'check', 'setting']
