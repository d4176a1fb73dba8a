"""``make rviz-screenshot``: rviz with ``config/baxter_pnp.rviz`` on a headless X server, after a table survey on the
fake Baxter, saved as a PNG (the README's picture).

Xvfb (Debian's ``xvfb``) keeps its screen in a file (``-fbdir``, XWD format); rviz draws with Mesa's software
renderer. Steps: a rosmaster, the fake on ``--scene`` (default: the stack scene's three blocks), ``table_task.py
survey`` with rviz already running (the map and debug image are latched by the survey's process: rviz keeps the
last ones it received), ``--settle`` more seconds, then the screen file is read and written as ``--out``. Needs ``rviz`` and ``xvfb``; exits 2 when either is
missing.
"""
import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time

import cv2
import numpy as np

from baxter_pnp.runtime import PACKAGE_ROOT, command_summary
from baxter_pnp.sim import launcher

RVIZ_CONFIG = os.path.join(PACKAGE_ROOT, 'config', 'baxter_pnp.rviz')
_XWD_HEADER_FIELDS = 25     # CARD32 fields of an XWD (version 7) file header, big-endian


def read_xwd(path):
    """(H, W, 3) uint8 BGR image of an XWD screen dump with 24- or 32-bit TrueColor pixels (Xvfb's ``-fbdir``)."""
    data = open(path, 'rb').read()
    header = np.frombuffer(data[:4 * _XWD_HEADER_FIELDS], dtype='>u4')
    header_size, version = int(header[0]), int(header[1])
    width, height, byte_order = int(header[4]), int(header[5]), int(header[7])
    bits_per_pixel, bytes_per_line, ncolors = int(header[11]), int(header[12]), int(header[19])
    if version != 7 or bits_per_pixel not in (24, 32):
        raise ValueError(f'{path}: XWD version {version}, {bits_per_pixel} bits per pixel: not a TrueColor dump')
    start = header_size + 12 * ncolors
    rows = np.frombuffer(data[start:start + bytes_per_line * height], np.uint8).reshape(height, bytes_per_line)
    pixels = rows[:, :width * bits_per_pixel // 8].reshape(height, width, bits_per_pixel // 8)
    return np.ascontiguousarray(pixels[..., :3] if byte_order == 0 else pixels[..., ::-1][..., :3])


def main(argv=None):
    parser = argparse.ArgumentParser(prog='rviz_screenshot.py', description=command_summary(__doc__))
    parser.add_argument('--out', default=os.path.join(PACKAGE_ROOT, 'docs', 'images', 'rviz.png'))
    parser.add_argument('--scene', default=os.path.join(PACKAGE_ROOT, 'config', 'scenes', 'stack.yaml'))
    parser.add_argument('--settle', type=float, default=10.0, help='seconds rviz draws after the survey')
    parser.add_argument('--size', default='1440x900')
    args = parser.parse_args(argv)
    missing = [tool for tool in ('rviz', 'Xvfb') if shutil.which(tool) is None]
    if missing:
        print('rviz_screenshot: not installed: %s (apt-get install rviz xvfb)' % ', '.join(missing), file=sys.stderr)
        return 2
    work = tempfile.mkdtemp(prefix='rviz_shot_')
    display = ':%d' % (90 + os.getpid() % 100)
    xvfb = subprocess.Popen(['Xvfb', display, '-screen', '0', args.size + 'x24', '-fbdir', work, '-nolisten', 'tcp'],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    master = launcher.RosMaster()
    fake = rviz = None
    try:
        master.start()
        fake = launcher.FakeBaxterProcess(master, ['--scene', args.scene, '--enable'],
                                          log_path=os.path.join(work, 'fake.log'))
        fake.start()
        env = dict(master.env(), DISPLAY=display, LIBGL_ALWAYS_SOFTWARE='1')
        rviz = subprocess.Popen(['rviz', '-d', RVIZ_CONFIG], env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, start_new_session=True)
        survey = launcher.run_script(master, 'table_task.py', ['survey', '--output-dir', work], timeout=600,
                                     log_path=os.path.join(work, 'survey.log'))
        print('survey: exit %s in %.0f s (log %s)' % (survey.returncode, survey.wall_seconds, survey.log_path))
        time.sleep(args.settle)
        image = read_xwd(os.path.join(work, 'Xvfb_screen0'))
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        cv2.imwrite(args.out, image)
        print('rviz_screenshot: %s (%dx%d)' % (args.out, image.shape[1], image.shape[0]))
        return 0 if survey.returncode == 0 else 1
    finally:
        for process in (rviz, xvfb):
            if process is not None:
                launcher.stop_process_group(process)
        if fake is not None:
            fake.stop()
        master.stop()
