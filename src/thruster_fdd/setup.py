from glob import glob

from setuptools import find_packages, setup

PACKAGE = "thruster_fdd"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={"thruster_fdd.core.sim": ["presets/*.yaml"]},
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
    description="Onboard soft-fault detection and diagnosis for AUV thrusters.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "thruster-fdd = thruster_fdd.cli:main",
        ],
    },
)
