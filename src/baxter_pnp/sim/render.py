"""Camera renderers of the fake Baxter's world: PyBullet's TinyRenderer, or OpenGL through EGL (Mesa).

Both draw the bodies of one PyBullet client as an ideal pinhole camera (``CameraModel`` without
distortion) sees them, into a uint8 BGR image whose pixel (u, v) is the ray of ``camera.project``'s
(u, v) (OpenCV convention: pixel centres at integer coordinates, row 0 on top). ``T_base_camera`` is
the optical frame (x right, y down, z forward) in the world (= Baxter's ``base``), metres.

- ``TinyRenderer``: PyBullet's software rasteriser (``ER_TINY_RENDERER``), ~75 ms of CPU for the 657x413 frame
  of a 640x400 camera with its margin, on the 2-core machine.
- ``EglRenderer``: the same scene drawn with OpenGL 3.3 in an EGL context without a window (Mesa's
  llvmpipe software rasteriser here, a GPU driver where there is one), ~5 ms of CPU a frame. It reads the
  scene from PyBullet (``getVisualShapeData``: boxes, cylinders, and the meshes its owner passes in)
  and shades it with TinyRenderer's model and ``LIGHT`` (ambient + diffuse + specular, light colour,
  8-bit arithmetic; textured boxes, e.g. the ``baxter`` look's table, mapped as PyBullet maps
  a box), so its images are TinyRenderer's but for a few silhouette pixels. With a ``Light`` whose ``shadows``
  > 0 it adds soft shadows from a shadow map (``sim.shaders``); TinyRenderer then draws its own (hard, fixed
  strength) shadows.

``make_renderer('auto' | 'egl' | 'tiny', client, meshes, textures, light)`` builds one; 'auto' is EGL when it works
here, else TinyRenderer, with one log line saying why. ``BAXTER_PNP_RENDERER`` overrides 'auto'.
PyBullet's own EGL plugin (``eglRenderer``) was measured too (``baxter_pnp.bench.render_bench``): it does
not draw meshes given as vertices (the blocks), ignores the ambient/diffuse coefficients, adds a shadow
pass, and costs 5x as much; see README, "Fake Baxter".
"""
import ctypes
import logging
import math
import os
from dataclasses import dataclass
from typing import Tuple

import cv2
import numpy as np
import pybullet as p

from baxter_pnp.camera import CameraModel
from baxter_pnp.sim import egl, shaders
from baxter_pnp.sim.egl import RendererUnavailable
from baxter_pnp.transforms import invert

LOG = logging.getLogger(__name__)
RENDERERS = ('auto', 'egl', 'tiny')
RENDERER_ENV = 'BAXTER_PNP_RENDERER'       # overrides 'auto' (e.g. to run a test suite on TinyRenderer)
CAMERA_NEAR, CAMERA_FAR = 0.01, 3.0         # m, render clipping planes
LIGHT = dict(lightDirection=[0.4, -0.3, 1.0], lightColor=[1.0, 1.0, 1.0], lightDistance=2.0,
             lightAmbientCoeff=0.55, lightDiffuseCoeff=0.45, lightSpecularCoeff=0.02, shadow=0)
TINY_SHININESS = 2.0                        # TinyRenderer's specular exponent for untextured shapes
# OpenGL camera (x right, y up, looking along -z) from the optical frame (x right, y down, z forward).
T_OPENGL_OPTICAL = np.diag([1.0, -1.0, -1.0, 1.0])
SHADOW_MAP_SIZE = 256                       # texels a side of the shadow map (about 7 mm on the default region)
SHADOW_BIAS = 0.004                         # m: depth a surface must lie behind the nearest one to be in shadow,
                                            # plus the depth a texel spans on the table (a low light)


@dataclass(frozen=True)
class Light:
    """The scene's directional light: ``direction`` toward the light (base frame, any length); ``shadows``: the
    share of the direct (diffuse + specular) light a surface in shadow loses, 0 (none, TinyRenderer's look) to 1
    (ambient light only); shadows are cast by what lies inside ``region`` ((x, y, z) low and high corners, m,
    base), e.g. the table and the arms above it."""
    direction: Tuple[float, float, float] = tuple(LIGHT['lightDirection'])
    shadows: float = 0.0
    region: Tuple[Tuple[float, float, float], Tuple[float, float, float]] = ((0.2, -0.9, -0.3), (1.3, 0.9, 0.9))

    @property
    def unit_direction(self):
        direction = np.asarray(self.direction, float)
        return direction / np.linalg.norm(direction)

    def clip_from_world(self):
        """4x4 orthographic projection of ``region`` along the light: x, y and depth in -1..1 (depth -1 nearest
        the light)."""
        z_axis = self.unit_direction
        helper = np.array([1.0, 0.0, 0.0]) if abs(z_axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x_axis = np.cross(helper, z_axis)
        x_axis /= np.linalg.norm(x_axis)
        R_light_world = np.array([x_axis, np.cross(z_axis, x_axis), z_axis])
        low, high = np.asarray(self.region, float)
        corners = np.array([[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1])
                            for z in (low[2], high[2])]) @ R_light_world.T
        lo, hi = corners.min(axis=0), corners.max(axis=0)
        scale = 2.0 / (hi - lo)
        clip = np.eye(4)
        clip[:3, :3] = np.diag([scale[0], scale[1], -scale[2]]) @ R_light_world    # depth grows away from the light
        clip[:3, 3] = [-1.0 - scale[0] * lo[0], -1.0 - scale[1] * lo[1], 1.0 + scale[2] * lo[2]]
        return clip, 2.0 / scale[2]            # and the depth range (m)


def make_renderer(kind, client, meshes=None, textures=None, light=Light()):
    """A renderer of PyBullet ``client``: ``kind`` 'egl', 'tiny' or 'auto' (EGL if it works, else Tiny; the
    ``BAXTER_PNP_RENDERER`` environment variable, if set, replaces 'auto'). ``meshes``: {body id: (vertices
    (V, 3), normals (V, 3), indices (3T,))} of the bodies whose visual shape is a mesh given as vertices.
    ``textures``: {body id: (H, W, 3) uint8 RGB image} of the box bodies given a texture in PyBullet (the same
    image: PyBullet gives textures back to no one); EGL draws them, TinyRenderer uses PyBullet's own.
    ``light``: the scene's ``Light``. 'egl' raises ``RendererUnavailable`` where it cannot run."""
    if kind not in RENDERERS:
        raise ValueError(f'unknown renderer {kind!r} (expected one of {", ".join(RENDERERS)})')
    if kind == 'auto':
        kind = os.environ.get(RENDERER_ENV) or 'auto'
        if kind not in RENDERERS:
            raise ValueError(f'{RENDERER_ENV}={kind!r}: expected one of {", ".join(RENDERERS)}')
    if kind == 'tiny':
        return TinyRenderer(client, light)
    try:
        return EglRenderer(client, meshes, textures, light)
    except RendererUnavailable as error:
        if kind == 'egl':
            raise
        _log_fallback_once(error)
        return TinyRenderer(client, light)


_fallbacks_logged = set()      # reasons already logged by this process


def _log_fallback_once(error):
    if str(error) not in _fallbacks_logged:
        _fallbacks_logged.add(str(error))
        LOG.warning('camera renderer: EGL not used (%s): PyBullet TinyRenderer draws the cameras (slower)', error)


def tiny_projection(camera, near=CAMERA_NEAR, far=CAMERA_FAR):
    """4x4 OpenGL projection matrix making PyBullet's TinyRenderer image (row 0 on top) that of the pinhole
    ``camera`` in OpenCV pixel convention. TinyRenderer samples pixel column u at NDC x = 2u/W - 1 and row v at
    NDC y = 1 - 2(v + 1)/H (measured: rendered blocks land on ``camera.project`` to 0.1 px)."""
    w, h = camera.width, camera.height
    return np.array([
        [2 * camera.fx / w, 0.0, 1 - 2 * camera.cx / w, 0.0],
        [0.0, 2 * camera.fy / h, 2 * (camera.cy + 1) / h - 1, 0.0],
        [0.0, 0.0, -(far + near) / (far - near), -2 * far * near / (far - near)],
        [0.0, 0.0, -1.0, 0.0]])


def optical_projection(camera, near=CAMERA_NEAR, far=CAMERA_FAR):
    """4x4 clip-from-optical-frame matrix for OpenGL: pixel (u, v) of the pinhole ``camera`` (OpenCV
    convention) is sampled at framebuffer pixel (u, v) (OpenGL samples pixel centres, u + 0.5), and
    framebuffer row 0 -- the first row ``glReadPixels`` returns -- is the image's top row."""
    w, h = camera.width, camera.height
    return np.array([
        [2 * camera.fx / w, 0.0, (2 * camera.cx + 1) / w - 1, 0.0],
        [0.0, 2 * camera.fy / h, (2 * camera.cy + 1) / h - 1, 0.0],
        [0.0, 0.0, (far + near) / (far - near), -2 * far * near / (far - near)],
        [0.0, 0.0, 1.0, 0.0]])


class TinyRenderer:
    """PyBullet's TinyRenderer (``p.getCameraImage``): needs no library beyond PyBullet."""

    name = 'tiny'
    description = 'PyBullet TinyRenderer'

    def __init__(self, client, light=Light()):
        self._client = client
        self._light = {**LIGHT, 'lightDirection': list(light.direction), 'shadow': int(light.shadows > 0)}

    def render(self, T_base_camera, camera, riding=None):
        """uint8 BGR (H, W, 3) image of the pinhole ``camera`` at ``T_base_camera`` (optical frame in base); with
        ``riding`` (a set of (body, link)) BGRA, alpha 0 on those parts' pixels and 255 elsewhere."""
        view = T_OPENGL_OPTICAL @ invert(T_base_camera)
        flags = p.ER_NO_SEGMENTATION_MASK if riding is None else p.ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX
        _, _, rgba, _, segments = p.getCameraImage(
            camera.width, camera.height, view.T.ravel().tolist(), tiny_projection(camera).T.ravel().tolist(),
            renderer=p.ER_TINY_RENDERER, flags=flags, physicsClientId=self._client, **self._light)
        rgba = np.reshape(rgba, (camera.height, camera.width, 4))
        if riding is None:
            return np.ascontiguousarray(rgba[:, :, 2::-1])
        segments = np.reshape(segments, (camera.height, camera.width)).astype(np.int64)
        codes = [body + ((link + 1) << 24) for body, link in riding]        # PyBullet's object-and-link code
        alpha = np.where(np.isin(segments, codes), 0, 255).astype(np.uint8)
        return np.dstack([rgba[:, :, 2::-1], alpha])

    def close(self):
        pass


# ======================================================================================= EGL + OpenGL
class EglRenderer:
    """The bodies of a PyBullet client drawn with OpenGL 3.3 core in a window-less EGL context.

    Geometry: TinyRenderer's tessellation of PyBullet's primitives (a box: 12 triangles with face normals;
    a cylinder: the hull of 32 points on each rim, vertex normals pointing from its centre through the
    vertex) and the meshes given to the constructor; each part is drawn in its link frame with the link's
    pose of the moment. Shading: TinyRenderer's (``sim.shaders``) with ``LIGHT`` from ``light.direction``, and
    with ``light.shadows`` > 0 a shadow map drawn from the light first (``SHADOW_MAP_SIZE``). Measured on the default
    scene: the images equal TinyRenderer's but for a few silhouette pixels of the cylinders
    (tests/test_render.py). The scene is re-read from PyBullet at each render (new bodies, colours).
    A box body given a texture (``textures``) is drawn with it: PyBullet's box texture coordinates (``_BOX_UV``),
    nearest texel. A shape of a kind it cannot draw (a sphere, a mesh file, a texture on a shape other than a
    box) makes TinyRenderer draw the frames from then on (logged once).
    """

    name = 'egl'

    def __init__(self, client, meshes=None, textures=None, light=Light()):
        self._client = client
        self._light = light
        self._shadow_map = None        # (framebuffer, depth texture) names, with shadows
        self._shadow_casters = None    # (N, 4, 4) poses of the parts the shadow map was drawn with
        self._meshes = dict(meshes or {})
        self._images = {body: np.ascontiguousarray(image, np.uint8) for body, image in (textures or {}).items()}
        self._textures = {}            # body -> OpenGL texture name, made at the first build
        self._gl = egl.shared_context()
        self._signature = None
        self._parts = []               # [_Part], in the order of the vertex buffer
        self._framebuffers = {}        # (width, height) -> (framebuffer, colour, depth) names
        self._vertex_array = self._vertex_buffer = None
        self._closed = False
        self._fallback = None          # TinyRenderer, once the scene holds a shape this one cannot draw
        with self._gl.current():
            programs = shaders.sources(light.shadows > 0)
            self._depth_program = self._gl.program(*programs.pop('depth')) if light.shadows > 0 else None
            self._programs = {shader: self._gl.program(*sources) for shader, sources in programs.items()}
            self._uniforms = {shader: {name: self._gl.uniform(program, name) for name in shaders.UNIFORMS}
                              for shader, program in self._programs.items()}
            if self._depth_program is not None:
                self._depth_clip_uniform = self._gl.uniform(self._depth_program, 'clip_from_link')
            self._sync_scene()
        # Mesa compiles the shaders at the first draw (LLVM; 45 ms idle, seconds on a loaded machine): draw once
        # now, while the fake boots, not at the first camera frame, where the stall would silence every stream.
        self._render(np.eye(4), CameraModel(64, 40, [[40.0, 0.0, 32.0], [0.0, 40.0, 20.0], [0.0, 0.0, 1.0]]))

    @property
    def description(self):
        """What draws the frames, e.g. 'OpenGL through EGL (llvmpipe (LLVM 15.0.6, 256 bits))'."""
        return self._fallback.description if self._fallback else f'OpenGL through EGL ({self._gl.description})'

    def render(self, T_base_camera, camera, riding=None):
        """uint8 BGR (H, W, 3) image of the pinhole ``camera`` at ``T_base_camera`` (optical frame in base); with
        ``riding`` (a set of (body, link)) BGRA, alpha 0 on those parts' pixels and 255 elsewhere.
        Once the scene holds a shape this renderer cannot draw, TinyRenderer draws it (logged once)."""
        if self._fallback is None:
            try:
                return self._render(T_base_camera, camera, riding)
            except RendererUnavailable as error:
                LOG.warning('camera renderer: switching from EGL to TinyRenderer: %s', error)
                self._fallback = TinyRenderer(self._client, self._light)
        return self._fallback.render(T_base_camera, camera, riding)

    def _render(self, T_base_camera, camera, riding=None):
        gl = self._gl
        with gl.current():
            self._sync_scene()
            poses = self._link_poses()
            shadow_from_world = self._draw_shadow_map(poses) if self._depth_program is not None else None
            clip_from_world = optical_projection(camera) @ invert(T_base_camera)
            gl.glBindFramebuffer(egl.GL_FRAMEBUFFER, self._framebuffer(camera.width, camera.height))
            gl.glViewport(0, 0, camera.width, camera.height)
            gl.glClearColor(1.0, 1.0, 1.0, 1.0)
            gl.glClear(egl.GL_COLOR_BUFFER_BIT | egl.GL_DEPTH_BUFFER_BIT)
            gl.glEnable(egl.GL_DEPTH_TEST)
            gl.glBindVertexArray(self._vertex_array)
            for shader, program in self._programs.items():
                gl.glUseProgram(program)
                u = self._uniforms[shader]
                self._set_light(u)
                for part in self._parts:
                    if part.shader != shader or part.rgba[3] == 0:
                        continue
                    if shader == 'textured':
                        gl.glBindTexture(egl.GL_TEXTURE_2D, self._textures[part.body])
                        gl.glUniform3f(u['tint'], *part.rgba[:3])
                    T_world_link = poses[part.body, part.link]
                    gl.glUniformMatrix4fv(u['clip_from_link'], 1, 1, _floats(clip_from_world @ T_world_link))
                    if shadow_from_world is not None:
                        gl.glUniformMatrix4fv(u['shadow_from_link'], 1, 1,
                                              _floats(shadow_from_world @ T_world_link))
                    gl.glUniformMatrix3fv(u['world_from_link'], 1, 1, _floats(T_world_link[:3, :3]))
                    # TinyRenderer keeps the colour as 8-bit (255 x rgba, truncated)
                    gl.glUniform3f(u['colour'], *(math.floor(255 * c) for c in part.rgba[:3]))
                    gl.glUniform1f(u['scene_alpha'], 0.0 if riding and (part.body, part.link) in riding else 1.0)
                    gl.glDrawArrays(egl.GL_TRIANGLES, part.first, part.count)
            rgba = np.empty((camera.height, camera.width, 4), np.uint8)
            gl.glPixelStorei(egl.GL_PACK_ALIGNMENT, 1)
            gl.glReadPixels(0, 0, camera.width, camera.height, egl.GL_RGBA, egl.GL_UNSIGNED_BYTE,
                            rgba.ctypes.data_as(ctypes.c_void_p))
        if riding is not None:
            return cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA)
        return cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGR)     # 10x faster than reading GL_BGR from llvmpipe

    def close(self):
        """Free the OpenGL objects (the shared context stays for the process's other renderers)."""
        if self._closed:
            return
        self._closed = True
        gl = self._gl
        with gl.current():
            for framebuffer, colour, depth in self._framebuffers.values():
                gl.glDeleteFramebuffers(1, _uints(framebuffer))
                gl.glDeleteRenderbuffers(2, _uints(colour, depth))
            self._delete_geometry()
            gl.glDeleteTextures(len(self._textures), _uints(*self._textures.values()))
            if self._shadow_map is not None:
                gl.glDeleteFramebuffers(1, _uints(self._shadow_map[0]))
                gl.glDeleteTextures(1, _uints(self._shadow_map[1]))
            for program in [*self._programs.values(), *([self._depth_program] if self._depth_program else [])]:
                gl.glDeleteProgram(program)
        self._framebuffers, self._textures = {}, {}

    def __del__(self):
        try:
            self.close()
        except Exception:      # interpreter shutdown
            pass

    # ------------------------------------------------------------------ scene
    def _visual_shapes(self):
        """[(body, link, geometry type, dimensions, position, orientation (link frame), rgba)] of every visual
        shape of the client."""
        shapes, client = [], self._client
        for i in range(p.getNumBodies(physicsClientId=client)):
            body = p.getBodyUniqueId(i, physicsClientId=client)
            for data in p.getVisualShapeData(body, physicsClientId=client):
                _, link, kind, dimensions, _, position, orientation, rgba = data[:8]
                shapes.append((body, link, kind, tuple(dimensions), tuple(position), tuple(orientation),
                               tuple(rgba)))
        return shapes

    def _sync_scene(self):
        """Rebuild the vertex buffer when the set of shapes changed; refresh the colours."""
        shapes = self._visual_shapes()
        signature = [shape[:6] for shape in shapes]
        if signature != self._signature:
            self._build(shapes)
            self._signature = signature
            self._shadow_casters = None
        for part, shape in zip(self._parts, shapes):
            part.rgba = shape[6]

    def _build(self, shapes):
        blocks, parts, first = [], [], 0
        for body, link, kind, dimensions, position, orientation, rgba in shapes:
            vertices, normals = self._triangles(body, kind, dimensions)
            uv, shader = np.zeros((len(vertices), 2)), 'flat'
            if body in self._images:
                self._upload_texture(body, kind)
                uv, shader = _box_uv(vertices, normals), 'textured'
            elif not np.allclose(normals[0::3], normals[1::3]) or not np.allclose(normals[0::3], normals[2::3]):
                shader = 'smooth'
            R = np.reshape(p.getMatrixFromQuaternion(orientation), (3, 3))
            vertices = vertices @ R.T + np.asarray(position)
            normals = normals @ R.T
            blocks.append(np.hstack([vertices, normals, uv]).astype(np.float32))
            parts.append(_Part(body, link, first, len(vertices), rgba, shader))
            first += len(vertices)
        data = np.ascontiguousarray(np.vstack(blocks) if blocks else np.zeros((0, 8), np.float32))
        gl = self._gl
        self._delete_geometry()
        self._vertex_array, self._vertex_buffer = gl.gen(gl.glGenVertexArrays), gl.gen(gl.glGenBuffers)
        gl.glBindVertexArray(self._vertex_array)
        gl.glBindBuffer(egl.GL_ARRAY_BUFFER, self._vertex_buffer)
        gl.glBufferData(egl.GL_ARRAY_BUFFER, data.nbytes, data.ctypes.data_as(ctypes.c_void_p), egl.GL_STATIC_DRAW)
        for location, size, offset in ((0, 3, 0), (1, 3, 12), (2, 2, 24)):     # position, normal, uv
            gl.glEnableVertexAttribArray(location)
            gl.glVertexAttribPointer(location, size, egl.GL_FLOAT, 0, 32, ctypes.c_void_p(offset))
        self._parts = parts
        self._link_keys = {}
        for part in parts:
            self._link_keys.setdefault(part.body, set()).add(part.link)

    def _upload_texture(self, body, kind):
        """``body``'s image as an OpenGL texture (once): nearest texel, repeated, flipped as PyBullet flips a loaded
        texture (row 0 at t = 1; measured: the other 7 orientations differ from TinyRenderer by 12 grey levels)."""
        if kind != p.GEOM_BOX:
            raise RendererUnavailable(f'body {body}: the EGL renderer draws textures on boxes only')
        if body in self._textures:
            return
        gl, image = self._gl, np.ascontiguousarray(self._images[body][::-1])
        if image.ndim != 3 or image.shape[2] != 3:
            raise RendererUnavailable(f'body {body}: texture of shape {image.shape}, expected (H, W, 3) RGB')
        gl.glBindTexture(egl.GL_TEXTURE_2D, self._textures.setdefault(body, gl.gen(gl.glGenTextures)))
        gl.glPixelStorei(egl.GL_UNPACK_ALIGNMENT, 1)
        gl.glTexImage2D(egl.GL_TEXTURE_2D, 0, egl.GL_RGB8, image.shape[1], image.shape[0], 0, egl.GL_RGB, egl.GL_UNSIGNED_BYTE,
                        image.ctypes.data_as(ctypes.c_void_p))
        for parameter in (egl.GL_TEXTURE_MIN_FILTER, egl.GL_TEXTURE_MAG_FILTER):
            gl.glTexParameteri(egl.GL_TEXTURE_2D, parameter, egl.GL_NEAREST)

    def _delete_geometry(self):
        if self._vertex_array is not None:
            self._gl.glDeleteVertexArrays(1, _uints(self._vertex_array))
            self._gl.glDeleteBuffers(1, _uints(self._vertex_buffer))
            self._vertex_array = self._vertex_buffer = None

    def _triangles(self, body, kind, dimensions):
        """(vertices (3T, 3), normals (3T, 3)) of one visual shape in its own frame, triangle by triangle."""
        if kind == p.GEOM_BOX:
            return _box_triangles(np.asarray(dimensions) / 2)
        if kind == p.GEOM_CYLINDER:
            return _cylinder_triangles(dimensions[0], dimensions[1])
        if kind == p.GEOM_MESH and body in self._meshes:
            vertices, normals, indices = (np.asarray(a) for a in self._meshes[body])
            indices = np.asarray(indices, int).ravel()
            return vertices[indices] * np.asarray(dimensions), normals[indices]
        raise RendererUnavailable(f'body {body}: visual geometry type {kind} is not drawn by the EGL renderer')

    def _link_poses(self):
        """{(body, link): T_world_link (4x4)} of every link that has a visual shape (link -1: the base)."""
        poses, client = {}, self._client
        for body, links in self._link_keys.items():
            if -1 in links:
                position, orientation = p.getBasePositionAndOrientation(body, physicsClientId=client)
                local_position, local_orientation = p.getDynamicsInfo(body, -1, physicsClientId=client)[3:5]
                inverse = p.invertTransform(local_position, local_orientation)
                poses[body, -1] = _matrix(*p.multiplyTransforms(position, orientation, *inverse))
            moving = sorted(link for link in links if link >= 0)
            if moving:
                states = p.getLinkStates(body, moving, computeForwardKinematics=1, physicsClientId=client)
                for link, state in zip(moving, states):
                    poses[body, link] = _matrix(state[4], state[5])
        return poses

    def _draw_shadow_map(self, poses):
        """Draw the depth of every part as the light sees it into the shadow map (bound to texture unit 1 for the
        shading pass); return shadow_from_world: 4x4, world point -> (texture u, v, depth) in 0..1."""
        gl = self._gl
        if self._shadow_map is None:
            self._shadow_map = self._make_shadow_map()
        light_clip_from_world, depth_range = self._light.clip_from_world()
        to_texture = np.diag([0.5, 0.5, 0.5, 1.0])
        to_texture[:3, 3] = 0.5
        texel_m = 2.0 / SHADOW_MAP_SIZE / np.linalg.norm(light_clip_from_world[:2, :3], axis=1).min()
        sine = self._light.unit_direction[2]                      # of the light's elevation
        self._shadow_bias = (SHADOW_BIAS + texel_m * math.sqrt(1.0 - sine ** 2) / sine) / depth_range
        casters = [(part, poses[part.body, part.link]) for part in self._parts if part.rgba[3] != 0]
        signature = np.array([T for _, T in casters])
        if self._shadow_casters is None or self._shadow_casters.shape != signature.shape or \
                not np.allclose(self._shadow_casters, signature, rtol=0.0, atol=1e-6):
            self._draw_depth(casters, light_clip_from_world)     # only when something moved (llvmpipe: ~4 ms)
            self._shadow_casters = signature
        gl.glActiveTexture(egl.GL_TEXTURE0 + 1)
        gl.glBindTexture(egl.GL_TEXTURE_2D, self._shadow_map[1])
        gl.glActiveTexture(egl.GL_TEXTURE0)
        return to_texture @ light_clip_from_world

    def _draw_depth(self, casters, light_clip_from_world):
        """Draw the depth of ``casters`` ([(part, T_world_link)]) as the light sees it into the shadow map."""
        gl = self._gl
        gl.glBindFramebuffer(egl.GL_FRAMEBUFFER, self._shadow_map[0])
        gl.glViewport(0, 0, SHADOW_MAP_SIZE, SHADOW_MAP_SIZE)
        gl.glClear(egl.GL_DEPTH_BUFFER_BIT)
        gl.glEnable(egl.GL_DEPTH_TEST)
        gl.glBindVertexArray(self._vertex_array)
        gl.glUseProgram(self._depth_program)
        for part, T_world_link in casters:
            gl.glUniformMatrix4fv(self._depth_clip_uniform, 1, 1, _floats(light_clip_from_world @ T_world_link))
            gl.glDrawArrays(egl.GL_TRIANGLES, part.first, part.count)

    def _make_shadow_map(self):
        """(framebuffer, depth texture) of the shadow map: ``SHADOW_MAP_SIZE`` square, compared with
        GL_LEQUAL and filtered 2x2 (percentage-closer filtering: a shadow's edge is soft over one texel)."""
        gl = self._gl
        texture, framebuffer = gl.gen(gl.glGenTextures), gl.gen(gl.glGenFramebuffers)
        gl.glBindTexture(egl.GL_TEXTURE_2D, texture)
        gl.glTexImage2D(egl.GL_TEXTURE_2D, 0, egl.GL_DEPTH_COMPONENT24, SHADOW_MAP_SIZE, SHADOW_MAP_SIZE, 0,
                        egl.GL_DEPTH_COMPONENT, egl.GL_FLOAT, None)
        for parameter, value in ((egl.GL_TEXTURE_MIN_FILTER, egl.GL_LINEAR), (egl.GL_TEXTURE_MAG_FILTER, egl.GL_LINEAR),
                                 (egl.GL_TEXTURE_WRAP_S, egl.GL_CLAMP_TO_EDGE),
                                 (egl.GL_TEXTURE_WRAP_T, egl.GL_CLAMP_TO_EDGE),
                                 (egl.GL_TEXTURE_COMPARE_MODE, egl.GL_COMPARE_REF_TO_TEXTURE),
                                 (egl.GL_TEXTURE_COMPARE_FUNC, egl.GL_LEQUAL)):
            gl.glTexParameteri(egl.GL_TEXTURE_2D, parameter, value)
        gl.glBindFramebuffer(egl.GL_FRAMEBUFFER, framebuffer)
        gl.glFramebufferTexture2D(egl.GL_FRAMEBUFFER, egl.GL_DEPTH_ATTACHMENT, egl.GL_TEXTURE_2D, texture, 0)
        gl.glDrawBuffer(egl.GL_NONE)
        gl.glReadBuffer(egl.GL_NONE)
        status = gl.glCheckFramebufferStatus(egl.GL_FRAMEBUFFER)
        if status != egl.GL_FRAMEBUFFER_COMPLETE:
            raise RendererUnavailable(f'OpenGL shadow map framebuffer incomplete (status {status:#x})')
        return framebuffer, texture

    def _set_light(self, u):
        gl = self._gl
        gl.glUniform3f(u['light_direction'], *self._light.unit_direction)
        gl.glUniform3f(u['light_colour'], *LIGHT['lightColor'])
        gl.glUniform1f(u['ambient'], LIGHT['lightAmbientCoeff'])
        gl.glUniform1f(u['diffuse'], LIGHT['lightDiffuseCoeff'])
        gl.glUniform1f(u['specular'], LIGHT['lightSpecularCoeff'])
        gl.glUniform1f(u['shininess'], TINY_SHININESS)
        gl.glUniform1i(u['image'], 0)
        if self._depth_program is not None:
            gl.glUniform1i(u['shadow_map'], 1)
            gl.glUniform1f(u['shadow_strength'], self._light.shadows)
            gl.glUniform1f(u['shadow_bias'], self._shadow_bias)

    def _framebuffer(self, width, height):
        key = (width, height)
        if key not in self._framebuffers:
            gl = self._gl
            framebuffer = gl.gen(gl.glGenFramebuffers)
            colour, depth = gl.gen(gl.glGenRenderbuffers), gl.gen(gl.glGenRenderbuffers)
            gl.glBindFramebuffer(egl.GL_FRAMEBUFFER, framebuffer)
            for name, storage, attachment in ((colour, egl.GL_RGBA8, egl.GL_COLOR_ATTACHMENT0),
                                              (depth, egl.GL_DEPTH_COMPONENT24, egl.GL_DEPTH_ATTACHMENT)):
                gl.glBindRenderbuffer(egl.GL_RENDERBUFFER, name)
                gl.glRenderbufferStorage(egl.GL_RENDERBUFFER, storage, width, height)
                gl.glFramebufferRenderbuffer(egl.GL_FRAMEBUFFER, attachment, egl.GL_RENDERBUFFER, name)
            status = gl.glCheckFramebufferStatus(egl.GL_FRAMEBUFFER)
            if status != egl.GL_FRAMEBUFFER_COMPLETE:
                raise RendererUnavailable(f'OpenGL framebuffer {width}x{height} incomplete (status {status:#x})')
            self._framebuffers[key] = (framebuffer, colour, depth)
        return self._framebuffers[key][0]


class _Part:
    """A run of triangles of one visual shape: drawn in link ``link`` of ``body`` with colour ``rgba`` by the
    program ``shader``: 'flat' (shaded per triangle), 'smooth' (its vertex normals vary over a triangle: per
    pixel) or 'textured' (the body's texture x rgba, per pixel)."""

    def __init__(self, body, link, first, count, rgba, shader):
        self.body, self.link, self.first, self.count, self.rgba, self.shader = body, link, first, count, rgba, shader


def _matrix(position, quaternion):
    T = np.eye(4)
    T[:3, :3] = np.reshape(p.getMatrixFromQuaternion(quaternion), (3, 3))
    T[:3, 3] = position
    return T


def _box_triangles(half):
    """A box of half extents ``half`` (3,): 12 triangles on its 8 corners, with the faces' outward normals."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half
    # each face as 4 corner indices around it; two triangles per face
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    indices = [i for a, b, c, d in faces for i in (a, b, c, a, c, d)]
    vertices = corners[indices]
    a, b, c = vertices[0::3], vertices[1::3], vertices[2::3]
    normals = np.cross(b - a, c - a)
    normals *= np.sign(np.sum(normals * (a + b + c), axis=1, keepdims=True))     # outward
    return vertices, np.repeat(normals / np.linalg.norm(normals, axis=1, keepdims=True), 3, axis=0)


# PyBullet's texture coordinates of a box (bullet3 OpenGLWindow/ShapeData.h cube_vertices_textured): {face normal:
# {corner (x, y, z signs): (u, v)}}. The +z face (the table top) shows u 0.75..1 along x, v 0.25..0 along y.
_BOX_UV = {
    (0, 0, 1): {(-1, -1, 1): (0.75, 0.25), (1, -1, 1): (1, 0.25), (1, 1, 1): (1, 0), (-1, 1, 1): (0.75, 0)},
    (0, 0, -1): {(-1, -1, -1): (0.5, 0.25), (1, -1, -1): (0.25, 0.25), (1, 1, -1): (0.25, 0), (-1, 1, -1): (0.5, 0)},
    (-1, 0, 0): {(-1, -1, -1): (0.5, 0), (-1, 1, -1): (0.75, 0), (-1, 1, 1): (0.75, 0.25), (-1, -1, 1): (0.5, 0.25)},
    (1, 0, 0): {(1, -1, -1): (0.25, 0.5), (1, 1, -1): (0.25, 0.25), (1, 1, 1): (0, 0.25), (1, -1, 1): (0, 0.5)},
    (0, -1, 0): {(-1, -1, -1): (0.25, 0.5), (-1, -1, 1): (0.25, 0.25), (1, -1, 1): (0.5, 0.25), (1, -1, -1): (0.5, 0.5)},
    (0, 1, 0): {(-1, 1, -1): (0, 0), (-1, 1, 1): (0, 0.25), (1, 1, 1): (0.25, 0.25), (1, 1, -1): (0.25, 0)},
}


def _box_uv(vertices, normals):
    """(3T, 2) texture coordinates of ``_box_triangles``' vertices (box frame, m) and face normals: ``_BOX_UV``."""
    return np.array([_BOX_UV[tuple(np.rint(n).astype(int))][tuple(np.sign(v).astype(int))]
                     for v, n in zip(vertices, normals)], float)


def _cylinder_triangles(length, radius, steps=32):
    """A cylinder along z (``length``, ``radius``) as TinyRenderer tessellates it: the hull of ``steps`` points
    on each rim, each vertex's normal pointing from the centre through the vertex."""
    angle = 2 * np.pi * np.arange(steps) / steps
    rim = np.column_stack([radius * np.sin(angle), radius * np.cos(angle)])
    top = np.column_stack([rim, np.full(steps, length / 2)])
    bottom = np.column_stack([rim, np.full(steps, -length / 2)])
    triangles = []
    for k in range(steps):
        n = (k + 1) % steps
        triangles += [(bottom[k], bottom[n], top[n]), (bottom[k], top[n], top[k])]
    for k in range(1, steps - 1):
        triangles += [(top[0], top[k], top[k + 1]), (bottom[0], bottom[k + 1], bottom[k])]
    vertices = np.reshape(triangles, (-1, 3))
    return vertices, vertices / np.linalg.norm(vertices, axis=1, keepdims=True)


def _floats(matrix):
    return np.ascontiguousarray(matrix, np.float32).ctypes.data_as(ctypes.POINTER(ctypes.c_float))


def _uints(*names):
    return (ctypes.c_uint * len(names))(*names)
