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
  no shadows, 8-bit arithmetic; textured boxes, e.g. the ``baxter`` look's table, mapped as PyBullet maps
  a box), so its images are TinyRenderer's but for a few silhouette pixels.

``make_renderer('auto' | 'egl' | 'tiny', client, meshes, textures)`` builds one; 'auto' is EGL when it works here,
else TinyRenderer, with one log line saying why. ``BAXTER_PNP_RENDERER`` overrides 'auto'.
PyBullet's own EGL plugin (``eglRenderer``) was measured too (``baxter_pnp.bench.render_bench``): it does
not draw meshes given as vertices (the blocks), ignores the ambient/diffuse coefficients, adds a shadow
pass, and costs 5x as much; see README, "Fake Baxter".
"""
import ctypes
import logging
import math
import os

import cv2
import numpy as np
import pybullet as p

from baxter_pnp.camera import CameraModel
from baxter_pnp.sim import egl
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




def make_renderer(kind, client, meshes=None, textures=None):
    """A renderer of PyBullet ``client``: ``kind`` 'egl', 'tiny' or 'auto' (EGL if it works, else Tiny; the
    ``BAXTER_PNP_RENDERER`` environment variable, if set, replaces 'auto'). ``meshes``: {body id: (vertices
    (V, 3), normals (V, 3), indices (3T,))} of the bodies whose visual shape is a mesh given as vertices.
    ``textures``: {body id: (H, W, 3) uint8 RGB image} of the box bodies given a texture in PyBullet (the same
    image: PyBullet gives textures back to no one); EGL draws them, TinyRenderer uses PyBullet's own.
    'egl' raises ``RendererUnavailable`` where it cannot run."""
    if kind not in RENDERERS:
        raise ValueError(f'unknown renderer {kind!r} (expected one of {", ".join(RENDERERS)})')
    if kind == 'auto':
        kind = os.environ.get(RENDERER_ENV) or 'auto'
        if kind not in RENDERERS:
            raise ValueError(f'{RENDERER_ENV}={kind!r}: expected one of {", ".join(RENDERERS)}')
    if kind == 'tiny':
        return TinyRenderer(client)
    try:
        return EglRenderer(client, meshes, textures)
    except RendererUnavailable as error:
        if kind == 'egl':
            raise
        _log_fallback_once(error)
        return TinyRenderer(client)


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

    def __init__(self, client):
        self._client = client

    def render(self, T_base_camera, camera):
        """uint8 BGR (H, W, 3) image of the pinhole ``camera`` at ``T_base_camera`` (optical frame in base)."""
        view = T_OPENGL_OPTICAL @ invert(T_base_camera)
        _, _, rgba, _, _ = p.getCameraImage(
            camera.width, camera.height, view.T.ravel().tolist(), tiny_projection(camera).T.ravel().tolist(),
            renderer=p.ER_TINY_RENDERER, flags=p.ER_NO_SEGMENTATION_MASK, physicsClientId=self._client, **LIGHT)
        return np.ascontiguousarray(np.reshape(rgba, (camera.height, camera.width, 4))[:, :, 2::-1])

    def close(self):
        pass


# ======================================================================================= EGL + OpenGL
class EglRenderer:
    """The bodies of a PyBullet client drawn with OpenGL 3.3 core in a window-less EGL context.

    Geometry: TinyRenderer's tessellation of PyBullet's primitives (a box: 12 triangles with face normals;
    a cylinder: the hull of 32 points on each rim, vertex normals pointing from its centre through the
    vertex) and the meshes given to the constructor; each part is drawn in its link frame with the link's
    pose of the moment. Shading: TinyRenderer's (``_SHADING``) with ``LIGHT``. Measured on the default
    scene: the images equal TinyRenderer's but for a few silhouette pixels of the cylinders
    (tests/test_render.py). The scene is re-read from PyBullet at each render (new bodies, colours).
    A box body given a texture (``textures``) is drawn with it: PyBullet's box texture coordinates (``_BOX_UV``),
    nearest texel. A shape of a kind it cannot draw (a sphere, a mesh file, a texture on a shape other than a
    box) makes TinyRenderer draw the frames from then on (logged once).
    """

    name = 'egl'

    def __init__(self, client, meshes=None, textures=None):
        self._client = client
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
            self._programs = {shader: self._gl.program(*sources) for shader, sources in _SHADERS.items()}
            self._uniforms = {shader: {name: self._gl.uniform(program, name) for name in _UNIFORMS}
                              for shader, program in self._programs.items()}
            self._sync_scene()
        # Mesa compiles the shaders at the first draw (LLVM; 45 ms idle, seconds on a loaded machine): draw once
        # now, while the fake boots, not at the first camera frame, where the stall would silence every stream.
        self._render(np.eye(4), CameraModel(64, 40, [[40.0, 0.0, 32.0], [0.0, 40.0, 20.0], [0.0, 0.0, 1.0]]))

    @property
    def description(self):
        """What draws the frames, e.g. 'OpenGL through EGL (llvmpipe (LLVM 15.0.6, 256 bits))'."""
        return self._fallback.description if self._fallback else f'OpenGL through EGL ({self._gl.description})'

    def render(self, T_base_camera, camera):
        """uint8 BGR (H, W, 3) image of the pinhole ``camera`` at ``T_base_camera`` (optical frame in base).
        Once the scene holds a shape this renderer cannot draw, TinyRenderer draws it (logged once)."""
        if self._fallback is None:
            try:
                return self._render(T_base_camera, camera)
            except RendererUnavailable as error:
                LOG.warning('camera renderer: switching from EGL to TinyRenderer: %s', error)
                self._fallback = TinyRenderer(self._client)
        return self._fallback.render(T_base_camera, camera)

    def _render(self, T_base_camera, camera):
        gl = self._gl
        with gl.current():
            self._sync_scene()
            poses = self._link_poses()
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
                    gl.glUniformMatrix3fv(u['world_from_link'], 1, 1, _floats(T_world_link[:3, :3]))
                    # TinyRenderer keeps the colour as 8-bit (255 x rgba, truncated)
                    gl.glUniform3f(u['colour'], *(math.floor(255 * c) for c in part.rgba[:3]))
                    gl.glDrawArrays(egl.GL_TRIANGLES, part.first, part.count)
            rgba = np.empty((camera.height, camera.width, 4), np.uint8)
            gl.glPixelStorei(egl.GL_PACK_ALIGNMENT, 1)
            gl.glReadPixels(0, 0, camera.width, camera.height, egl.GL_RGBA, egl.GL_UNSIGNED_BYTE,
                            rgba.ctypes.data_as(ctypes.c_void_p))
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
            for program in self._programs.values():
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

    def _set_light(self, u):
        gl = self._gl
        direction = np.asarray(LIGHT['lightDirection'], float)
        gl.glUniform3f(u['light_direction'], *(direction / np.linalg.norm(direction)))
        gl.glUniform3f(u['light_colour'], *LIGHT['lightColor'])
        gl.glUniform1f(u['ambient'], LIGHT['lightAmbientCoeff'])
        gl.glUniform1f(u['diffuse'], LIGHT['lightDiffuseCoeff'])
        gl.glUniform1f(u['specular'], LIGHT['lightSpecularCoeff'])
        gl.glUniform1f(u['shininess'], TINY_SHININESS)

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


# TinyRenderer's fragment shading (PyBullet 3.2, shadows off): 8-bit colour c, unit normal n, light direction l
# (unit, world); r = reflect(-l, n); value = floor(ambient c + (kd max(n.l, 0) + ks max(r_z, 0)^shininess) c
# light_colour), at most 255. Per pixel for smooth parts; per triangle (in the vertex shader) for flat ones,
# whose pixels all have the triangle's normal: the same values, at a fraction of the cost.
_SHADING = """
uniform vec3 colour;             // 0..255 (untextured parts)
uniform vec3 light_direction;    // unit, world
uniform vec3 light_colour;
uniform float ambient, diffuse, specular, shininess;
float lighting(vec3 world_normal) {
    vec3 n = normalize(world_normal);
    float n_dot_l = dot(n, light_direction);
    vec3 reflection = normalize(n * (2.0 * n_dot_l) - light_direction);
    return diffuse * max(n_dot_l, 0.0) + specular * pow(max(reflection.z, 0.0), shininess);
}
vec3 shade(float lit, vec3 colour) {
    return min(floor(ambient * colour + lit * colour * light_colour), vec3(255.0)) / 255.0;
}
"""
_VERTEX_INPUTS = """#version 330 core
layout(location = 0) in vec3 position;   // m, link frame
layout(location = 1) in vec3 normal;     // link frame
layout(location = 2) in vec2 uv;         // texture coordinates (textured parts)
uniform mat4 clip_from_link;
uniform mat3 world_from_link;
"""
_SHADERS = {    # name: (vertex shader, fragment shader)
    'flat': (_VERTEX_INPUTS + _SHADING + """
flat out vec3 shaded;
void main() {
    gl_Position = clip_from_link * vec4(position, 1.0);
    shaded = shade(lighting(world_from_link * normal), colour);
}
""", """#version 330 core
flat in vec3 shaded;
out vec4 fragment;
void main() { fragment = vec4(shaded, 1.0); }
"""),
    'smooth': (_VERTEX_INPUTS + """
out vec3 world_normal;
void main() {
    gl_Position = clip_from_link * vec4(position, 1.0);
    world_normal = world_from_link * normal;
}
""", """#version 330 core
in vec3 world_normal;
out vec4 fragment;
""" + _SHADING + """
void main() { fragment = vec4(shade(lighting(world_normal), colour), 1.0); }
"""),
    # TinyRenderer: the texel (nearest, 8-bit) x rgba, truncated, then shaded; the light per (flat) box triangle
    'textured': (_VERTEX_INPUTS + _SHADING + """
flat out float lit;
out vec2 texture_uv;
void main() {
    gl_Position = clip_from_link * vec4(position, 1.0);
    lit = lighting(world_from_link * normal);
    texture_uv = uv;
}
""", """#version 330 core
flat in float lit;
in vec2 texture_uv;
uniform sampler2D image;
uniform vec3 tint;               // rgba of the shape, 0..1
out vec4 fragment;
""" + _SHADING + """
void main() {
    fragment = vec4(shade(lit, floor(round(texture(image, texture_uv).rgb * 255.0) * tint)), 1.0);
}
"""),
}
_UNIFORMS = ('clip_from_link', 'world_from_link', 'colour', 'light_direction', 'light_colour', 'ambient', 'diffuse',
             'specular', 'shininess', 'tint')
