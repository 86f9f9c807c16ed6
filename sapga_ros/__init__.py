"""sapga_ros: exemplar-based policy search (SAP-GA) for pendulums, with ROS 2 nodes.

Layers, lowest first (``tests/test_layers.py`` keeps imports pointing down; docs/architecture.md):
``errors``/``io`` (file primitives), the method core (``exemplars``, ``evaluation``,
``optim``; numpy and numba, never rclpy), ``training`` and ``recording``, the ROS shells
(``nodes``, ``launch``), and the applications (``cli``, ``bench``, ``viz``).  The
environment (problem configs, model kernels, the simulator node) is the ``sim_nodes``
package below all of them.
"""
__version__ = '0.1.0'
