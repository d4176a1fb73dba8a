"""The layout's rules (docs/ARCHITECTURE.md): the import graph goes one way, pure cores import no rospy, no module
is over 700 lines, and only sim/ and bench/ touch the fake's ground truth."""
import ast
import os

import pytest

from baxter_pnp.runtime import PACKAGE_ROOT

SOURCE = os.path.join(PACKAGE_ROOT, 'src', 'baxter_pnp')
PURE = ('params', 'transforms', 'calibration', 'synthetic', 'models', 'pose', 'perception', 'servo', 'view',
        'kinematics', 'safety', 'pick', 'vision', 'task.settings', 'task.target', 'robot.sdk')
# What sim/ may import from the package: the pure cores it renders and simulates with, and the SDK's names.
SIM_MAY_IMPORT = ('sim', 'camera', 'kinematics', 'models', 'transforms', 'runtime', 'msgs', 'ros_image',
                  'synthetic', 'params', 'robot', 'robot.sdk')
GROUND_TRUTH_TOPICS = ('/fake_baxter/object_poses', '/fake_baxter/respawns')
MAX_LINES = 700


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


def test_only_the_fake_and_the_benchmarks_touch_the_ground_truth():
    for name, path in modules().items():
        if name.split('.')[0] in ('sim', 'bench'):
            continue
        text = open(path).read()
        assert not any(topic in text for topic in GROUND_TRUTH_TOPICS), name
