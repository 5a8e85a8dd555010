"""Packaging beyond ``pyproject.toml`` (which holds everything else): which packages go into the
wheel, with the data giwbc cannot run without.

The robot descriptions (``robots/``: robot.toml, hardware.toml, randomization.toml, URDFs) and the
shipped policies (``policies/``) stay at the top of the source tree, where the docs and the
commands name them, and go into the wheel as package data under ``giwbc/_data/``, where
``giwbc.util.shipped`` finds them in an installed giwbc (a source checkout, editable or not, reads
the top-level folders). pyproject.toml cannot map folders outside the package next to
``packages.find``, hence this file.
"""

from setuptools import find_packages, setup

# Top-level data folders of the source tree -> their package in the wheel (giwbc/_data/<folder>).
DATA_FOLDERS = {"giwbc._data.robots": "robots", "giwbc._data.policies": "policies"}

setup(
    packages=[*find_packages(include=["giwbc", "giwbc.*"]), *DATA_FOLDERS],
    package_dir=DATA_FOLDERS,
    package_data={package: ["**/*"] for package in DATA_FOLDERS},
    include_package_data=False,
)
