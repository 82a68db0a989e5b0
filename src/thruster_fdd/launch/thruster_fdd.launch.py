"""The vehicle's node set: N thrusters from one parameters file.

``ros2 launch thruster_fdd thruster_fdd.launch.py [params_file:=FILE] [record:=true]
[autostart:=true] [executor:=events]``

Every ``/thruster/<id>/esc_driver`` entry of the parameters file (standard ``node:
ros__parameters:`` form; the package's ``config/thruster_fdd.yaml`` by default) is a thruster:
its ESC driver, nominal model and classifier run in one ``container`` process with every other
thruster's (as ``thruster-fdd up`` runs them), with the health node (``/thruster_fdd/health``
for the allocator, over every thruster in the file's order) and, with ``record``, the recorder,
which writes what the process publishes without subscribing to it. With ``autostart``
the drivers configure and activate themselves; ``autostart:=false`` leaves them unconfigured
for a lifecycle manager of your own (``<node>/change_state``).
"""

from __future__ import annotations

from pathlib import Path

import yaml
from ament_index_python.packages import get_package_share_directory
from launch import LaunchContext, LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction, SetEnvironmentVariable
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

STAGES = ("esc_driver", "nominal_model", "classifier")


def thruster_ids(params_file: str) -> list[str]:
    """The ids of the thrusters with an ``/thruster/<id>/esc_driver`` entry in ``params_file``."""
    spec = yaml.safe_load(Path(params_file).read_text()) or {}
    ids = []
    for key in spec:
        parts = str(key).strip("/").split("/")
        if len(parts) == 3 and parts[0] == "thruster" and parts[2] == "esc_driver":
            ids.append(parts[1])
    if not ids:
        raise RuntimeError(f"{params_file}: no /thruster/<id>/esc_driver entry")
    return ids


def _nodes(context: LaunchContext) -> list[Node]:
    """The vehicle's container: the thrusters' stages, the health node and (``record``) the
    recorder."""
    params_file = LaunchConfiguration("params_file").perform(context)
    autostart = LaunchConfiguration("autostart").perform(context).lower() == "true"
    record = LaunchConfiguration("record").perform(context).lower() == "true"
    ids = thruster_ids(params_file)
    # The health node's thruster_ids are the thrusters': the masks' bits follow the file.
    vehicle = Node(
        package="thruster_fdd",
        executable="container",
        arguments=[
            *STAGES,
            "--thrusters",
            *ids,
            "--vehicle",
            "health",
            *(["recorder"] if record else []),
            "-p",
            f"esc_driver:autostart={autostart}",
        ],
        parameters=[params_file],
        output="screen",
    )
    return [vehicle]


def generate_launch_description() -> LaunchDescription:
    """The launch description (see the module docstring)."""
    default_params = Path(get_package_share_directory("thruster_fdd")) / "config"
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "params_file",
                default_value=str(default_params / "thruster_fdd.yaml"),
                description="parameters of every node; its esc_driver entries are the thrusters",
            ),
            DeclareLaunchArgument("record", default_value="true", description="start the recorder"),
            DeclareLaunchArgument(
                "autostart",
                default_value="true",
                description="the drivers configure and activate themselves",
            ),
            DeclareLaunchArgument(
                "executor",
                default_value="events",
                description="executor of the node processes: events or single",
            ),
            SetEnvironmentVariable("THRUSTER_FDD_EXECUTOR", LaunchConfiguration("executor")),
            OpaqueFunction(function=_nodes),
        ]
    )
