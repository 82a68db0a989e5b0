from glob import glob

from setuptools import find_packages, setup

PACKAGE = "thruster_fdd_shore"

setup(
    name=PACKAGE,
    version="0.2.0",
    packages=find_packages(exclude=["test"]),
    package_data={"thruster_fdd_shore.core.sim": ["presets/*.yaml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        ("bin", ["bin/thruster-fdd"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="thruster_fdd maintainers",
    maintainer_email="thruster-fdd@example.org",
    description="thruster_fdd ashore: simulator, emulator, training, evaluation, discrepancy "
    "and the thruster-fdd command.",
    license="Apache-2.0",
    # The simulation harness's node: `ros2 run thruster_fdd_shore command_player`.
    entry_points={
        "console_scripts": [
            "command_player = thruster_fdd_shore.nodes.command_player:main",
        ],
    },
)
