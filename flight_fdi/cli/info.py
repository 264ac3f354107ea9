"""``flight-fdi info``: the environment this tool runs in and the flight_fdi_msgs interfaces."""
from __future__ import annotations

import argparse
import importlib
import os
import platform
import sys

MESSAGES = ("Innovation", "FilterState", "ModelInfo", "FaultLocalization", "SmoothedState",
            "VoteStatus")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("info", help="show the ROS 2 environment and the flight_fdi_msgs messages",
                       description=__doc__)
    p.set_defaults(func=run)


def _version(dist: str) -> str:
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "not installed"


def run(args: argparse.Namespace) -> int:
    from flight_fdi.cli.errors import CliError

    print(f"python          {platform.python_version()} ({sys.executable})")
    for dist in ("ros-jazzy-rclpy", "rosbags", "numpy", "scipy"):
        print(f"{dist:<15} {_version(dist)}")
    print(f"RMW             {os.environ.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp (default)')}")
    print(f"ROS_DOMAIN_ID   {os.environ.get('ROS_DOMAIN_ID', '0 (default)')}")
    try:
        msg_mod = importlib.import_module("flight_fdi_msgs.msg")
    except ImportError as exc:
        raise CliError(f"flight_fdi_msgs is not importable ({exc}); run 'make setup'") from None
    print("messages (flight_fdi_msgs/msg):")
    for name in MESSAGES:
        cls = getattr(msg_mod, name)
        fields = ", ".join(cls.get_fields_and_field_types())
        print(f"  {name}: {fields}")
    return 0
