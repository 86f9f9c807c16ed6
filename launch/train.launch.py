"""``ros2 launch sapga_ros train.launch.py [problem:=acrobot] [steps:=30000000] [seed:=0]
[out:=policy.json]``

The trainer node training at once (``train_on_start``), writing its best policy to ``out``
(the log and checkpoint beside it), serving it on ``/trainer_node/get_policy`` and reporting
on ``/diagnostics``; a policy node whose ``/policy_node/load_policy`` fetches that policy.
Call ``ros2 service call /policy_node/load_policy std_srvs/srv/Trigger`` once the
diagnostics say ``done`` (or any time for the best so far), then start a simulator
(``swingup.launch.py`` with ``policy_file:=<out>``, or ``ros2 run sapga_ros sim_node``).
``sapga launch train_deploy`` does all of it in one command and records the episode.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

ARGUMENTS = {
    'problem': ('acrobot', 'problem name: msg_configs/<problem>.yaml'),
    'steps': ('30000000', 'budget of MDP steps simulated'),
    'seed': ('0', 'seed of every random choice of the run'),
    'out': ('policy.json', 'best policy file, in an existing folder'),
}


def generate_launch_description() -> LaunchDescription:
    """The trainer node (training at once) and a policy node that loads from it."""
    arg = LaunchConfiguration
    return LaunchDescription([
        *[DeclareLaunchArgument(name, default_value=default, description=text)
          for name, (default, text) in ARGUMENTS.items()],
        Node(package='sapga_ros', executable='trainer_node', name='trainer_node',
             parameters=[{'problem': arg('problem'), 'steps': arg('steps'),
                          'seed': arg('seed'), 'out': arg('out'), 'train_on_start': True}],
             output='screen'),
        Node(package='sapga_ros', executable='policy_node', name='policy_node',
             parameters=[{'problem': arg('problem'),
                          'trainer_service': 'trainer_node/get_policy'}],
             output='screen'),
    ])
