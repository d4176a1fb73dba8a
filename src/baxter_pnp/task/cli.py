"""The command line every task script shares: the session's options (arm, camera calibration, hand-eye
calibration, table, speed, outputs), the ``~name`` private ROS parameters, and reading both into the task's
config and the session's (``task.settings.load_configs``: defaults <- YAML <- ``~name`` <- command line).

A bad value anywhere is a ``CONFIG_ERRORS`` exception naming the key; the scripts log it and exit 2 before the
robot is touched (:func:`configure`). ROS edge (``rospy`` for the parameters and the log).
"""
import json

import rospy

from baxter_pnp.task.settings import SessionConfig, field_names, load_configs

CONFIG_ERRORS = (OSError, ValueError, TypeError)      # ParameterError is a ValueError

# Session options every task takes, by SessionConfig field: (flags, argparse keyword arguments).
SESSION_OPTIONS = {
    'side': (('--arm', '--side'), dict(choices=['left', 'right'], help='arm (and its hand camera)')),
    'table_top_z': (('--table-top-z',), dict(type=float, help='table top height in base (m); a --hand-eye file '
                                                              'with a table plane replaces it')),
    'camera_calibration': (('--camera-calibration',), dict(metavar='YAML', help="camera calibration to use "
                                                                                "instead of the robot's camera_info")),
    'hand_eye': (('--hand-eye',), dict(metavar='YAML', help='hand-eye calibration (calibrate_hand_eye.py) to use '
                                                            'instead of tf / the URDF')),
    'speed_ratio': (('--speed-ratio',), dict(type=float, help='arm speed ratio (0, 1]')),
    'camera_exposure': (('--camera-exposure',), dict(type=int, help='hand camera exposure 0-100 (-1: automatic)')),
    'camera_gain': (('--camera-gain',), dict(type=int, help='hand camera gain 0-79 (-1: automatic)')),
    'save_views': (('--save-views',), dict(action='store_true', default=None,
                                           help='save every annotated camera view as a PNG in OUTPUT_DIR/views')),
}


def add_session_arguments(parser, default_config, cycles=False):
    """The options every task script takes: ``--config`` (the task's YAML, default ``default_config``), the
    session options above, ``--vision-config``, ``--result-json``, ``--output-dir`` (and ``--cycles``)."""
    parser.add_argument('--config', default=default_config, help='parameters YAML (default %(default)s)')
    for key, (flags, options) in SESSION_OPTIONS.items():
        parser.add_argument(*flags, dest=key, **options)
    if cycles:
        parser.add_argument('--cycles', type=int, help='run the task this many times, one after the other')
    parser.add_argument('--vision-config', metavar='YAML', help='vision parameters (default config/vision.yaml)')
    parser.add_argument('--result-json', metavar='FILE', help='write the result JSON here')
    parser.add_argument('--output-dir', metavar='DIR', help='write the result and plots here')


def private_parameters(names):
    """The private ROS parameters (``~name``) that are set, of ``names``."""
    return {name: rospy.get_param('~' + name) for name in names if rospy.has_param('~' + name)}


def read_configs(task_class, args, task_keys, extra_overrides=None, private_params=None):
    """``(task_class config, SessionConfig)`` from ``args.config``, the private parameters (read from the
    parameter server unless ``private_params`` is given) and the command line (``args``' ``task_keys``, the
    session options, ``cycles`` if parsed, and ``extra_overrides``). ParameterError names a bad key."""
    if private_params is None:
        private_params = private_parameters(field_names(task_class) + field_names(SessionConfig))
    keys = list(task_keys) + [name for name in SESSION_OPTIONS] + (['cycles'] if hasattr(args, 'cycles') else [])
    overrides = {name: getattr(args, name, None) for name in keys}
    overrides.update(extra_overrides or {})
    return load_configs(task_class, args.config, private_params, overrides)


def start(name, argv, parse_args, build):
    """The node ``name`` started on the command line ``argv`` (``rospy.myargv`` when None): ``(args, configs)``
    with ``configs = build(args)``, or ``(args, None)`` after logging the error when a parameter or file is bad
    (the script then exits 2: nothing reached the robot)."""
    args = parse_args(rospy.myargv()[1:] if argv is None else argv)
    rospy.init_node(name, disable_signals=False)
    return args, configure(name, lambda: build(args))


def configure(name, build):
    """``build()`` (returning the run's configs), or None after logging the error when a parameter or file is
    bad."""
    try:
        configs = build()
    except CONFIG_ERRORS as error:
        rospy.logerr('%s: bad configuration: %s' % (name, error))
        return None
    merged = {}
    for config in configs:
        if hasattr(config, 'as_dict'):
            merged.update(config.as_dict())
    rospy.loginfo('%s: %s' % (name, json.dumps(merged)))
    return configs
