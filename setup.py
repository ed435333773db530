"""Map the root folders onto the ``contactflow.<folder>`` import namespace."""

from setuptools import find_packages, setup

AREAS = ("nodes", "embodiments", "abstraction", "fusion", "recognition", "deploy")

packages: list[str] = []
package_dir: dict[str, str] = {}
for area in AREAS:
    package_dir[f"contactflow.{area}"] = area
    packages.append(f"contactflow.{area}")
    packages.extend(f"contactflow.{area}.{sub}" for sub in find_packages(area))

setup(packages=packages, package_dir=package_dir)
