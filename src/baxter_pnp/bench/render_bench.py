"""Camera rendering benchmark (``make bench-render``): ms per frame of each way the fake Baxter can draw its
hand camera, and the speed of the world loop (physics + camera) with each, measured side by side.

Every candidate runs in its own process (a renderer library initialises once per process, and
``LP_NUM_THREADS``, Mesa's llvmpipe thread count, is read then), on the default scene from a start pose,
drawing ``left_hand_camera`` at 640x400 as the fake does (the ideal pinhole with the margin the lens
distortion needs, 657x413 px, then ``cv2.remap``):

- ``tiny``: PyBullet's TinyRenderer (``sim.render.TinyRenderer``);
- ``egl``, ``egl LP=0|1``: OpenGL through EGL (``sim.render.EglRenderer``) with llvmpipe's default thread count
  (one per core) or ``LP_NUM_THREADS`` 0 (rasterised in the calling thread) or 1;
- ``tiny baxter``, ``egl baxter``: the same with the scene's ``appearance: baxter`` (the table a speckle texture,
  ``sim.appearance.table_texture``; EGL draws it as TinyRenderer does); ``|diff|`` against ``tiny baxter``;
- ``pybullet-egl``: PyBullet's own EGL plugin (``eglRenderer``, ``ER_BULLET_HARDWARE_OPENGL``), loaded before the
  bodies are made. Its images are not the fake's (it skips meshes given as vertices -- the blocks --, shades
  with its own fixed light model and a shadow pass): timed for comparison only.

Columns: ``render`` = wall ms per ``world._render`` (draw + remap), median; ``cpu`` = CPU ms per frame of the
whole process (all threads: llvmpipe's and PyBullet's workers too); ``|diff|`` = mean absolute difference to
the ``tiny`` image (grey levels); ``loop`` = simulated seconds per wall second of a bare world loop (240 Hz
physics steps, a frame every 1/20 s, no ROS, no noise), i.e. the fake's ceiling with that renderer.
"""
import argparse
import dataclasses
import json
import os
import pkgutil
import subprocess
import sys
import tempfile
import time

import numpy as np

from baxter_pnp.runtime import command_summary

CANDIDATES = {          # name: (renderer, extra environment, appearance)
    'tiny': ('tiny', {}, 'clean'),
    'egl': ('egl', {}, 'clean'),
    'egl LP=0': ('egl', {'LP_NUM_THREADS': '0'}, 'clean'),
    'egl LP=1': ('egl', {'LP_NUM_THREADS': '1'}, 'clean'),
    'tiny baxter': ('tiny', {}, 'baxter'),
    'egl baxter': ('egl', {}, 'baxter'),
    'pybullet-egl': ('pybullet-egl', {}, 'clean'),
}
CAMERA = ('left_hand_camera', 640, 400, 20.0)      # name, width, height, fps


def process_cpu_seconds():
    """User + system CPU seconds of this process so far, all threads (Linux /proc)."""
    with open('/proc/self/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def make_world(renderer, start, look='clean'):
    """SimWorld of the default scene from ``start`` with appearance preset ``look``; ``renderer`` 'pybullet-egl'
    loads PyBullet's EGL plugin into the world's client before its bodies exist (the plugin only draws bodies made
    after it) and draws with TinyRenderer calls, which the plugin then serves."""
    import pybullet as p
    from baxter_pnp.sim.scene import DEFAULT_SCENE_YAML, load_scene
    from baxter_pnp.sim.world import SimWorld
    from baxter_pnp.sim.appearance import AppearanceConfig, expand
    scene = dataclasses.replace(load_scene(DEFAULT_SCENE_YAML), start=start,
                                appearance=AppearanceConfig.from_dict(expand(look)))
    if renderer != 'pybullet-egl':
        return SimWorld(scene, renderer=renderer)
    connect = p.connect

    def connect_with_plugin(*args, **kwargs):
        client = connect(*args, **kwargs)
        p.loadPlugin(pkgutil.get_loader('eglRenderer').get_filename(), '_eglRendererPlugin', physicsClientId=client)
        return client
    p.connect = connect_with_plugin
    try:
        return SimWorld(scene, renderer='tiny')
    finally:
        p.connect = connect


def measure(renderer, start, frames, image_path, look='clean'):
    """{render_ms, cpu_ms, loop_factor, description} of ``renderer`` in this process; the last image goes to
    ``image_path`` (.npy)."""
    from baxter_pnp.sim.cameras import sensor_model, sensor_window
    name, width, height, fps = CAMERA
    world = make_world(renderer, start, look)
    camera = sensor_model(name).windowed(sensor_window(width, height))
    image = world._render(name, camera)                  # warm-up: shader compilation, maps
    times, cpu = [], process_cpu_seconds()
    for _ in range(frames):
        began = time.perf_counter()
        image = world._render(name, camera)
        times.append(time.perf_counter() - began)
    cpu = process_cpu_seconds() - cpu
    np.save(image_path, image)
    steps_per_frame = round(1.0 / fps / world.time_step)
    simulated, began = 0.0, time.perf_counter()
    for _ in range(frames):
        world.step(steps_per_frame)
        world._render(name, camera)
        simulated += steps_per_frame * world.time_step
    loop_factor = simulated / (time.perf_counter() - began)
    description = 'PyBullet eglRenderer plugin' if renderer == 'pybullet-egl' else world.renderer_description
    world.close()
    return {'render_ms': 1000 * float(np.median(times)), 'cpu_ms': 1000 * cpu / frames,
            'loop_factor': loop_factor, 'description': description}


def run_candidate(name, start, frames, folder):
    """``measure`` in a child process for candidate ``name``; (results dict, image) or (None, error text)."""
    renderer, extra, look = CANDIDATES[name]
    image_path = os.path.join(folder, name.replace(' ', '_').replace('=', '') + '.npy')
    command = [sys.executable, '-m', 'baxter_pnp.bench.render_bench', '--worker', renderer, '--start', start,
               '--frames', str(frames), '--image', image_path, '--look', look]
    done = subprocess.run(command, env={**os.environ, **extra}, capture_output=True, text=True, timeout=600)
    lines = [line for line in done.stdout.splitlines() if line.startswith('{')]
    if done.returncode != 0 or not lines:
        return None, (done.stderr.strip().splitlines() or ['exit %d' % done.returncode])[-1]
    return json.loads(lines[-1]), np.load(image_path)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='bench_render.py', description=command_summary(__doc__))
    parser.add_argument('--frames', type=int, default=60, help='frames per candidate; default %(default)s')
    parser.add_argument('--start', default='angled', choices=('angled', 'down', 'neutral'),
                        help='start pose of the left arm (what the camera sees); default %(default)s')
    parser.add_argument('--only', action='append', choices=sorted(CANDIDATES), help='candidates to run (repeatable)')
    parser.add_argument('--worker', help=argparse.SUPPRESS)
    parser.add_argument('--image', help=argparse.SUPPRESS)
    parser.add_argument('--look', default='clean', help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        print(json.dumps(measure(args.worker, args.start, args.frames, args.image, args.look)))
        return 0
    print(f'{CAMERA[0]} {CAMERA[1]}x{CAMERA[2]}, start pose {args.start}, {args.frames} frames per candidate, '
          f'{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}')
    print(f'{"candidate":14s} {"render ms":>9s} {"cpu ms":>7s} {"|diff|":>7s} {"loop x":>7s}  renderer')
    references = {}         # appearance -> the tiny image of it
    with tempfile.TemporaryDirectory() as folder:
        for name in args.only or list(CANDIDATES):
            result, image = run_candidate(name, args.start, args.frames, folder)
            if result is None:
                print(f'{name:14s} unavailable: {image}')
                continue
            look = CANDIDATES[name][2]
            if CANDIDATES[name][0] == 'tiny':
                references.setdefault(look, image.astype(np.int16))
            reference = references.get(look)
            diff = '-' if reference is None else f'{np.abs(image.astype(np.int16) - reference).mean():.2f}'
            print(f'{name:14s} {result["render_ms"]:9.1f} {result["cpu_ms"]:7.1f} {diff:>7s} '
                  f'{result["loop_factor"]:7.2f}  {result["description"]}', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
