"""An OpenGL 3.3 core context through EGL without a window (Mesa's surfaceless platform, else the first EGL
device), and the GL functions and constants the fake's ``sim.render.EglRenderer`` calls (ctypes, no extra
package). One context per process (``shared_context``), current in one thread at a time.
"""
import contextlib
import ctypes
import threading


class RendererUnavailable(RuntimeError):
    """This renderer cannot run here (no EGL, no OpenGL 3.3, a shape it cannot draw)."""

GL_TRIANGLES, GL_FLOAT, GL_UNSIGNED_BYTE = 0x0004, 0x1406, 0x1401
GL_COLOR_BUFFER_BIT, GL_DEPTH_BUFFER_BIT, GL_DEPTH_TEST = 0x4000, 0x0100, 0x0B71
GL_ARRAY_BUFFER, GL_STATIC_DRAW = 0x8892, 0x88E4
GL_FRAMEBUFFER, GL_RENDERBUFFER, GL_FRAMEBUFFER_COMPLETE = 0x8D40, 0x8D41, 0x8CD5
GL_COLOR_ATTACHMENT0, GL_DEPTH_ATTACHMENT = 0x8CE0, 0x8D00
GL_RGBA8, GL_DEPTH_COMPONENT24, GL_RGBA, GL_PACK_ALIGNMENT = 0x8058, 0x81A6, 0x1908, 0x0D05
_GL_VERTEX_SHADER, _GL_FRAGMENT_SHADER, _GL_COMPILE_STATUS, _GL_LINK_STATUS = 0x8B31, 0x8B30, 0x8B81, 0x8B82
_GL_RENDERER, GL_TEXTURE_MAG_FILTER, GL_TEXTURE_MIN_FILTER = 0x1F01, 0x2800, 0x2801
GL_TEXTURE_2D, GL_RGB, GL_RGB8, GL_UNPACK_ALIGNMENT, GL_NEAREST = 0x0DE1, 0x1907, 0x8051, 0x0CF5, 0x2600
GL_TEXTURE0, GL_DEPTH_COMPONENT, GL_LINEAR, GL_NONE, GL_LEQUAL = 0x84C0, 0x1902, 0x2601, 0, 0x0203
GL_TEXTURE_COMPARE_MODE, GL_TEXTURE_COMPARE_FUNC, GL_COMPARE_REF_TO_TEXTURE = 0x884C, 0x884D, 0x884E
GL_TEXTURE_WRAP_S, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE = 0x2802, 0x2803, 0x812F
_EGL_PLATFORM_SURFACELESS_MESA, _EGL_PLATFORM_DEVICE_EXT = 0x31DD, 0x313F
_EGL_OPENGL_API, _EGL_NONE = 0x30A2, 0x3038
_EGL_CONTEXT_MAJOR_VERSION, _EGL_CONTEXT_MINOR_VERSION = 0x3098, 0x30FB
_EGL_CONTEXT_OPENGL_PROFILE_MASK, _EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT = 0x30FD, 0x1

_c = ctypes
_GL_FUNCTIONS = {     # name: (result, argument types)
    'glGetString': (_c.c_char_p, [_c.c_uint]),
    'glGetError': (_c.c_uint, []),
    'glViewport': (None, [_c.c_int] * 4),
    'glClearColor': (None, [_c.c_float] * 4),
    'glClear': (None, [_c.c_uint]),
    'glEnable': (None, [_c.c_uint]),
    'glPixelStorei': (None, [_c.c_uint, _c.c_int]),
    'glReadPixels': (None, [_c.c_int, _c.c_int, _c.c_int, _c.c_int, _c.c_uint, _c.c_uint, _c.c_void_p]),
    **{f'gl{verb}{objects}': (None, [_c.c_int, _c.POINTER(_c.c_uint)]) for verb in ('Gen', 'Delete')
       for objects in ('Framebuffers', 'Renderbuffers', 'VertexArrays', 'Buffers', 'Textures')},
    'glBindFramebuffer': (None, [_c.c_uint, _c.c_uint]),
    'glCheckFramebufferStatus': (_c.c_uint, [_c.c_uint]),
    'glBindRenderbuffer': (None, [_c.c_uint, _c.c_uint]),
    'glRenderbufferStorage': (None, [_c.c_uint, _c.c_uint, _c.c_int, _c.c_int]),
    'glFramebufferRenderbuffer': (None, [_c.c_uint, _c.c_uint, _c.c_uint, _c.c_uint]),
    'glBindVertexArray': (None, [_c.c_uint]),
    'glBindBuffer': (None, [_c.c_uint, _c.c_uint]),
    'glBufferData': (None, [_c.c_uint, _c.c_ssize_t, _c.c_void_p, _c.c_uint]),
    'glEnableVertexAttribArray': (None, [_c.c_uint]),
    'glVertexAttribPointer': (None, [_c.c_uint, _c.c_int, _c.c_uint, _c.c_ubyte, _c.c_int, _c.c_void_p]),
    'glDrawArrays': (None, [_c.c_uint, _c.c_int, _c.c_int]),
    'glBindTexture': (None, [_c.c_uint, _c.c_uint]),
    'glTexImage2D': (None, [_c.c_uint] + [_c.c_int] * 5 + [_c.c_uint, _c.c_uint, _c.c_void_p]),
    'glTexParameteri': (None, [_c.c_uint, _c.c_uint, _c.c_int]),
    'glActiveTexture': (None, [_c.c_uint]),
    'glFramebufferTexture2D': (None, [_c.c_uint, _c.c_uint, _c.c_uint, _c.c_uint, _c.c_int]),
    'glDrawBuffer': (None, [_c.c_uint]),
    'glReadBuffer': (None, [_c.c_uint]),
    'glUniform1i': (None, [_c.c_int, _c.c_int]),
    'glCreateShader': (_c.c_uint, [_c.c_uint]),
    'glShaderSource': (None, [_c.c_uint, _c.c_int, _c.POINTER(_c.c_char_p), _c.c_void_p]),
    'glCompileShader': (None, [_c.c_uint]),
    'glGetShaderiv': (None, [_c.c_uint, _c.c_uint, _c.POINTER(_c.c_int)]),
    'glGetShaderInfoLog': (None, [_c.c_uint, _c.c_int, _c.c_void_p, _c.c_char_p]),
    'glDeleteShader': (None, [_c.c_uint]),
    'glCreateProgram': (_c.c_uint, []),
    'glAttachShader': (None, [_c.c_uint, _c.c_uint]),
    'glLinkProgram': (None, [_c.c_uint]),
    'glGetProgramiv': (None, [_c.c_uint, _c.c_uint, _c.POINTER(_c.c_int)]),
    'glGetProgramInfoLog': (None, [_c.c_uint, _c.c_int, _c.c_void_p, _c.c_char_p]),
    'glDeleteProgram': (None, [_c.c_uint]),
    'glUseProgram': (None, [_c.c_uint]),
    'glGetUniformLocation': (_c.c_int, [_c.c_uint, _c.c_char_p]),
    'glUniform1f': (None, [_c.c_int, _c.c_float]),
    'glUniform3f': (None, [_c.c_int, _c.c_float, _c.c_float, _c.c_float]),
    'glUniformMatrix3fv': (None, [_c.c_int, _c.c_int, _c.c_ubyte, _c.POINTER(_c.c_float)]),
    'glUniformMatrix4fv': (None, [_c.c_int, _c.c_int, _c.c_ubyte, _c.POINTER(_c.c_float)]),
}


class _EglContext:
    """One OpenGL 3.3 core context per process on an EGL display without a window (Mesa's surfaceless
    platform, else the first EGL device), its GL functions as attributes (``gl.glClear(...)``).
    ``current()`` makes it current in the calling thread for a block (one thread at a time)."""

    def __init__(self):
        try:
            egl = ctypes.CDLL('libEGL.so.1')
        except OSError as error:
            raise RendererUnavailable(f'no EGL library ({error})') from None
        egl.eglGetProcAddress.restype = ctypes.c_void_p
        egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
        egl.eglInitialize.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_int), ctypes.POINTER(ctypes.c_int)]
        egl.eglBindAPI.argtypes = [ctypes.c_uint]
        egl.eglCreateContext.restype = ctypes.c_void_p
        egl.eglCreateContext.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                                         ctypes.POINTER(ctypes.c_int)]
        egl.eglMakeCurrent.argtypes = [ctypes.c_void_p] * 4
        egl.eglGetError.restype = ctypes.c_int
        self._egl = egl
        self._display = self._open_display()
        if not egl.eglBindAPI(_EGL_OPENGL_API):
            raise RendererUnavailable(f'eglBindAPI(OpenGL) failed ({egl.eglGetError():#x})')
        attributes = (ctypes.c_int * 7)(_EGL_CONTEXT_MAJOR_VERSION, 3, _EGL_CONTEXT_MINOR_VERSION, 3,
                                        _EGL_CONTEXT_OPENGL_PROFILE_MASK, _EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT,
                                        _EGL_NONE)
        self._context = egl.eglCreateContext(self._display, None, None, attributes)
        if not self._context:
            raise RendererUnavailable(f'no OpenGL 3.3 core context ({egl.eglGetError():#x})')
        self._lock = threading.RLock()
        for name, (result, arguments) in _GL_FUNCTIONS.items():
            address = egl.eglGetProcAddress(name.encode())
            if not address:
                raise RendererUnavailable(f'OpenGL function {name} missing')
            setattr(self, name, ctypes.CFUNCTYPE(result, *arguments)(address))
        with self.current():
            self.description = (self.glGetString(_GL_RENDERER) or b'?').decode(errors='replace')

    def _open_display(self):
        egl = self._egl
        get_platform_display = egl.eglGetProcAddress(b'eglGetPlatformDisplayEXT')
        if not get_platform_display:
            raise RendererUnavailable('EGL has no eglGetPlatformDisplayEXT')
        get_platform_display = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.c_uint, ctypes.c_void_p,
                                                ctypes.c_void_p)(get_platform_display)
        candidates = [(_EGL_PLATFORM_SURFACELESS_MESA, None)]
        query_devices = egl.eglGetProcAddress(b'eglQueryDevicesEXT')
        if query_devices:
            devices, count = (ctypes.c_void_p * 4)(), ctypes.c_int()
            ctypes.CFUNCTYPE(ctypes.c_uint, ctypes.c_int, ctypes.c_void_p, ctypes.POINTER(ctypes.c_int))(
                query_devices)(4, devices, ctypes.byref(count))
            candidates += [(_EGL_PLATFORM_DEVICE_EXT, devices[i]) for i in range(count.value)]
        major, minor = ctypes.c_int(), ctypes.c_int()
        for platform, native in candidates:
            display = get_platform_display(platform, native, None)
            if display and egl.eglInitialize(display, ctypes.byref(major), ctypes.byref(minor)):
                return display
        raise RendererUnavailable(f'no EGL display without a window could be initialised ({egl.eglGetError():#x})')

    def current(self):
        """Context manager: this context is current in the calling thread for the block."""
        return _current(self)

    def gen(self, function):
        """One new name from a glGen* ``function``."""
        name = ctypes.c_uint()
        function(1, ctypes.byref(name))
        return name.value

    def program(self, vertex_source, fragment_source):
        """A linked shader program; RendererUnavailable with the compiler's log otherwise."""
        shaders = []
        for kind, source in ((_GL_VERTEX_SHADER, vertex_source), (_GL_FRAGMENT_SHADER, fragment_source)):
            shader = self.glCreateShader(kind)
            self.glShaderSource(shader, 1, ctypes.byref(ctypes.c_char_p(source.encode())), None)
            self.glCompileShader(shader)
            self._check(shader, self.glGetShaderiv, self.glGetShaderInfoLog, _GL_COMPILE_STATUS, 'compile')
            shaders.append(shader)
        program = self.glCreateProgram()
        for shader in shaders:
            self.glAttachShader(program, shader)
        self.glLinkProgram(program)
        self._check(program, self.glGetProgramiv, self.glGetProgramInfoLog, _GL_LINK_STATUS, 'link')
        for shader in shaders:
            self.glDeleteShader(shader)
        return program

    def uniform(self, program, name):
        return self.glGetUniformLocation(program, name.encode())

    @staticmethod
    def _check(name, get, get_log, status, what):
        ok = ctypes.c_int()
        get(name, status, ctypes.byref(ok))
        if not ok.value:
            log = ctypes.create_string_buffer(4096)
            get_log(name, len(log), None, log)
            raise RendererUnavailable(f'shader {what} failed: {log.value.decode(errors="replace")}')


@contextlib.contextmanager
def _current(context):
    """``context`` current in the calling thread, holding its lock, for the block."""
    with context._lock:
        if not context._egl.eglMakeCurrent(context._display, None, None, context._context):
            raise RendererUnavailable(f'eglMakeCurrent failed ({context._egl.eglGetError():#x})')
        yield context


_context, _context_error, _context_lock = None, None, threading.Lock()


def shared_context():
    """The process's ``_EglContext`` (created on first use; a failure is remembered and raised again)."""
    global _context, _context_error
    with _context_lock:
        if _context is None and _context_error is None:
            try:
                _context = _EglContext()
            except RendererUnavailable as error:
                _context_error = error
        if _context_error is not None:
            raise RendererUnavailable(str(_context_error))
        return _context
