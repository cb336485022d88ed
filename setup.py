"""The package list: ``sim`` and ``compensation`` with every subpackage found on disk, and
``procam_scenes`` with ``procam_scenes.studies``: the ``scenes/`` folder, mapped and given its data
files in pyproject.toml.

pyproject.toml cannot both discover packages and name one by hand, hence this file; everything
else is declared there.
"""
from setuptools import find_packages, setup

setup(packages=find_packages(include=["sim", "sim.*", "compensation", "compensation.*"])
      + ["procam_scenes", "procam_scenes.studies"])
