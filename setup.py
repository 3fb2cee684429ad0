"""The repository keeps the design card's layout (common/, services/<name>/ at the top)
while everything installs under the one import name `viena`: viena.common, viena.services.*."""
from setuptools import find_packages, setup

shared = find_packages(include=["common", "common.*", "services", "services.*"])
setup(
    packages=["viena", *(f"viena.{name}" for name in shared)],
    package_dir={"viena": "viena", "viena.common": "common", "viena.services": "services"},
    package_data={"viena.services.steering": ["*.eds"]},
)
