"""GLSL programs built from the files in the ``shaders`` package.

A program is named by its two main files, e.g. ``("camera_pass.vert", "camera_pass.frag")``. Each
main file starts with ``#version``; the builder then assembles the source the driver gets:

- ``#include "name.glsl"`` lines are replaced by that file of the ``shaders`` package (names are
  relative to the package, e.g. ``"chunks/lighting.glsl"``), recursively; each file enters a stage
  once, later includes of it are left out, and an include cycle or a missing file raises
  :class:`ShaderError` naming the including file and line. Includes are resolved before the GLSL
  preprocessor runs, so one inside a false ``#if`` is still pulled in.
- A stage *declares* its variant defines with their defaults at the top of its files: the
  ``#define NAME value`` lines before the first line that is not blank, a ``//`` comment or a
  ``#define`` (right after ``#version`` in a main file). The requested defines replace those
  values in place; a requested name that neither stage of the program declares raises
  :class:`ShaderError` (a typo would otherwise compile to the default silently).
- The constants shared with Python (:func:`~shadowmap.renderer.shader_constants.shader_constants`)
  are defined right after ``#version``, in every stage; a GLSL file that defines one of them
  raises :class:`ShaderError`.
- ``#line`` directives number the lines by file: source string 0 is the main file (so its
  ``#version`` line is 0:1, as drivers number a single string), 1 the generated constants, 2 and
  on the included files in the order they enter. Compile errors rewrite the driver's ``S:L``
  locations to ``file:L`` and list the numbers.

Programs are cached by (files, defines). Uniforms are set through :meth:`Program.set`, which raises
on a name the program does not use instead of silently ignoring it.
"""

from __future__ import annotations

import posixpath
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from functools import cache
from importlib import resources

import numpy as np
from numpy.typing import ArrayLike
from OpenGL import GL

from ..errors import ShaderError
from ..shader_constants import shader_constants

Defines = tuple[tuple[str, str], ...]
#: Text of a file by its name in the ``shaders`` package; raises ShaderError, FileNotFoundError
#: or KeyError when there is no such file.
Loader = Callable[[str], str]

#: Legend name of source string 1, the constants the builder writes.
GENERATED = "<constants>"

_INCLUDE = re.compile(r"^\s*#\s*include\b(?P<rest>.*)$")
_INCLUDE_NAME = re.compile(r'^\s*"(?P<name>[^"]+)"\s*(//.*)?$')
_DEFINE = re.compile(r"^\s*#\s*define\s+(?P<name>[A-Za-z_]\w*)")
# An object-like macro: the name is followed by blanks, a comment or the end of the line (a
# function-like one has "(" right after the name and is no declaration).
_DECLARATION = re.compile(
    r"^(?P<head>\s*#\s*define\s+)(?P<name>[A-Za-z_]\w*)"
    r"(?:[ \t]+(?P<value>.*?))?[ \t]*(?P<comment>//.*)?$"
)
_IDENTIFIER = re.compile(r"^[A-Za-z_]\w*$")
# Compiler locations "S:L" of the common drivers: Mesa "0:12(5): error", "ERROR: 0:12: ..." (AMD,
# Intel on Windows), NVIDIA "0(12) : error".
_LOCATIONS = (
    re.compile(r"^(?P<pre>)(?P<src>\d+):(?P<line>\d+)(?P<post>\(\d+\))", re.M),
    re.compile(r"^(?P<pre>(?:ERROR|WARNING): )(?P<src>\d+):(?P<line>\d+)(?P<post>)", re.M),
    re.compile(r"^(?P<pre>)(?P<src>\d+)\((?P<line>\d+)\)(?P<post>)", re.M),
)


@cache
def shader_text(name: str) -> str:
    """Text of one file of the ``shaders`` package (works from a checkout and from a wheel).

    Parameters
    ----------
    name : str
        Path inside the package with ``/`` separators, e.g. ``"chunks/lighting.glsl"``.

    Raises
    ------
    ShaderError
        When the package has no such file.
    """
    node = resources.files("shadowmap.shaders")
    for part in name.split("/"):  # one segment at a time: every Traversable supports that
        node = node.joinpath(part)
    try:
        return node.read_text(encoding="utf-8")
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
        raise ShaderError(f"shader file {name!r} is not in the shaders package") from None


@dataclass(frozen=True)
class Declaration:
    """A variant define a stage declares: ``#define name default`` at ``file``:``line``."""

    name: str
    default: str
    file: str
    line: int


@dataclass(frozen=True)
class StageSource:
    """One stage, its includes resolved and its defines set: what the driver compiles.

    Attributes
    ----------
    main : str
        The stage's main file.
    text : str
        The source handed to the driver.
    files : tuple of str
        Source-string number (as in ``#line`` and the compiler's messages) -> file;
        ``files[0]`` is the main file, ``files[1]`` :data:`GENERATED`.
    declared : dict of str to Declaration
        The variant defines of the stage (its main file and includes), by name.
    """

    main: str
    text: str
    files: tuple[str, ...]
    declared: Mapping[str, Declaration]

    def legend(self) -> str:
        """``"0=camera_pass.frag, 1=<constants>, 2=chunks/lighting.glsl, ..."``: the numbers."""
        return ", ".join(f"{i}={f}" for i, f in enumerate(self.files))

    def locate(self, log: str) -> str:
        """The compiler's log with each ``S:L`` location at a line start written ``file:L``."""

        def name(m: re.Match) -> str:
            src = int(m["src"])
            if src >= len(self.files):
                return m[0]
            return f"{m['pre']}{self.files[src]}:{m['line']}{m['post']}"

        for pattern in _LOCATIONS:
            log, count = pattern.subn(name, log)
            if count:
                break
        return log


@dataclass
class _Resolved:
    """A stage with its includes resolved; the declaration lines still hold their defaults."""

    main: str
    lines: list[str]
    files: list[str]
    declared: dict[str, Declaration]
    # Index in `lines` of each declaration, its text before the value, its comment and the
    # comment's column (kept when the value changes, so that dumps stay aligned).
    slots: dict[str, tuple[int, str, str, int]]


def _constant_names() -> set[str]:
    return {name.split("(", 1)[0] for name, _ in shader_constants()}


def _read(name: str, loader: Loader) -> str:
    try:
        return loader(name)
    except ShaderError as e:
        raise FileNotFoundError(str(e)) from None
    except KeyError:
        raise FileNotFoundError(f"shader file {name!r} is not in the shaders package") from None


def _include_name(including: str, lineno: int, rest: str) -> str:
    m = _INCLUDE_NAME.match(rest)
    if m is None:
        raise ShaderError(f'{including}:{lineno}: malformed #include (want #include "name.glsl")')
    name = posixpath.normpath(m["name"])
    if name.startswith(("/", "../")) or name == "..":
        raise ShaderError(f"{including}:{lineno}: #include {m['name']!r} leaves the shaders "
                          "package")
    return name


def _resolve(main: str, loader: Loader) -> _Resolved:
    """Resolve the includes of one stage and find its declarations."""
    try:
        text = _read(main, loader)
    except FileNotFoundError as e:
        raise ShaderError(str(e)) from None
    out = _Resolved(main, [], [], {}, {})
    constants = _constant_names()

    def expand(name: str, text: str, stack: list[str]) -> None:
        src = len(out.files)
        out.files.append(name)
        lines = text.splitlines()
        start = 0
        if src == 0:
            if not lines or not lines[0].startswith("#version"):
                raise ShaderError(f"{name}: the first line must be a #version directive")
            out.files.append(GENERATED)
            out.lines.append(lines[0])
            out.lines.append("#line 1 1")
            out.lines += [f"#define {k} {v}" for k, v in shader_constants()]
            out.lines.append("#line 2 0")
            start = 1
        else:
            out.lines.append(f"#line 1 {src}")
        header = True  # still in the block where declarations go
        for i in range(start, len(lines)):
            line, lineno = lines[i], i + 1
            stripped = line.strip()
            if stripped.startswith("#") and stripped[1:].lstrip().startswith("version"):
                raise ShaderError(f"{name}:{lineno}: #version belongs on the first line of a main "
                                  "file only")
            inc = _INCLUDE.match(line)
            if inc is not None:
                header = False
                target = _include_name(name, lineno, inc["rest"])
                if target in stack:
                    cycle = " -> ".join(stack[stack.index(target):] + [target])
                    raise ShaderError(f'{name}:{lineno}: #include "{target}" makes a cycle: '
                                      f"{cycle}")
                if target in out.files:
                    out.lines.append(f"// {stripped} (already included)")
                    continue
                try:
                    child = _read(target, loader)
                except FileNotFoundError:
                    raise ShaderError(f'{name}:{lineno}: #include "{target}": no such file in the '
                                      "shaders package") from None
                expand(target, child, stack + [target])
                out.lines.append(f"#line {lineno + 1} {src}")
                continue
            define = _DEFINE.match(line)
            if define is not None and define["name"] in constants:
                raise ShaderError(f"{name}:{lineno}: {define['name']} is a constant the builder "
                                  "defines from Python (shader_constants); do not define it here")
            if header and define is not None:
                decl = _DECLARATION.match(line)
                if decl is not None:
                    dname = decl["name"]
                    if dname in out.declared:
                        first = out.declared[dname]
                        raise ShaderError(f"{name}:{lineno}: {dname} is already declared at "
                                          f"{first.file}:{first.line}")
                    default = decl["value"] or ""
                    out.declared[dname] = Declaration(dname, default, name, lineno)
                    column = decl.start("comment") if decl["comment"] else 0
                    out.slots[dname] = (len(out.lines), decl["head"] + dname,
                                        decl["comment"] or "", column)
            elif header and stripped and not stripped.startswith("//"):
                header = False
            out.lines.append(line)

    expand(main, text, [main])
    return out


def _specialise(stage: _Resolved, defines: Defines, shared: Iterable[str]) -> StageSource:
    allowed = set(stage.declared) | set(shared)
    unknown = [k for k, _ in defines if k not in allowed]
    if unknown:
        raise ShaderError(f"{stage.main} declares no {', '.join(unknown)} (declared: "
                          f"{', '.join(sorted(allowed)) or 'none'})")
    lines = list(stage.lines)
    for k, v in defines:
        if k in stage.slots:
            index, head, comment, column = stage.slots[k]
            line = f"{head} {v}" if v else head
            if comment:
                line += " " * max(2, column - len(line)) + comment
            lines[index] = line
    return StageSource(stage.main, "\n".join(lines) + "\n", tuple(stage.files),
                       dict(stage.declared))


def build_source(
    main: str,
    defines: Mapping[str, object] | Defines | None = None,
    *,
    shared: Iterable[str] = (),
    loader: Loader = shader_text,
) -> StageSource:
    """Assemble one stage: ``#version``, the constants, then the main file with its includes.

    Parameters
    ----------
    main : str
        The stage's main file in the ``shaders`` package.
    defines : mapping or Defines, optional
        Values for the stage's declared defines (see :func:`normalize_defines`).
    shared : iterable of str
        Names the program's other stage declares: requested, but left alone here.
    loader : callable, optional
        Reads a file by name; the ``shaders`` package by default.

    Raises
    ------
    ShaderError
        A missing file or include, an include cycle, a name that is neither declared nor in
        ``shared``, or a GLSL file defining one of the Python constants.
    """
    return _specialise(_resolve(main, loader), normalize_defines(defines), shared)


def build_program(
    vertex: str,
    fragment: str,
    defines: Mapping[str, object] | Defines | None = None,
    *,
    loader: Loader = shader_text,
) -> tuple[StageSource, StageSource]:
    """Both stages of a program from one define dict.

    The stages share the dict, so a name needs declaring by one of them only; each stage sets
    the names it declares.

    Raises
    ------
    ShaderError
        As :func:`build_source`; an unknown name is one that neither stage declares.
    """
    pairs = normalize_defines(defines)
    stages = (_resolve(vertex, loader), _resolve(fragment, loader))
    unknown = [k for k, _ in pairs if not any(k in s.declared for s in stages)]
    if unknown:
        raise ShaderError(f"neither {vertex} nor {fragment} declares {', '.join(unknown)}")
    vert, frag = stages
    return (_specialise(vert, pairs, frag.declared), _specialise(frag, pairs, vert.declared))


def normalize_defines(defines: Mapping[str, object] | Defines | None) -> Defines:
    """Sorted (name, value) pairs; booleans become 1/0 so ``#if NAME`` works.

    Raises
    ------
    ShaderError
        A name that is no identifier, or a value that spans lines (it would shift every
        line number after it).
    """
    items = defines.items() if isinstance(defines, Mapping) else (defines or ())
    out = []
    for k, v in sorted(items):
        if isinstance(v, bool):
            v = int(v)
        v = str(v).strip()
        if not _IDENTIFIER.match(k):
            raise ShaderError(f"define name {k!r} is not an identifier")
        if "\n" in v or "\r" in v:
            raise ShaderError(f"define {k}: the value must fit on one line, got {v!r}")
        out.append((k, v))
    return tuple(out)


class Program:
    """A linked GL program with strict uniform setters.

    Parameters
    ----------
    vertex, fragment : str
        The main files of the two stages in the ``shaders`` package.
    defines : Defines
        Values of the variant defines the stages declare (:func:`normalize_defines`).
    loader : callable, optional
        Reads a file by name; the ``shaders`` package by default.
    """

    def __init__(self, vertex: str, fragment: str, defines: Defines,
                 loader: Loader = shader_text) -> None:
        self.label = f"({vertex} | {fragment})"
        self.defines = defines
        # Built before any GL object exists: a bad include or define leaves nothing to clean up.
        stages = build_program(vertex, fragment, defines, loader=loader)
        shaders = []
        try:
            kinds = (GL.GL_VERTEX_SHADER, GL.GL_FRAGMENT_SHADER)
            for stage, kind in zip(stages, kinds, strict=True):
                shaders.append(self._compile(stage, kind, defines))
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
        self._values: dict[int, bytes] = {}  # the value last sent to each uniform location
        # The plan and texture units the camera pass last set this program's frame uniforms for.
        self.frame_plan: object = None
        self.frame_units: list[int] = []

    @staticmethod
    def _compile(stage: StageSource, kind: int, defines: Defines) -> int:
        shader = GL.glCreateShader(kind)
        GL.glShaderSource(shader, stage.text)
        GL.glCompileShader(shader)
        if GL.glGetShaderiv(shader, GL.GL_COMPILE_STATUS) != GL.GL_TRUE:
            log = GL.glGetShaderInfoLog(shader).decode(errors="replace")
            GL.glDeleteShader(shader)
            define_text = ", ".join(f"{k}={v}" for k, v in defines) or "no defines"
            raise ShaderError(
                f"compiling {stage.main} ({define_text}; source numbers {stage.legend()}) "
                f"failed:\n{stage.locate(log.strip())}"
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

    def set(self, name: str, value: ArrayLike) -> None:
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
        # A program keeps its uniforms: a value it holds already is not sent again (most of a
        # frame's uniforms repeat the last frame's, and each call through PyOpenGL costs far
        # more than this comparison).
        raw = flat.tobytes()
        if self._values.get(loc) == raw:
            return
        self._values[loc] = raw
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
    GL.GL_SAMPLER_2D_ARRAY,
    GL.GL_SAMPLER_2D_ARRAY_SHADOW,
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
    """Programs of one GL context, keyed by (vertex file, fragment file, defines).

    Parameters
    ----------
    loader : callable, optional
        Reads a shader file by name; the ``shaders`` package by default.
    """

    #: What :meth:`get` builds (a subclass may change how uniforms are set).
    program_type: type[Program] = Program

    def __init__(self, loader: Loader = shader_text) -> None:
        self._programs: dict[tuple, Program] = {}
        self._seen: dict[tuple, Program] = {}  # by the defines' items as given
        self._loader = loader

    def get(
        self,
        vertex: str,
        fragment: str,
        defines: Mapping[str, object] | None = None,
    ) -> Program:
        """The program of two main files and a define dict, built on first use.

        Raises
        ------
        ShaderError
            When building fails (see :func:`build_program`), or compiling or linking does.
        """
        if not isinstance(vertex, str) or not isinstance(fragment, str):
            # The former API took tuples of library files: those now come in by #include.
            raise TypeError("a program is named by its two main files, e.g. "
                            "get('camera_pass.vert', 'camera_pass.frag', defines)")
        # Draws ask with the same dicts, built in the same order, every frame: their items
        # find the program without normalising them again.
        fast = (vertex, fragment, tuple(defines.items())) if defines else (vertex, fragment)
        prog = self._seen.get(fast)
        if prog is not None:
            return prog
        key = (vertex, fragment, normalize_defines(defines))
        prog = self._programs.get(key)
        if prog is None:
            prog = self._programs[key] = self.program_type(*key, loader=self._loader)
        self._seen[fast] = prog
        return prog

    def __len__(self) -> int:
        return len(self._programs)

    def release(self) -> None:
        for p in self._programs.values():
            p.release()
        self._programs.clear()
        self._seen.clear()
