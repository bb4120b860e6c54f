import importlib.util
import json
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup
from setuptools.command.build_py import build_py

package_name = 'eqhrl_ros'
HERE = Path(__file__).resolve().parent


def git_state() -> dict:
    """The source tree's commit and whether it has changes not committed, as every run folder
    names them (eqhrl_ros/core/runs/provenance.py, read here by its path: the package is not
    importable while it is being built)."""
    spec = importlib.util.spec_from_file_location('provenance', HERE / package_name / 'core/runs/provenance.py')
    provenance = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(provenance)
    return provenance.git_state(HERE)


class BuildWithCommit(build_py):
    """The package as built, with eqhrl_ros/build_info.json: git_state() of its source tree
    ({} where it is not a git checkout)."""

    def run(self):
        super().run()
        target = Path(self.build_lib) / package_name / 'build_info.json'
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(json.dumps(git_state()) + '\n')


setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['tests']),
    package_data={package_name: ['web/*.html', 'web/*.js']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml', 'README.md']),
        ('share/' + package_name + '/params', glob('params/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        ('share/' + package_name + '/studies', glob('studies/*.yaml')),
        ('share/' + package_name + '/config', glob('config/*.xml')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='eqhrl_ros maintainers',
    maintainer_email='maintainers@eqhrl.dev',
    description='EQ-HRL human-in-the-loop reinforcement learning for ROS 2.',
    license='Apache-2.0',
    tests_require=['pytest'],
    cmdclass={'build_py': BuildWithCommit},
    entry_points={
        'console_scripts': [
            'gym_env = eqhrl_ros.cli.node_programs:gym_env',
            'learner = eqhrl_ros.cli.node_programs:learner',
            'actor = eqhrl_ros.cli.node_programs:actor',
            'trainer = eqhrl_ros.cli.node_programs:trainer',
            'expert = eqhrl_ros.cli.node_programs:expert',
            'policy_driver = eqhrl_ros.cli.node_programs:policy_driver',
            'teleop_expert = eqhrl_ros.cli.node_programs:teleop_expert',
            'keyboard_teleop = eqhrl_ros.cli.node_programs:keyboard_teleop',
            'advice_console = eqhrl_ros.cli.node_programs:advice_console',
            'double_integrator_env = eqhrl_ros.cli.node_programs:double_integrator_env',
            'eqhrl-train = eqhrl_ros.cli.train:main',
            'eqhrl-demo = eqhrl_ros.cli.demo:main',
            'eqhrl-experiment = eqhrl_ros.cli.experiment:main',
            'eqhrl-report = eqhrl_ros.cli.report:main',
            'eqhrl-study = eqhrl_ros.cli.study:main',
            'eqhrl-study-report = eqhrl_ros.cli.study_report:main',
        ],
    },
)
