"""``ros2 launch sapga_ros swingup.launch.py policy_file:=FILE [problem:=acrobot]
[mode:=realtime] [real_time_factor:=1.0] [record:=true] [output_dir:=recordings]``

Deploys a policy file: the recorder (``record:=true``), the simulator (``sim_node`` with the
problem) and the policy node, as ``sapga launch swingup`` starts them in plain Python.  The
simulator's first episode waits for the recorder (``wait_for_recorder``) and, in realtime,
for the policy's answer to its first state (``wait_for_policy``), so nothing is lost and no
state goes unanswered.  ``sapga launch swingup`` also checks the finished recording and
compares each episode with the offline evaluation; this file only starts the nodes.  To run
it under a namespace, include it from a launch file with ``PushRosNamespace``.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

ARGUMENTS = {
    'policy_file': (None, 'policy JSON file to deploy (sapga train --out); required'),
    'problem': ('acrobot', 'problem name: msg_configs/<problem>.yaml'),
    'mode': ('realtime', 'realtime (one step per tick of wall time) or lockstep'),
    'real_time_factor': ('1.0', 'sim time / wall time in realtime'),
    'record': ('true', 'record a rosbag2 bag (MCAP storage) with recorder_node'),
    'output_dir': ('recordings', 'where the recorder makes its bag directory'),
}


def generate_launch_description() -> LaunchDescription:
    """The recorder, the simulator and the policy node of the launch arguments."""
    arg = LaunchConfiguration
    record = IfCondition(arg('record'))
    sim = {'problem': arg('problem'), 'mode': arg('mode'),
           'real_time_factor': arg('real_time_factor')}
    return LaunchDescription([
        *[DeclareLaunchArgument(name, description=text) if default is None else
          DeclareLaunchArgument(name, default_value=default, description=text)
          for name, (default, text) in ARGUMENTS.items()],
        Node(package='sapga_ros', executable='recorder_node', name='recorder_node',
             parameters=[{'problem': arg('problem'), 'output_dir': arg('output_dir')}],
             condition=record, output='screen'),
        Node(package='sapga_ros', executable='policy_node', name='policy_node',
             parameters=[{'problem': arg('problem'), 'policy_file': arg('policy_file')}],
             output='screen'),
        Node(package='sapga_ros', executable='sim_node', name='sim_node',
             parameters=[{**sim, 'wait_for_recorder': 'recorder_node'}], condition=record,
             output='screen'),
        Node(package='sapga_ros', executable='sim_node', name='sim_node', parameters=[sim],
             condition=UnlessCondition(arg('record')), output='screen'),
    ])
