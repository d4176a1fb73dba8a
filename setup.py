"""Python package declaration for catkin (``catkin_python_setup()``); not for pip."""
from setuptools import setup
from catkin_pkg.python_setup import generate_distutils_setup

setup(**generate_distutils_setup(packages=['baxter_pnp', 'baxter_pnp.bench', 'baxter_pnp.robot', 'baxter_pnp.sim',
                                           'baxter_pnp.task', 'baxter_pnp.vision'],
                                 package_dir={'': 'src'}))
