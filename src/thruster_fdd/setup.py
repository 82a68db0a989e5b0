from glob import glob

from setuptools import find_packages, setup

PACKAGE = "thruster_fdd"

setup(
    name=PACKAGE,
    version="0.2.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.json")),
        (f"share/{PACKAGE}/launch", glob("launch/*.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="thruster_fdd maintainers",
    maintainer_email="thruster-fdd@example.org",
    description="Onboard soft-fault detection and diagnosis for AUV thrusters: the vehicle side.",
    license="Apache-2.0",
    # Every node an executable in lib/thruster_fdd (setup.cfg): `ros2 run thruster_fdd esc_driver`.
    entry_points={
        "console_scripts": [
            "esc_driver = thruster_fdd.nodes.esc_driver:main",
            "nominal_model = thruster_fdd.nodes.nominal_model:main",
            "classifier = thruster_fdd.nodes.classifier:main",
            "recorder = thruster_fdd.nodes.recorder:main",
            "container = thruster_fdd.nodes.container:main",
            "health = thruster_fdd.nodes.health:main",
        ],
    },
)
