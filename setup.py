"""Package discovery for the one distribution ``planar-vo`` (metadata: pyproject.toml).

The repository keeps the product's layers at the top level (``core/``, ``frontend/``,
``backend/``, ``io/``), all installed under the one import package ``planar_vo``; every subpackage below
each root is found here, so a new one ships without touching any list.
"""
from setuptools import find_packages, setup

#: import name -> folder
ROOTS = {"planar_vo": "planar_vo", "planar_vo.core": "core", "planar_vo.frontend": "frontend",
         "planar_vo.backend": "backend", "planar_vo.io": "io", "planar_vo.data": "data"}


def packages() -> list[str]:
    out = []
    for name, folder in ROOTS.items():
        out.append(name)
        out += [f"{name}.{sub}" for sub in find_packages(folder) if not sub.startswith("tum_")]
    return out


setup(packages=packages(), package_dir=ROOTS, package_data={"planar_vo.data": ["*.yaml"]})
