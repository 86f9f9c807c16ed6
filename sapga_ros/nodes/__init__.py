"""ROS 2 nodes of sapga_ros (SPEC 4): thin rclpy shells around the core.

``common`` holds what every node shares (QoS and topic names from msg_configs, the
JointState <-> state-vector conversion, the standard ``main()`` runner); each other module
holds one ``Node`` subclass and its ``main``.  The simulator node lives in
``sim_nodes.ros.sim_node``.  The topic contract is docs/ros_interface.md.
"""
