"""Start env, expert and learner with one params file.

ros2 launch eqhrl_ros train.launch.py env:=pendulum
ros2 launch eqhrl_ros train.launch.py env:=lunar_lander mode:=qasac
ros2 launch eqhrl_ros train.launch.py params_file:=/path/to/my.yaml
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _nodes(context):
    env = LaunchConfiguration('env').perform(context)
    params_file = LaunchConfiguration('params_file').perform(context) or os.path.join(
        get_package_share_directory('eqhrl_ros'), 'params', f'{env}.yaml'
    )
    mode = LaunchConfiguration('mode').perform(context)
    learner_params = [params_file] + ([{'mode': mode}] if mode else [])
    return [
        Node(package='eqhrl_ros', executable='gym_env', name='gym_env', parameters=[params_file], output='screen'),
        Node(package='eqhrl_ros', executable='expert', name='expert', parameters=[params_file], output='screen'),
        Node(
            package='eqhrl_ros',
            executable='learner',
            name='learner',
            parameters=learner_params,
            output='screen',
            emulate_tty=True,
        ),
    ]


def generate_launch_description():
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                'env', default_value='pendulum', description='params file name: pendulum or lunar_lander'
            ),
            DeclareLaunchArgument('params_file', default_value='', description='a params file path (overrides env)'),
            DeclareLaunchArgument(
                'mode', default_value='', description='sac, qasac or eqsac (overrides the params file)'
            ),
            OpaqueFunction(function=_nodes),
        ]
    )
