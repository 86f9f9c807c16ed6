"""ROS 2 nodes of sapga_ros: thin rclpy shells around the core.

What every node shares lives in ``sim_nodes.ros``: ``common`` (QoS and topic names from
msg_configs, the JointState <-> state-vector conversion), ``params`` (parameters declared
from one table with their ranges, which also gives ``--help``), ``runner`` (the standard
``main()``: --help, ROS arguments, guarded spin, exit codes) and ``dropped`` (messages a
queue dropped, counted).  Each node module here holds one ``Node`` subclass and its ``main``,
its parameter table beside it (``policy_params``, ``recorder_params``, ``trainer_params``);
``policy_loader`` prepares policies off the executor thread.  The simulator node lives in
``sim_nodes.ros.sim_node``.  The topic contract is docs/ros_interface.md.
"""
