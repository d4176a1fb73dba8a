"""The layout's rules (docs/ARCHITECTURE.md): the import graph goes one way, pure cores import no rospy, no module
is over 700 lines, and only sim/ and bench/ touch the fake's ground truth (no other module, script, launch or
config file names a topic or service of the fake's own namespace, /fake_baxter/, nor imports sim/)."""
import ast
import os

import pytest

from baxter_pnp.runtime import PACKAGE_ROOT

SOURCE = os.path.join(PACKAGE_ROOT, 'src', 'baxter_pnp')
PURE = ('params', 'transforms', 'calibration', 'synthetic', 'models', 'pose', 'silhouette', 'on_table', 'perception',
        'servo', 'view', 'kinematics', 'safety', 'pick', 'vision', 'task.settings', 'task.target', 'robot.sdk', 'hand_eye',
        'board_views', 'survey', 'table_map', 'table_plan')
# What sim/ may import from the package: the pure cores it renders and simulates with, and the SDK's names.
SIM_MAY_IMPORT = ('sim', 'camera', 'kinematics', 'models', 'transforms', 'runtime', 'msgs', 'ros_image',
                  'synthetic', 'params', 'robot', 'robot.sdk')
MAX_LINES = 700
ROS_ENDPOINTS = ('Publisher', 'Subscriber', 'Service', 'state_publisher')
FAKE_NAMESPACE = 'fake_baxter/'    # the fake's node name: its private (~) topics and services live below it
# Scripts exempt from the ground-truth rule: the fake's own entry point and the benchmarks' (they only call the
# main of a sim/ or bench/ module, checked below; docs/ARCHITECTURE.md: bench/ reads the ground truth).
FAKE_AND_BENCH_SCRIPTS = {'fake_baxter.py': 'sim.node', 'run_trials.py': 'bench.trials',
                          'run_experiments.py': 'bench.experiments', 'bench_perception.py': 'bench.perception_bench',
                          'demo.py': 'bench.demo', 'perception_demo.py': 'bench.perception_demo',
                          'bench_render.py': 'bench.render_bench', 'bench_appearance.py': 'bench.appearance_stats',
                          'bench_hand_eye.py': 'bench.hand_eye_bench', 'bench_real_time.py': 'bench.real_time_bench',
                          'rviz_screenshot.py': 'bench.rviz_screenshot'}


def modules():
    """{dotted name below baxter_pnp: path} of every package module (generated messages excluded)."""
    found = {}
    for directory, _, files in os.walk(SOURCE):
        if '_generated' in directory or '__pycache__' in directory:
            continue
        for name in files:
            if name.endswith('.py'):
                path = os.path.join(directory, name)
                dotted = os.path.relpath(path, SOURCE)[:-3].replace(os.sep, '.')
                found[dotted[:-len('.__init__')] if dotted.endswith('.__init__') else dotted] = path
    return found


def imports(path):
    """Every module an import statement names anywhere in the file (function-level imports included)."""
    names = set()
    for node in ast.walk(ast.parse(open(path).read())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names.update('%s.%s' % (node.module, alias.name) for alias in node.names)
    return names


def package_imports(path):
    """The package modules (dotted below baxter_pnp) a file imports."""
    known = modules()
    return {name[len('baxter_pnp.'):] for name in imports(path)
            if name.startswith('baxter_pnp.') and name[len('baxter_pnp.'):] in known}


def test_the_fake_imports_nothing_of_the_task_layers_or_the_benchmarks():
    for name, path in modules().items():
        if name == 'sim' or name.startswith('sim.'):
            bad = {m for m in package_imports(path) if m.split('.')[0] not in ('sim',) and m not in SIM_MAY_IMPORT}
            assert not bad, '%s imports %s' % (name, sorted(bad))


def test_nothing_below_bench_imports_it():
    for name, path in modules().items():
        if not name.startswith('bench'):
            assert not {m for m in package_imports(path) if m.startswith('bench')}, name


def test_pure_cores_import_no_rospy():
    checked = 0
    for name, path in modules().items():
        if any(name == pure or name.startswith(pure + '.') for pure in PURE):
            ros = {m for m in imports(path) if m.split('.')[0] in ('rospy', 'tf2_ros', 'rosgraph', 'roslaunch')}
            assert not ros, '%s (pure) imports %s' % (name, sorted(ros))
            checked += 1
    assert checked >= len(PURE)


@pytest.mark.parametrize('root', ['src', 'scripts'])
def test_no_module_over_700_lines(root):
    for directory, _, files in os.walk(os.path.join(PACKAGE_ROOT, root)):
        if '_generated' in directory:
            continue
        for name in files:
            if name.endswith('.py'):
                with open(os.path.join(directory, name)) as f:
                    lines = sum(1 for _ in f)
                assert lines <= MAX_LINES, '%s: %d lines' % (name, lines)


def fake_private_names():
    """Names of the fake's private topics and services (``~name`` in sim/: rospy.Publisher, Subscriber, Service,
    ``sim.publishers.state_publisher``)."""
    names = set()
    for name, path in modules().items():
        if name.split('.')[0] != 'sim':
            continue
        for node in ast.walk(ast.parse(open(path).read())):
            called = getattr(node.func, 'attr', getattr(node.func, 'id', None)) if isinstance(node, ast.Call) else None
            if (called in ROS_ENDPOINTS and node.args
                    and isinstance(node.args[0], ast.Constant) and str(node.args[0].value).startswith('~')):
                names.add(node.args[0].value[1:])
    return names


def names_of_the_fake(text, private_names):
    """The strings in Python source ``text`` (constants, f-string parts) that name a topic or service of the
    fake's namespace: containing 'fake_baxter/', or a private name alone or as a path's last part."""
    found = []
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            value = node.value
            last_part = value.rsplit('/', 1)[-1] if '/' in value else None
            if FAKE_NAMESPACE in value or value.lstrip('~/') in private_names or last_part in private_names:
                found.append(value)
    return found


def test_the_fakes_ground_truth_names_are_found():
    """Premise of the rule below: the parse finds the ground truth the fake publishes (docs/fake_baxter.md)."""
    assert {'object_poses', 'respawns'} <= fake_private_names()
    assert names_of_the_fake("rospy.Subscriber('/fake_baxter/object_poses', PoseArray, f)", set()) != []
    assert names_of_the_fake("topic = f'/{node}/respawns'", {'respawns'}) != []
    assert names_of_the_fake("ns = 'fake_baxter/'", set()) != []
    assert names_of_the_fake("log('respawns are off')", {'respawns'}) == []


def test_only_the_fake_and_the_benchmarks_touch_the_ground_truth():
    """No package module outside sim/ and bench/ names a topic or service of the fake's namespace or imports
    sim/ (the application reaches the fake only through the robot's SDK interfaces)."""
    private_names, checked = fake_private_names(), 0
    for name, path in modules().items():
        if name.split('.')[0] in ('sim', 'bench'):
            continue
        assert not names_of_the_fake(open(path).read(), private_names), name
        assert not {m for m in package_imports(path) if m.split('.')[0] == 'sim'}, '%s imports sim/' % name
        checked += 1
    assert checked > 40                       # premise: the walk saw the package (robot/, task/, vision/, ...)


def test_scripts_launch_and_config_files_name_no_ground_truth():
    """The application's scripts (pick_square.py, detect_image.py, the calibrations) name no topic of the fake's
    namespace and import neither sim/ nor bench/; the exempt ones only start a sim/ or bench/ main; no launch or
    config file names the fake's namespace (a remap onto the ground truth would hide it from the check above)."""
    private_names, scripts = fake_private_names(), os.path.join(PACKAGE_ROOT, 'scripts')
    application_scripts = set()
    for script in sorted(os.listdir(scripts)):
        if not script.endswith('.py'):
            continue
        path = os.path.join(scripts, script)
        imported = {name[len('baxter_pnp.'):] for name in imports(path) if name.startswith('baxter_pnp.')}
        if script in FAKE_AND_BENCH_SCRIPTS:
            assert imported <= {'runtime', 'runtime.use_project_venv', FAKE_AND_BENCH_SCRIPTS[script],
                                FAKE_AND_BENCH_SCRIPTS[script] + '.main'}, '%s imports %s' % (script, imported)
            continue
        application_scripts.add(script)
        assert not names_of_the_fake(open(path).read(), private_names), script
        assert not {m for m in imported if m.split('.')[0] in ('sim', 'bench')}, '%s imports %s' % (script, imported)
    assert 'pick_square.py' in application_scripts
    for directory, extensions in (('launch', ('.launch', '.xml')), ('config', ('.yaml', '.yml'))):
        for root, _, files in os.walk(os.path.join(PACKAGE_ROOT, directory)):
            for name in files:
                if name.endswith(extensions):
                    with open(os.path.join(root, name)) as f:
                        assert FAKE_NAMESPACE not in f.read(), os.path.join(directory, name)


def test_every_entry_points_help_says_what_it_does():
    """The ``--help`` description of each command (``runtime.command_summary`` of its module's docstring): one
    sentence, capitalised, without the usage or reST's double backquotes."""
    from baxter_pnp.runtime import command_summary
    described = {name: path for name, path in modules().items() if 'command_summary(__doc__)' in open(path).read()}
    assert len(described) >= 13, sorted(described)
    for name, path in described.items():
        summary = command_summary(ast.get_docstring(ast.parse(open(path).read()), clean=False))
        assert summary[0].isupper() and summary.endswith('.') and '``' not in summary and '\n' not in summary, \
            (name, summary)
    assert command_summary('``pick.py ARGS``: picks\n  a block.\n\nMore.') == 'Picks a block.'
