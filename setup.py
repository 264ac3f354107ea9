"""ament_python build of flight_fdi (colcon build / ros2 run). See README.md."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "flight_fdi"

NODES = {
    "filter_node": "flight_fdi.nodes.filter_node:main",
    "recorder_node": "flight_fdi.nodes.recorder_node:main",
    "smoother_node": "flight_fdi.nodes.smoother_node:main",
    "bag_player": "flight_fdi.nodes.bag_player:main",
    "voter_node": "flight_fdi.nodes.voter_node:main",
}

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, PACKAGE + ".*"]),
    package_data={PACKAGE + ".schema": ["*.schema.json"]},
    include_package_data=True,
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/config", glob("config/*.yaml") + glob("config/*.xml")),
        ("share/" + PACKAGE + "/config/models", glob("config/models/*.yaml")),
        ("share/" + PACKAGE + "/config/inputs", glob("config/inputs/*.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="flight_fdi developers",
    maintainer_email="flight-fdi@example.com",
    description="INS fault detection in flight and fault isolation after the flight",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [f"{name} = {target}" for name, target in NODES.items()]
        + ["flight-fdi = flight_fdi.cli.main:main"],
    },
)
