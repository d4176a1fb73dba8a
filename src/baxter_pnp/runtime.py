"""Start-up helpers for entry points: run under the project's virtual environment.

Debian's ROS Python modules live with ``/usr/bin/python3``; the pinned numpy, scipy, OpenCV and
PyBullet live in the project's venv (created by ``make venv`` from ``/usr/bin/python3
--system-site-packages``, so it sees both). ``rosrun`` starts a script with its shebang
(``/usr/bin/python3``), or through catkin's relay with the same interpreter; ``use_project_venv``
then re-executes the script with the venv's interpreter when one is found.
"""
import os
import re
import sys

PACKAGE_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def venv_python():
    """Path of the venv interpreter: ``$BAXTER_PNP_VENV/bin/python`` or ``<repo>/.venv/bin/python``."""
    venv = os.environ.get('BAXTER_PNP_VENV') or os.path.join(PACKAGE_ROOT, '.venv')
    return os.path.join(venv, 'bin', 'python')


def single_threaded_blas():
    """Keep OpenBLAS (numpy's, scipy's) to the calling thread unless the user set its thread count: this project's
    matrices are small (12x12 at most), and a BLAS worker thread waiting for a busy core turned each 7 us
    ``numpy.linalg.solve`` into 2.8 ms in ``pick_square.py`` beside the fake on 2 cores (docs/fake_baxter.md,
    "Time"). Effective only before numpy is first imported."""
    os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')


def use_project_venv(script_path):
    """Re-exec ``script_path`` under the venv interpreter unless already running in it, with BLAS single-threaded
    (``single_threaded_blas``).

    Does nothing else when the venv does not exist (e.g. a robot workstation whose system Python has
    every dependency), so the import errors that follow name the missing module.
    """
    single_threaded_blas()
    python = venv_python()
    in_venv = os.path.realpath(sys.prefix) == os.path.realpath(os.path.dirname(os.path.dirname(python)))
    if in_venv or not os.path.exists(python) or os.environ.get('BAXTER_PNP_NO_REEXEC'):
        return
    os.environ['BAXTER_PNP_NO_REEXEC'] = '1'
    os.execv(python, [python, os.path.realpath(script_path)] + sys.argv[1:])


def command_summary(docstring):
    """What an entry point's ``--help`` says it does: the first paragraph of its module ``docstring`` on one line,
    without a leading usage (a double-backquoted command and a colon) and without reST's double backquotes."""
    paragraph = re.sub(r'^``[^`]*``:\s*', '', ' '.join(docstring.strip().split('\n\n')[0].split()))
    return (paragraph[:1].upper() + paragraph[1:]).replace('``', '')
