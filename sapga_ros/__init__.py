"""sapga_ros: exemplar-based policy search (SAP-GA) for pendulums, with ROS 2 nodes.

The core (``selector``, ``policy``, ``kernels``, ``evaluation``, ``operators``, ``sapga``,
``qlearning``, ``train``) imports numpy and numba, never rclpy; ``sapga_ros.nodes`` are thin
rclpy shells around it.
"""
__version__ = '0.1.0'
