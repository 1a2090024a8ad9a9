"""torch_grid installs as pure Python: kernels are generated and compiled per robot at first use,
so installing compiles nothing and needs no torch in the build environment."""
from pathlib import Path

from setuptools import find_packages, setup

ROOT = Path(__file__).parent


setup(
    name="torch_grid",
    version="0.1.0",
    description="Robot-specific rigid-body dynamics kernels as batched torch ops (CPU and CUDA), "
    "in Pinocchio's or MuJoCo's convention",
    long_description=(ROOT / "README.md").read_text(),
    long_description_content_type="text/markdown",
    license="BSD-3-Clause",
    python_requires=">=3.9",
    packages=find_packages(include=["torch_grid", "torch_grid.*"]),
    # the bundled robots, and the C++ sources every robot's kernels are generated and compiled against
    package_data={"torch_grid": ["robots/*.urdf", "robots/*.xml", "robots/*.json", "robots/NOTICE",
                                 "csrc/torch/*.h", "csrc/batch/*.h", "csrc/batch/*.cuh", "csrc/kernels/*.h",
                                 "csrc/kernels/*/*.h"]},
    # torch: tested 2.11 (CUDA 13.0 build) and 2.13; its C++ extension builder brings setuptools.
    # numpy: imported with the package (MuJoCo model conversion). ninja: builds each robot's kernels.
    # Pinocchio and MuJoCo are imported only to read a URDF, an MJCF or their model objects: the extras.
    install_requires=["torch>=2.11", "numpy", "ninja"],
    extras_require={
        "pin": ["pin>=3.4"],
        "mujoco": ["mujoco>=3.2"],
        # cmeel-eigen: tests/pinocchio_cpp_oracle.py compiles Pinocchio's C++ second-order derivatives;
        # pytest-xdist: the suite runs one test file per core (-n auto --dist loadfile)
        "test": ["pytest>=8", "pytest-xdist>=3.5", "pin==4.1.0", "mujoco==4.0.0", "example-robot-data==6.0.0", "cmeel-eigen==3.4.1"],
        # bench/pinocchio_cpp.py compiles against Pinocchio's headers, which need these two too
        "bench": ["pin==4.1.0", "example-robot-data==6.0.0", "cmeel-eigen==3.4.1", "cmeel-urdfdom-headers==3.0.0"],
        # the Sphinx build of docs/ (sphinx-build -W): Markdown pages, the API reference, the gallery, whose
        # scripts plot with matplotlib and render with MuJoCo offscreen
        "docs": ["sphinx==9.0.4", "myst-parser==5.2.0", "sphinx-gallery==0.22.1", "furo==2025.12.19",
                 "matplotlib==3.11.2", "mujoco==4.0.0"],
    },
)
