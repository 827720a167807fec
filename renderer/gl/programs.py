"""GLSL programs built from the files in the ``shaders`` package.

A stage is a list of files: library files (``*.glsl``) followed by one main file that starts with
``#version``. The source handed to the driver is that ``#version`` line, then one ``#define NAME
value`` per variant setting, then the library files, then the rest of the main file. Programs are
cached by (files, defines); compile and link errors raise :class:`ShaderError` naming the files.
Uniforms are set through :meth:`Program.set`, which raises on a name the program does not use
instead of silently ignoring it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import lru_cache
from importlib import resources

import numpy as np
from OpenGL import GL

from ..errors import ShaderError

Defines = tuple[tuple[str, str], ...]


@lru_cache(maxsize=None)
def shader_text(name: str) -> str:
    """Text of one file of the ``shaders`` package (works from a checkout and from a wheel)."""
    try:
        return resources.files("shadowmap.shaders").joinpath(name).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ShaderError(f"shader file {name!r} is not in the shaders package") from None


def build_source(files: Sequence[str], defines: Defines) -> str:
    """Assemble one stage's source: ``#version``, defines, library files, main file."""
    *libs, main = files
    text = shader_text(main)
    first, _, rest = text.partition("\n")
    if not first.startswith("#version"):
        raise ShaderError(f"{main}: the first line must be a #version directive")
    parts = [first]
    parts += [f"#define {k} {v}" for k, v in defines]
    # "#line L S": compiler messages then read "S:L", S being the file's number in `files` + 1.
    for i, lib in enumerate(libs):
        parts.append(f"#line 1 {i + 1}")
        parts.append(shader_text(lib))
    parts.append(f"#line 2 {len(libs) + 1}")
    parts.append(rest)
    return "\n".join(parts)


def normalize_defines(defines: Mapping[str, object] | None) -> Defines:
    """Sorted (name, value) pairs; booleans become 1/0 so ``#if NAME`` works."""
    out = []
    for k, v in sorted((defines or {}).items()):
        if isinstance(v, bool):
            v = int(v)
        out.append((k, str(v)))
    return tuple(out)


class Program:
    """A linked GL program with strict uniform setters.

    Parameters
    ----------
    vertex, fragment : sequence of str
        File names in the ``shaders`` package; the last one of each is the main file.
    defines : Defines
    """

    def __init__(self, vertex: Sequence[str], fragment: Sequence[str], defines: Defines) -> None:
        self.label = f"({', '.join(vertex)} | {', '.join(fragment)})"
        self.defines = defines
        shaders = []
        try:
            for files, kind in ((vertex, GL.GL_VERTEX_SHADER), (fragment, GL.GL_FRAGMENT_SHADER)):
                shaders.append(self._compile(files, kind, defines))
            self.id = GL.glCreateProgram()
            for s in shaders:
                GL.glAttachShader(self.id, s)
            GL.glLinkProgram(self.id)
            if GL.glGetProgramiv(self.id, GL.GL_LINK_STATUS) != GL.GL_TRUE:
                log = GL.glGetProgramInfoLog(self.id).decode(errors="replace")
                GL.glDeleteProgram(self.id)
                raise ShaderError(f"linking {self.label} failed: {log.strip()}")
        finally:
            for s in shaders:
                GL.glDeleteShader(s)
        self._uniforms = self._active_uniforms()

    @staticmethod
    def _compile(files: Sequence[str], kind: int, defines: Defines) -> int:
        source = build_source(files, defines)
        shader = GL.glCreateShader(kind)
        GL.glShaderSource(shader, source)
        GL.glCompileShader(shader)
        if GL.glGetShaderiv(shader, GL.GL_COMPILE_STATUS) != GL.GL_TRUE:
            log = GL.glGetShaderInfoLog(shader).decode(errors="replace")
            GL.glDeleteShader(shader)
            define_text = ", ".join(f"{k}={v}" for k, v in defines) or "no defines"
            numbers = ", ".join(f"{i + 1}={f}" for i, f in enumerate(files))
            raise ShaderError(
                f"compiling {' + '.join(files)} ({define_text}; source numbers {numbers}) "
                f"failed:\n{log.strip()}"
            )
        return shader

    def _active_uniforms(self) -> dict[str, tuple[int, int, int]]:
        """name -> (location, GL type, array size); arrays are listed without ``[0]``."""
        out = {}
        count = GL.glGetProgramiv(self.id, GL.GL_ACTIVE_UNIFORMS)
        for i in range(count):
            name, size, utype = GL.glGetActiveUniform(self.id, i)
            name = name.decode() if isinstance(name, bytes) else name
            if name.endswith("[0]"):
                name = name[:-3]
            out[name] = (GL.glGetUniformLocation(self.id, name), int(utype), int(size))
        return out

    def has(self, name: str) -> bool:
        """True when the program uses the uniform ``name`` (after the compiler's pruning)."""
        return name in self._uniforms

    def use(self) -> None:
        GL.glUseProgram(self.id)

    def set(self, name: str, value) -> None:
        """Set a uniform of the (bound) program.

        Raises
        ------
        ShaderError
            When the program has no active uniform called ``name``, or the value's shape does
            not fit its type.
        """
        try:
            loc, utype, size = self._uniforms[name]
        except KeyError:
            raise ShaderError(f"{self.label} has no active uniform {name!r}") from None
        v = np.asarray(value)
        setter = _SETTERS.get(utype)
        if setter is None:
            raise ShaderError(f"{self.label}: uniform {name!r} has an unsupported type {utype}")
        fn, width, dtype = setter
        flat = np.ascontiguousarray(v, dtype=dtype).reshape(-1)
        count = flat.size // width
        if flat.size % width or count < 1:
            raise ShaderError(
                f"{self.label}: uniform {name!r} takes value(s) of {width}, got shape {v.shape}"
            )
        # The compiler may shorten an array to its last element in use: the rest is unused.
        count = min(count, size)
        flat = flat[: count * width]
        if width == 16:
            fn(loc, count, GL.GL_TRUE, flat)  # row-major numpy matrices
        else:
            fn(loc, count, flat)

    def release(self) -> None:
        if self.id:
            GL.glDeleteProgram(self.id)
            self.id = 0


_SAMPLERS = (
    GL.GL_SAMPLER_2D,
    GL.GL_SAMPLER_2D_SHADOW,
    GL.GL_SAMPLER_CUBE,
    GL.GL_SAMPLER_CUBE_SHADOW,
)
_SETTERS: dict[int, tuple] = {
    GL.GL_FLOAT: (GL.glUniform1fv, 1, np.float32),
    GL.GL_FLOAT_VEC2: (GL.glUniform2fv, 2, np.float32),
    GL.GL_FLOAT_VEC3: (GL.glUniform3fv, 3, np.float32),
    GL.GL_FLOAT_VEC4: (GL.glUniform4fv, 4, np.float32),
    GL.GL_INT: (GL.glUniform1iv, 1, np.int32),
    GL.GL_BOOL: (GL.glUniform1iv, 1, np.int32),
    GL.GL_FLOAT_MAT4: (GL.glUniformMatrix4fv, 16, np.float32),
    **{s: (GL.glUniform1iv, 1, np.int32) for s in _SAMPLERS},
}


class ProgramCache:
    """Programs of one GL context, keyed by (vertex files, fragment files, defines)."""

    def __init__(self) -> None:
        self._programs: dict[tuple, Program] = {}

    def get(
        self,
        vertex: Sequence[str],
        fragment: Sequence[str],
        defines: Mapping[str, object] | None = None,
    ) -> Program:
        key = (tuple(vertex), tuple(fragment), normalize_defines(defines))
        prog = self._programs.get(key)
        if prog is None:
            prog = self._programs[key] = Program(key[0], key[1], key[2])
        return prog

    def __len__(self) -> int:
        return len(self._programs)

    def release(self) -> None:
        for p in self._programs.values():
            p.release()
        self._programs.clear()
