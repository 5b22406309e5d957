"""The package list, found rather than kept by hand: encons and its subpackages, and conf/ shipped as
``encons.conf`` with one package per config-group folder (setuptools wants every folder of package
data listed as a package, else it warns once per folder on install). The rest is in pyproject.toml."""

import os

from setuptools import find_packages, setup

conf = sorted(".".join(["encons.conf", *[p for p in os.path.relpath(folder, "conf").split(os.sep) if p != "."]])
              for folder, _, _ in os.walk("conf", followlinks=True))  # conf/sweeps links to sweeps/
setup(packages=find_packages(include=["encons", "encons.*"]) + conf)
