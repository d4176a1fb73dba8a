"""Import point for the Baxter SDK's ``baxter_core_msgs`` message and service classes.

On a robot workstation the SDK's own package is importable and is used. Otherwise the classes
generated from this repository's ``msg/`` and ``srv/`` (``tools/gen_msgs.py``, run by ``make`` and
by catkin) are put on the path. Either way the type names and md5sums are the SDK's.

Usage: ``from baxter_pnp.msgs import msg, srv`` then ``msg.JointCommand``, ``srv.SolvePositionIK``.
"""
import os
import sys

GENERATED_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), '_generated')

try:
    from baxter_core_msgs import msg, srv
except ImportError:
    if not os.path.isdir(os.path.join(GENERATED_DIR, 'baxter_core_msgs')):
        raise ImportError('baxter_core_msgs is neither installed nor generated: run `make` '
                          '(or tools/gen_msgs.py %s)' % GENERATED_DIR)
    sys.path.append(GENERATED_DIR)
    sys.modules.pop('baxter_core_msgs', None)
    from baxter_core_msgs import msg, srv  # noqa: E402  (generated fallback)

__all__ = ['msg', 'srv']
