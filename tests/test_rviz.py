"""The rviz configuration and launch arguments (README "Multi-block tasks", `make rviz-screenshot`).

The config must show what the application publishes, under the names it publishes them (a renamed topic leaves
an empty panel and no error anywhere); both launch files start rviz with it on `rviz:=true`; the screenshot's XWD
reader gives back the pixels Xvfb wrote. The screenshot itself (rviz on Xvfb, ~1 min) is `make rviz-screenshot`.
"""
import os
import xml.etree.ElementTree as ElementTree

import numpy as np
import pytest
import yaml

from baxter_pnp.bench.rviz_screenshot import RVIZ_CONFIG, read_xwd
from baxter_pnp.robot import sdk
from baxter_pnp.task import eye, survey

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _displays():
    with open(RVIZ_CONFIG) as f:
        config = yaml.safe_load(f)
    return config['Visualization Manager']


def test_the_rviz_config_shows_what_the_application_publishes():
    manager = _displays()
    assert manager['Global Options']['Fixed Frame'] == 'base'
    by_class = {}
    for display in manager['Displays']:
        topic = display.get('Image Topic') or display.get('Marker Topic') or display.get('Topic')
        by_class.setdefault(display['Class'], set()).add(topic)
    assert by_class['rviz/Image'] == {eye.DEBUG_IMAGE_TOPIC, sdk.camera_topics('left_hand_camera')[0]}
    assert by_class['rviz/MarkerArray'] == {survey.TABLE_MAP_TOPIC}
    assert by_class['rviz/Pose'] == {eye.TARGET_POSE_TOPIC}
    assert 'rviz/RobotModel' in by_class


@pytest.mark.parametrize('launch', ['pick_square.launch', 'table_task.launch'])
def test_rviz_true_starts_rviz_with_the_config(launch):
    root = ElementTree.parse(os.path.join(REPO, 'launch', launch)).getroot()
    assert root.find("arg[@name='rviz']").get('default') == 'false'
    [node] = [n for n in root.iter('node') if n.get('pkg') == 'rviz']
    assert node.get('if') == '$(arg rviz)'
    assert node.get('args') == '-d $(find baxter_pnp)/config/baxter_pnp.rviz'


def _xwd(pixels_bgrx, byte_order):
    """An XWD v7 file of 32-bit pixels (H, W, 4), written as X servers write it."""
    height, width = pixels_bgrx.shape[:2]
    name = b'screen\x00'
    header_size = 4 * 25 + len(name)
    fields = [header_size, 7, 2, 24, width, height, 0, byte_order, 32, byte_order, 32, 32, 4 * width, 4,
              0xff0000, 0xff00, 0xff, 8, 256, 2, width, height, 0, 0, 0]
    colormap = b'\x00' * 24
    data = pixels_bgrx if byte_order == 0 else pixels_bgrx[..., ::-1]
    return np.array(fields, '>u4').tobytes() + name + colormap + data.tobytes()


@pytest.mark.parametrize('byte_order', [0, 1])
def test_read_xwd_gives_the_pixels_back(tmp_path, byte_order):
    rng = np.random.default_rng(3)
    bgrx = rng.integers(0, 256, size=(5, 7, 4), dtype=np.uint8)
    path = tmp_path / 'screen.xwd'
    path.write_bytes(_xwd(bgrx, byte_order))
    np.testing.assert_array_equal(read_xwd(str(path)), bgrx[..., :3])
