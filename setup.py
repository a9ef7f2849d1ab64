"""The one thing pyproject.toml cannot say: the examples folder ships too, as the package
``canstack_examples`` (its scenario files and scripts as package data), so that a plain
``pip install`` has them (``canstack examples``). Everything else is in pyproject.toml."""

from setuptools import find_packages, setup

setup(
    packages=[*find_packages(include=["stack*", "profiles*", "dbc*"]), "canstack_examples"],
    package_dir={"canstack_examples": "examples"},
)
