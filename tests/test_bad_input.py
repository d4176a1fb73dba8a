"""Bad input (issue 10's acceptance): any image size, depth or channel count, empty or corrupt files, NaN or
non-positive values in a camera YAML or CameraInfo, broken bags: a clear error, never a pose.

Through the library (``vision.detect``, ``perception.observe_blocks``, ``CameraModel.from_yaml``,
``CameraModel.from_camera_info``: ValueError) and through ``detect_image.py`` (exit 2 for arguments and
configuration, 1 for an image, frame or bag that cannot be used; the other inputs of the run are still reported).
"""
import re

import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Image

import recorded_runs as runs
from baxter_pnp import detect_cli, perception, synthetic, vision
from baxter_pnp.camera import CameraModel, load_default_camera

SIDE = 0.04
T0_NS = 1543526450 * 10**9                         # ROS time of the bags' first frame (ns)
GREEN, RED = (40, 170, 40), (40, 40, 200)          # BGR


@pytest.fixture(scope='module')
def config():
    return vision.VisionConfig.from_yaml()


@pytest.fixture(scope='module')
def thesis_view(tmp_path_factory):
    """(path of a PNG, the BGR image): a green square seen by the thesis camera (640x480)."""
    image = block_image(load_default_camera())
    path = tmp_path_factory.mktemp('views') / 'thesis_view.png'
    cv2.imwrite(str(path), image)
    return path, image


def block_image(camera, colour_bgr=GREEN, seed=0):
    """A rendered view of one square block of ``colour_bgr`` (BGR uint8, the camera's size)."""
    rng = np.random.default_rng(seed)
    block = synthetic.BlockSpec('square', SIDE, 0.02, colour_bgr)
    T_camera_block = synthetic.random_block_pose(rng, (0.2, 0.25), 15.0, camera=camera, margin_px=40, block=block)
    return synthetic.render_block_scene(camera, [(block, T_camera_block)], rng)[0]


def run_cli(capsys, *argv):
    """(exit status, JSON reports on stdout, stderr) of ``detect_image.py argv --side 0.04 --json``."""
    status = detect_cli.main([str(a) for a in argv] + ['--side', str(SIDE), '--json'])
    output = capsys.readouterr()
    return status, runs.json_lines(output.out), output.err


# ------------------------------------------------------------------------------------------------ library

BAD_ARRAYS = {
    '16-bit': (np.zeros((40, 60, 3), np.uint16), 'uint8'),
    'float': (np.zeros((40, 60, 3), np.float32), 'uint8'),
    '1-channel': (np.zeros((40, 60), np.uint8), 'mono8'),
    '1-channel 3-d': (np.zeros((40, 60, 1), np.uint8), r'\(H, W, 3\)'),
    '2-channel': (np.zeros((40, 60, 2), np.uint8), r'\(H, W, 3\)'),
    '4-channel': (np.zeros((40, 60, 4), np.uint8), r'\(H, W, 3\)'),
    '0x0': (np.zeros((0, 0, 3), np.uint8), 'empty'),
    '0 rows': (np.zeros((0, 640, 3), np.uint8), 'empty'),
    'not an array': ([[[0, 0, 0]]], 'numpy array'),
}


@pytest.mark.parametrize('name', BAD_ARRAYS)
def test_the_library_refuses_images_it_cannot_segment(name, config):
    image, message = BAD_ARRAYS[name]
    with pytest.raises(ValueError, match=message):
        vision.detect(image, config)
    with pytest.raises(ValueError, match=message):
        perception.observe_blocks(image, load_default_camera(), config, SIDE)


def test_tiny_and_extreme_aspect_images_give_no_detection(config):
    """1x1, 1x5000, 5000x1 and 20x4000 images (the block's colour everywhere): valid arrays, nothing to find;
    posing them with a camera model of another size is refused (the poses would be silently wrong)."""
    for height, width in ((1, 1), (1, 5000), (5000, 1), (20, 4000)):
        image = np.full((height, width, 3), GREEN, np.uint8)
        assert vision.detect(image, config) == []
        with pytest.raises(ValueError, match='but the camera model is 640x480'):
            perception.observe_blocks(image, load_default_camera(), config, SIDE)


def edit_matrix(key, index, value):
    return lambda d: d[key]['data'].__setitem__(index, value)


BAD_YAML_EDITS = {
    'NaN fx': (edit_matrix('camera_matrix', 0, float('nan')), 'camera_matrix must be finite'),
    'inf fx': (edit_matrix('camera_matrix', 0, float('inf')), 'camera_matrix must be finite'),
    'NaN fy': (edit_matrix('camera_matrix', 4, float('nan')), 'camera_matrix must be finite'),
    'zero fx': (edit_matrix('camera_matrix', 0, 0.0), 'zero focal length'),
    'zero fy': (edit_matrix('camera_matrix', 4, 0.0), 'zero focal length'),
    'negative fx': (edit_matrix('camera_matrix', 0, -409.0), 'focal lengths must be positive'),
    'negative fy': (edit_matrix('camera_matrix', 4, -409.0), 'focal lengths must be positive'),
    'NaN D': (edit_matrix('distortion_coefficients', 0, float('nan')), 'distortion_coefficients must be finite'),
    'inf D': (edit_matrix('distortion_coefficients', 4, float('-inf')), 'distortion_coefficients must be finite'),
    'NaN P': (edit_matrix('projection_matrix', 2, float('nan')), 'projection_matrix must be finite'),
    'NaN R': (edit_matrix('rectification_matrix', 0, float('nan')), 'rectification_matrix must be finite'),
    'text in K': (edit_matrix('camera_matrix', 2, 'centre'), 'camera_matrix data must be numbers'),
    'fx of 1e-30 px': (edit_matrix('camera_matrix', 0, 1e-30), "are no camera's"),
    'fy of 1e30 px': (edit_matrix('camera_matrix', 4, 1e30), "are no camera's"),
    'K not upper triangular': (edit_matrix('camera_matrix', 3, 5.0), 'must be upper triangular'),
    'R a scaling': (lambda d: d['rectification_matrix'].update(data=[2.0, 0, 0, 0, 2.0, 0, 0, 0, 2.0]),
                    'rectification_matrix must be a rotation'),
    'P with zero fx': (edit_matrix('projection_matrix', 0, 0.0), 'projection_matrix: focal lengths must be positive'),
    'width 0': (lambda d: d.update(image_width=0), 'size must be positive'),
    'negative height': (lambda d: d.update(image_height=-400), 'size must be positive'),
    'fractional width': (lambda d: d.update(image_width=640.5), 'image_width must be an integer'),
    'width as text': (lambda d: d.update(image_width='640 px'), 'image_width must be an integer'),
    'missing camera_matrix': (lambda d: d.pop('camera_matrix'), "missing field 'camera_matrix'"),
    'missing distortion': (lambda d: d.pop('distortion_coefficients'), "missing field 'distortion_coefficients'"),
    'missing height': (lambda d: d.pop('image_height'), "missing field 'image_height'"),
    'K without data': (lambda d: d['camera_matrix'].pop('data'), 'camera_matrix must be a mapping'),
}


def camera_info_fields():
    """The real robot's CameraInfo as ``rostopic echo`` prints it (a mapping; ``recorded_runs``)."""
    return runs.robot_sensor().camera_info_fields(runs.WINDOW_640x400, frame_id=runs.FRAME_ID)


def edit_list(key, index, value):
    return lambda d: d[key].__setitem__(index, value)


BAD_CAMERA_INFO_EDITS = {
    'NaN K': (edit_list('K', 0, float('nan')), 'finite'),
    'NaN P': (edit_list('P', 0, float('nan')), 'P must be 12 finite numbers'),
    'inf P': (edit_list('P', 6, float('inf')), 'P must be 12 finite numbers'),
    'short P': (lambda d: d.update(P=[1.0] * 4), 'P must be 12 finite numbers'),
    'NaN R': (edit_list('R', 4, float('nan')), 'R must be 9 finite numbers'),
    'NaN D': (edit_list('D', 1, float('nan')), 'finite'),
    'zero fx': (edit_list('K', 0, 0.0), 'focal lengths must be positive'),
    'negative fy': (edit_list('K', 4, -400.0), 'focal lengths must be positive'),
    'fx of 1e-30 px': (edit_list('K', 0, 1e-30), "are no camera's"),
    'K not upper triangular': (edit_list('K', 3, 5.0), 'must be upper triangular'),
    'R a reflection': (lambda d: d.update(R=[1.0, 0, 0, 0, 1.0, 0, 0, 0, -1.0]), 'R must be a rotation'),
    'P with zero fx': (edit_list('P', 0, 0.0), 'P: focal lengths must be positive'),
    'P with negative fy': (edit_list('P', 5, -400.0), 'P: focal lengths must be positive'),
    'ROI wider than the sensor': (lambda d: d['roi'].update(width=1300), 'larger than the sensor'),
    'ROI taller than the sensor': (lambda d: d['roi'].update(height=900), 'larger than the sensor'),
    'zero-width ROI': (lambda d: d['roi'].update(width=0), 'is not an image'),
    'negative ROI offset': (lambda d: d['roi'].update(x_offset=-20), 'roi.x_offset must be at least 0'),
    'negative binning': (lambda d: d.update(binning_x=-2), 'binning_x must be at least 0'),
    'K as a number': (lambda d: d.update(K=400.0), 'K must be a list of numbers'),
    'K of 3': (lambda d: d.update(K=[400.0, 400.0, 1.0]), 'K must have 9 elements'),
    'width 0 without ROI': (lambda d: d.update(width=0, roi={}), 'size must be positive'),
}


def write_yaml(path, fields):
    path.write_text(yaml.safe_dump(fields))
    return path


@pytest.mark.parametrize('name', list(BAD_YAML_EDITS) + [f'CameraInfo {n}' for n in BAD_CAMERA_INFO_EDITS])
def test_a_bad_camera_yaml_is_refused_by_the_library_and_by_detect_image(name, tmp_path, capsys, thesis_view):
    """Each bad calibration file: ValueError naming the field from ``CameraModel.from_yaml``; ``detect_image.py``
    exits 2 with that message and reports nothing, not even the good image it was given."""
    if name.startswith('CameraInfo '):
        edit, message = BAD_CAMERA_INFO_EDITS[name[len('CameraInfo '):]]
        fields = camera_info_fields()
    else:
        edit, message = BAD_YAML_EDITS[name]
        fields = load_default_camera().to_dict()
    edit(fields)
    path = write_yaml(tmp_path / 'bad.yaml', fields)
    with pytest.raises(ValueError, match=message):
        CameraModel.from_yaml(path)
    status, reports, err = run_cli(capsys, thesis_view[0], '--camera-info', path)
    assert (status, reports) == (2, [])
    assert 'bad configuration' in err and str(path) in err and re.search(message, err), err


@pytest.mark.parametrize('name', ['NaN K', 'NaN P', 'inf P', 'ROI wider than the sensor', 'zero fx'])
def test_a_bad_camera_info_message_is_refused(name):
    """The same fields in a ``sensor_msgs/CameraInfo`` message (the robot's, then edited)."""
    msg = runs.camera_info(0, 0)
    fields = camera_info_fields()
    BAD_CAMERA_INFO_EDITS[name][0](fields)
    msg.K, msg.P, msg.roi.width = fields['K'], fields['P'], fields['roi']['width']
    with pytest.raises(ValueError, match=BAD_CAMERA_INFO_EDITS[name][1]):
        CameraModel.from_camera_info(msg)


def test_bad_yaml_text_and_bad_numbers_in_arguments(tmp_path, capsys, thesis_view):
    """Not YAML, not a mapping, a binary file: exit 2 naming the file. --side or --height not a positive
    number, --every 0, a table plane that is not four numbers, has no normal or the camera under it, --towers
    without it: argparse's exit 2."""
    image_path = thesis_view[0]
    for text, message in (('K: [1, 2', 'not valid YAML'), ('- 1\n- 2\n', 'not a mapping'),
                          (b'\x89PNG\r\n\x1a\n\xff\xfe', 'not a text file')):
        path = tmp_path / 'camera.yaml'
        path.write_bytes(text if isinstance(text, bytes) else text.encode())
        status, reports, err = run_cli(capsys, image_path, '--camera-info', path)
        assert (status, reports) == (2, []) and message in err and str(path) in err, err
    for bad in (['--side', 'inf'], ['--side', 'nan'], ['--height', '-0.02'], ['--side', '0'], ['--every', '0'],
                ['--max-frames', '0'], ['--edge-radius', '-0.001'], ['--edge-radius', 'nan'],
                ['--edge-radius', '0.02'], ['--table-plane', '0,0,-1'], ['--table-plane', '0,0,0,-0.5'],
                ['--table-plane', '0,0,-1,0.5'], ['--table-plane', 'a,b,c,d'], ['--table-plane', 'nan,0,-1,-0.5'],
                ['--towers']):
        with pytest.raises(SystemExit) as exit_info:
            detect_cli.main([str(image_path), '--side', str(SIDE)] + bad)
        assert exit_info.value.code == 2, bad
        assert 'detect_image.py: error:' in capsys.readouterr().err


def test_a_table_plane_given_to_detect_image_poses_blocks_standing_on_it(tmp_path, capsys):
    """``--table-plane``: the block's own table gives its pose (within 2 mm of the truth); a table tilted 60 deg
    from its top face gives none (no block stands on it that way), as the pick's looks decide."""
    camera = load_default_camera()
    rng = np.random.default_rng(3)
    block = synthetic.BlockSpec('square', SIDE, 0.02, GREEN)
    T = synthetic.random_block_pose(rng, (0.2, 0.25), 15.0, camera=camera, margin_px=40, block=block)
    path = tmp_path / 'view.png'
    cv2.imwrite(str(path), synthetic.render_block_scene(camera, [(block, T)], rng)[0])
    normal = T[:3, 2]
    table = ','.join('%.9f' % v for v in (*normal, normal @ T[:3, 3] - 0.02))
    status, reports, _ = run_cli(capsys, path, '--table-plane=' + table)      # '=': it may start with a minus
    posed = [d for d in reports[0]['detections'] if d['position_m'] is not None]
    assert status == 0 and len(posed) == 1
    assert np.linalg.norm(np.subtract(posed[0]['position_m'], T[:3, 3])) < 0.002
    tilted = Rotation.from_rotvec(np.radians(60.0) * T[:3, 0]).apply(normal)
    status, reports, _ = run_cli(capsys, path, '--table-plane=' + ','.join(
        '%.9f' % v for v in (*tilted, tilted @ T[:3, 3] - 0.02)))
    assert status == 0 and all(d['position_m'] is None for d in reports[0]['detections'])
    assert any('tilted' in (d['error'] or '') for d in reports[0]['detections'])


# ------------------------------------------------------------------------------------------ image files

def test_unusable_image_files_are_named_with_the_reason_and_the_others_still_posed(tmp_path, capsys, thesis_view):
    """One run over every kind of bad file and two good ones (BGR, and BGRA as a robot frame saved with its
    alpha): exit 1, one line on stderr per bad file saying why, the good files posed (the same block), nothing
    else on stdout."""
    good, view = thesis_view
    good_bgra = tmp_path / 'good_bgra.png'
    cv2.imwrite(str(good_bgra), cv2.cvtColor(view, cv2.COLOR_BGR2BGRA))
    png, jpg = good.read_bytes(), cv2.imencode('.jpg', view)[1].tobytes()
    bad = {
        'empty.png': (b'', 'empty file'),
        'truncated.png': (png[:len(png) // 2], 'not an image OpenCV can decode'),
        'text.png': (b'this is not an image\n', 'not an image OpenCV can decode'),
        'truncated.jpg': (jpg[:int(len(jpg) * 0.6)], 'truncated JPEG'),
        'one_pixel.png': (cv2.imencode('.png', view[:1, :1])[1].tobytes(), 'too small to hold a block'),
        'strip.png': (cv2.imencode('.png', cv2.resize(view, (4000, 20)))[1].tobytes(), 'aspect ratios'),
        'deep.png': (cv2.imencode('.png', view.astype(np.uint16) * 257)[1].tobytes(), 'uint16 pixels'),
        'float.tiff': (cv2.imencode('.tiff', view.astype(np.float32) / 255)[1].tobytes(), 'float32 pixels'),
        'grey.png': (cv2.imencode('.png', cv2.cvtColor(view, cv2.COLOR_BGR2GRAY))[1].tobytes(), 'grey image'),
    }
    for name, (data, _) in bad.items():
        (tmp_path / name).write_bytes(data)
    bad['missing.png'] = (None, 'No such file')
    paths = [tmp_path / name for name in bad]
    status, reports, err = run_cli(capsys, good, *paths, good_bgra)
    assert status == 1
    assert [r['image'] for r in reports] == [str(good), str(good_bgra)]
    assert reports[0]['detections'] == reports[1]['detections']
    assert [(d['shape'], d['colour'], d['position_m'] is not None) for d in reports[0]['detections']] == [
        ('square', 'green', True)]
    lines = err.splitlines()
    for path, (_, reason) in zip(paths, bad.values()):
        assert [line for line in lines if f'cannot use image {path}: ' in line and reason in line], (path, err)
    assert len(lines) == len(bad), err


# ------------------------------------------------------------------------------------------------- bags

def nan_camera_info(stamp_ns, seq, key):
    info = runs.camera_info(stamp_ns, seq)
    values = list(getattr(info, key))
    values[0] = float('nan')
    setattr(info, key, values)
    return info


def test_unusable_bag_frames_are_named_and_the_others_posed(tmp_path, capsys):
    """A bag whose frames go wrong in every way a recording can: mono8, a 16-bit encoding, a data length that
    does not match step x height, a size that is not its CameraInfo's, CameraInfos with a NaN K or P. Each is
    one error line naming bag, seq and stamp (exit 1); the good bgra8 and rgb8 frames (a red block: a swapped
    channel order would make it blue) are posed, also after the bad CameraInfo was replaced."""
    camera = runs.window_camera(runs.WINDOW_640x400)
    green, red = block_image(camera), block_image(camera, RED, seed=1)
    t = [T0_NS + k * 10**8 for k in range(8)]
    wrong_length = runs.image(green, t[6], 6, 'bgr8')
    wrong_length.data = wrong_length.data[:-640]
    deep = Image(height=400, width=640, encoding='rgb16', step=640 * 6, data=bytes(400 * 640 * 6))
    frames = [
        (runs.image(green, t[0], 0), runs.camera_info(t[0], 0), None),
        (runs.image(green, t[1], 1, 'mono8'), None, 'mono8 image: the pipeline segments by colour'),
        (runs.stamped(deep, t[2], 2), None, "image encoding 'rgb16' is not supported"),
        (runs.image(cv2.resize(green, (320, 200)), t[3], 3), None,
         'the image is 320x200 but its camera_info describes a 640x400 image'),
        (runs.image(green, t[4], 4), nan_camera_info(t[4], 4, 'K'), 'camera_info .* is unusable: .*finite'),
        (runs.image(green, t[5], 5), nan_camera_info(t[5], 5, 'P'), 'unusable: CameraInfo: P must be 12 finite'),
        (wrong_length, runs.camera_info(t[6], 6), 'image data has'),
        (runs.image(red, t[7], 7, 'rgb8'), None, None),
    ]
    messages = []
    for image_msg, info, _ in frames:
        messages += runs.frame_messages(image_msg.header.stamp.to_nsec(), image_msg.header.seq, image_msg, info)
    bag = runs.write_bag(tmp_path / 'bad_frames.bag', messages)
    status, reports, err = run_cli(capsys, bag)
    assert status == 1
    assert [(r['seq'], [(d['colour'], d['position_m'] is not None) for d in r['detections']]) for r in reports] == [
        (0, [('green', True)]), (7, [('red', True)])]
    lines = err.splitlines()
    assert len(lines) == 6, err
    for (image_msg, _, reason), line in zip([f for f in frames if f[2]], lines):
        seq, stamp = image_msg.header.seq, image_msg.header.stamp
        assert line.startswith(f'detect_image: cannot use {bag} {runs.IMAGE_TOPIC} frame seq {seq} at '
                               f'{stamp.secs}.{stamp.nsecs:09d}: '), line
        assert re.search(reason, line), (reason, line)


def test_topics_that_are_not_in_the_bag_list_its_topics(tmp_path, capsys):
    """Exit 2 before any output (a good image given first prints nothing): an unknown --image-topic, a topic of
    another type, two image topics and none chosen, no camera_info and no --camera-info. Choosing the topic, or
    giving the calibration, replays it."""
    camera = runs.window_camera(runs.WINDOW_640x400)
    view = block_image(camera)
    image_path = tmp_path / 'view.png'
    cv2.imwrite(str(image_path), view)
    right = runs.image(view, T0_NS, 0)
    two_cameras = runs.write_bag(tmp_path / 'two.bag', runs.frame_messages(T0_NS, 0, runs.image(view, T0_NS, 0),
                                                                            runs.camera_info(T0_NS, 0))
                                 + [('/cameras/right_hand_camera/image', right, T0_NS + 5)])
    no_info = runs.write_bag(tmp_path / 'no_info.bag', runs.frame_messages(T0_NS, 0, runs.image(view, T0_NS, 0)))
    listing = f'{runs.INFO_TOPIC} (sensor_msgs/CameraInfo), {runs.IMAGE_TOPIC} (sensor_msgs/Image), ' \
              f'/cameras/right_hand_camera/image (sensor_msgs/Image)'
    cases = [
        ([two_cameras, '--image-topic', '/cameras/head_camera/image'], 'has no topic /cameras/head_camera/image'),
        ([two_cameras, '--image-topic', runs.INFO_TOPIC], 'holds sensor_msgs/CameraInfo, not sensor_msgs/Image'),
        ([two_cameras], 'has 2 sensor_msgs/Image topics: choose one with --image-topic'),
        ([two_cameras, '--image-topic', '/cameras/right_hand_camera/image'],
         'has no topic /cameras/right_hand_camera/camera_info'),
        ([no_info], f'has no topic {runs.INFO_TOPIC}'),
    ]
    for argv, message in cases:
        status, reports, err = run_cli(capsys, image_path, *argv)
        assert (status, reports) == (2, []) and message in err, (argv, err)
        if argv[0] == two_cameras:
            assert all(topic in err for topic in listing.split(', ')), err
    status, reports, err = run_cli(capsys, two_cameras, '--image-topic', runs.IMAGE_TOPIC.lstrip('/'))
    assert status == 0 and [r['topic'] for r in reports] == [runs.IMAGE_TOPIC] and reports[0]['detections']
    window_yaml = tmp_path / 'window.yaml'
    camera.to_yaml(window_yaml)
    status, reports, err = run_cli(capsys, no_info, '--camera-info', window_yaml)
    assert status == 0 and [d['colour'] for d in reports[0]['detections']] == ['green'], err


def test_unreadable_bags_are_named_and_the_readable_ones_replayed(tmp_path, capsys):
    """A text file named .bag, a bag cut in half, an unindexed bag (recording killed), a missing one: exit 1,
    one line each naming it; the good bag given with them is still replayed."""
    view = block_image(runs.window_camera(runs.WINDOW_640x400))
    good = runs.write_bag(tmp_path / 'good.bag', runs.frame_messages(T0_NS, 0, runs.image(view, T0_NS, 0),
                                                                      runs.camera_info(T0_NS, 0)))
    data = open(good, 'rb').read()
    (tmp_path / 'text.bag').write_text('not a bag\n')
    (tmp_path / 'half.bag').write_bytes(data[:len(data) // 2])
    bad = [tmp_path / 'text.bag', tmp_path / 'half.bag', tmp_path / 'missing.bag']
    status, reports, err = run_cli(capsys, *bad, good)
    assert status == 1 and [r['bag'] for r in reports] == [good], err
    lines = err.splitlines()
    assert len(lines) == len(bad), err
    for path, line in zip(bad, lines):
        assert line.startswith(f'detect_image: cannot read bag {path}: '), line
