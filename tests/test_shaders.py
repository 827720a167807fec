"""The shader builder: includes, declared defines, #line mapping and the constants from Python.

Most cases build sources from small in-memory files and need no GL; those that compile are marked
``gl``.
"""

from __future__ import annotations

import re
from importlib import resources

import numpy as np
import pytest

from shadowmap.renderer import ShaderError, encodings
from shadowmap.renderer.gl.programs import (
    GENERATED,
    Program,
    ProgramCache,
    build_program,
    build_source,
    shader_text,
)
from shadowmap.renderer.limits import MAX_LIGHTS
from shadowmap.renderer.shader_constants import LIGHT_TYPES, shader_constants


def loader_of(files: dict[str, str]):
    """A loader over in-memory files, falling back to the shaders package."""

    def load(name: str) -> str:
        return files[name] if name in files else shader_text(name)

    return load


def source_lines(text: str) -> list[tuple[int, int, str]]:
    """(source number, line number, text) of every line that is not a ``#line`` directive.

    GLSL 3.30 and later: after ``#line L S`` the next line is line L of source string S.
    """
    out = []
    src, line = 0, 1
    for row in text.splitlines():
        m = re.fullmatch(r"#line (\d+) (\d+)", row)
        if m:
            line, src = int(m[1]), int(m[2])
            continue
        out.append((src, line, row))
        line += 1
    return out


MAIN = """#version 410 core
// a test stage
#define USE_B 0  // pull in b
#define SIZE 4

#include "chunks/a.glsl"
#if USE_B
#include "chunks/b.glsl"
#endif
void main() {}
"""
A = """// chunk a
float a() { return 1.0; }
"""
B = """// chunk b, which uses a
#include "chunks/a.glsl"
float b() { return a(); }
"""
FILES = {"main.frag": MAIN, "chunks/a.glsl": A, "chunks/b.glsl": B}


def test_include_is_replaced_by_the_file_with_line_directives():
    stage = build_source("main.frag", loader=loader_of(FILES))
    assert stage.files == ("main.frag", GENERATED, "chunks/a.glsl", "chunks/b.glsl")
    lines = stage.text.splitlines()
    n = len(shader_constants())
    assert lines[:2] == ["#version 410 core", "#line 1 1"]
    assert lines[2 + n : 6 + n] == ["#line 2 0", "// a test stage", "#define USE_B 0  // pull in b",
                                    "#define SIZE 4"]
    assert lines[6 + n : 11 + n] == [
        "",
        "#line 1 2",
        "// chunk a",
        "float a() { return 1.0; }",
        "#line 7 0",  # back in main.frag, on the line after the #include
    ]


@pytest.mark.parametrize("use_b", [0, 1])
def test_every_line_maps_back_to_its_file_and_line(use_b):
    stage = build_source("main.frag", {"USE_B": use_b}, loader=loader_of(FILES))
    seen = set()
    for src, line, row in source_lines(stage.text):
        name = stage.files[src]
        if name == GENERATED:
            continue
        original = FILES[name].splitlines()[line - 1]
        if row != original:  # only a set define, or an include left out, reads differently
            assert (row, original) == ("#define USE_B 1  // pull in b", MAIN.splitlines()[2]) or (
                row == f"// {original} (already included)"), (name, line, row)
        seen.add((name, line))
    # Every line of every file that entered, but the #include lines the files replace.
    expect = {(n, i + 1) for n in stage.files[:1] + stage.files[2:]
              for i in range(len(FILES[n].splitlines()))}
    # (b enters whatever USE_B says: includes are resolved before the preprocessor runs)
    expect -= {("main.frag", 6), ("main.frag", 8)}
    assert seen == expect


def test_a_file_enters_a_stage_once():
    stage = build_source("main.frag", loader=loader_of(FILES))
    # b's include of a is left out (a came in first): a's body appears once.
    assert stage.text.count("float a()") == 1
    assert stage.files == ("main.frag", GENERATED, "chunks/a.glsl", "chunks/b.glsl")
    assert '// #include "chunks/a.glsl" (already included)' in stage.text


def test_include_cycle_names_the_including_file_and_line():
    files = {
        "main.frag": '#version 410 core\n#include "chunks/x.glsl"\n',
        "chunks/x.glsl": '// x\n#include "chunks/y.glsl"\n',
        "chunks/y.glsl": '// y\n\n#include "chunks/x.glsl"\n',
    }
    with pytest.raises(ShaderError) as e:
        build_source("main.frag", loader=loader_of(files))
    assert str(e.value) == ('chunks/y.glsl:3: #include "chunks/x.glsl" makes a cycle: '
                            "chunks/x.glsl -> chunks/y.glsl -> chunks/x.glsl")


def test_a_file_including_itself_is_a_cycle():
    files = {"main.frag": '#version 410 core\n#include "main.frag"\n'}
    with pytest.raises(ShaderError, match=r"^main\.frag:2: .* cycle: main\.frag -> main\.frag$"):
        build_source("main.frag", loader=loader_of(files))


def test_missing_include_names_the_including_file_and_line():
    files = FILES | {"main.frag": MAIN.replace("chunks/a.glsl", "chunks/nope.glsl")}
    with pytest.raises(ShaderError, match=r'^main\.frag:6: #include "chunks/nope\.glsl": no such'):
        build_source("main.frag", loader=loader_of(files))


def test_missing_main_file_and_malformed_include():
    with pytest.raises(ShaderError, match="'nope.frag' is not in the shaders package"):
        build_source("nope.frag")
    files = {"main.frag": "#version 410 core\n#include chunks/a.glsl\n"}
    with pytest.raises(ShaderError, match=r"^main\.frag:2: malformed #include"):
        build_source("main.frag", loader=loader_of(files))
    files = {"main.frag": '#version 410 core\n#include "../secret.glsl"\n'}
    with pytest.raises(ShaderError, match="leaves the shaders package"):
        build_source("main.frag", loader=loader_of(files))


def test_main_file_must_start_with_version_and_chunks_must_not_have_one():
    with pytest.raises(ShaderError, match="first line must be a #version"):
        build_source("main.frag", loader=loader_of({"main.frag": "// no version\n"}))
    files = FILES | {"chunks/a.glsl": "#version 410 core\n"}
    with pytest.raises(ShaderError, match=r"^chunks/a\.glsl:1: #version"):
        build_source("main.frag", loader=loader_of(files))


def test_requested_defines_replace_the_declared_defaults():
    stage = build_source("main.frag", {"SIZE": 16, "USE_B": True}, loader=loader_of(FILES))
    lines = stage.text.splitlines()
    assert "#define USE_B 1  // pull in b" in lines  # booleans become 1/0; the comment stays
    assert "#define SIZE 16" in lines
    assert {d.name: (d.default, d.file, d.line) for d in stage.declared.values()} == {
        "USE_B": ("0", "main.frag", 3),
        "SIZE": ("4", "main.frag", 4),
    }
    default = build_source("main.frag", loader=loader_of(FILES))
    assert "#define SIZE 4" in default.text.splitlines()


def test_unknown_define_is_refused():
    load = loader_of(FILES)
    with pytest.raises(ShaderError, match=r"main\.frag declares no SIZ\b"):
        build_source("main.frag", {"SIZ": 8}, loader=load)
    # A define of the real shaders, misspelt.
    with pytest.raises(ShaderError, match="neither light_pass.vert nor light_pass.frag declares "
                                          "ENCODNG"):
        build_program("light_pass.vert", "light_pass.frag", {"ENCODNG": 1})


def test_only_the_header_declares():
    # A #define after the first line of code, or a function-like macro, is no variant define.
    files = {
        "main.frag": "#version 410 core\n#define TWICE(x) (2 * (x))\n#define A 1\n"
                     "float f;\n#define LATE 1\n",
    }
    stage = build_source("main.frag", loader=loader_of(files))
    assert set(stage.declared) == {"A"}
    for name in ("TWICE", "LATE"):
        with pytest.raises(ShaderError, match=f"declares no {name}"):
            build_source("main.frag", {name: 2}, loader=loader_of(files))


def test_a_chunk_header_declares_too_but_only_once():
    files = {
        "main.frag": '#version 410 core\n#define A 1\n#include "chunks/c.glsl"\n',
        "chunks/c.glsl": "// c\n#define C 0\nfloat c;\n",
    }
    assert set(build_source("main.frag", loader=loader_of(files)).declared) == {"A", "C"}
    files["chunks/c.glsl"] = "#define A 2\n"
    with pytest.raises(ShaderError, match=r"^chunks/c\.glsl:1: A is already declared at "
                                          r"main\.frag:2$"):
        build_source("main.frag", loader=loader_of(files))


def test_the_stages_of_a_program_share_one_define_dict():
    # LOC_MODEL is the vertex stage's, ENCODING the fragment stage's, ALPHA_TEST both stages'.
    defines = {"LOC_MODEL": 4, "ENCODING": 3, "ALPHA_TEST": 1}
    vert, frag = build_program("light_pass.vert", "light_pass.frag", defines)
    assert "#define LOC_MODEL 4" in vert.text and "LOC_MODEL" not in frag.text
    assert "ENCODING 3" in frag.text and "ENCODING" not in vert.text
    assert "#define ALPHA_TEST 1" in vert.text and "#define ALPHA_TEST 1" in frag.text
    # One stage alone refuses the other's names unless told they are shared.
    with pytest.raises(ShaderError, match="declares no LOC_MODEL"):
        build_source("light_pass.frag", defines)
    build_source("light_pass.frag", defines, shared=vert.declared)


def test_define_values_must_fit_on_one_line():
    with pytest.raises(ShaderError, match="one line"):
        build_source("light_pass.frag", {"ENCODING": "1\n2"})


def test_constants_are_python_values():
    # The generated source string: exactly the Python constants, before the main file.
    stage = build_source("fullscreen.vert")
    rows = [row for src, _, row in source_lines(stage.text) if src == 1]
    got = dict(re.fullmatch(r"#define (\S+) (.*)", row).groups() for row in rows)
    assert got == dict(shader_constants())
    for name, ident in encodings.ENCODING_ID.items():
        assert got[f"ENC_{name.upper()}"] == str(ident)
    for name, ident in LIGHT_TYPES.items():
        assert got[f"LIGHT_{name.upper()}"] == str(ident)
    assert got["MAX_LIGHTS"] == str(MAX_LIGHTS)
    assert got["FOR_EACH_SLOT(X)"].split() == [f"X({k})" for k in range(MAX_LIGHTS)]


def test_glsl_files_do_not_define_the_constants():
    files = {"main.frag": "#version 410 core\nvoid f() {}\n#define LIGHT_POINT 2\n"}
    with pytest.raises(ShaderError, match=r"^main\.frag:3: LIGHT_POINT is a constant"):
        build_source("main.frag", loader=loader_of(files))
    # Nor guard them: without the builder's definitions a shader must fail to compile.
    names = {n.split("(")[0] for n, _ in shader_constants()}
    root = resources.files("shadowmap.shaders")
    paths = [p for p in root.iterdir() if p.name.endswith((".vert", ".frag", ".glsl"))]
    paths += [p for p in root.joinpath("chunks").iterdir() if p.name.endswith(".glsl")]
    assert len(paths) >= 12
    for p in paths:
        for row in p.read_text().splitlines():
            m = re.match(r"\s*#\s*(ifn?def|define|undef)\s+(\w+)", row)
            assert not (m and m[2] in names), (p.name, row)


@pytest.mark.parametrize(
    "vertex, fragment",
    [("camera_pass.vert", "camera_pass.frag"), ("light_pass.vert", "light_pass.frag"),
     ("fullscreen.vert", "encoding_probe.frag"), ("fullscreen.vert", "compare_probe.frag")],
)
def test_every_program_of_the_package_builds_with_its_defaults(vertex, fragment):
    vert, frag = build_program(vertex, fragment)
    assert vert.files[0] == vertex and frag.files[0] == fragment
    assert "#include" not in frag.text.replace("// #include", "")


def test_camera_pass_pulls_in_its_chunks_once():
    frag = build_source("camera_pass.frag")
    assert frag.files == (
        "camera_pass.frag", GENERATED, "chunks/lighting.glsl", "chunks/shadow_2d.glsl",
        "chunks/shadow_lookup.glsl", "chunks/depth_encoding.glsl", "chunks/shadow_cube.glsl",
        "chunks/shadow_csm.glsl",
    )
    assert frag.text.count("vec4 encode_depth(float t)") == 1


def test_locations_in_a_compiler_log_are_named_by_file():
    stage = build_source("main.frag", loader=loader_of(FILES))
    log = "2:2(7): error: syntax error\n0:10(1): warning: x\n9:1(1): error: y"
    assert stage.locate(log) == ("chunks/a.glsl:2(7): error: syntax error\n"
                                 "main.frag:10(1): warning: x\n9:1(1): error: y")
    assert stage.locate("ERROR: 0:3: bad") == "ERROR: main.frag:3: bad"
    assert stage.locate("2(5) : error C0000: bad") == "chunks/a.glsl:5 : error C0000: bad"
    assert stage.legend() == "0=main.frag, 1=<constants>, 2=chunks/a.glsl, 3=chunks/b.glsl"


def test_shader_text_reads_subfolders_of_the_package():
    assert shader_text("chunks/depth_encoding.glsl").startswith("// Depth encodings")
    with pytest.raises(ShaderError, match="not in the shaders package"):
        shader_text("chunks/nope.glsl")


def test_programs_are_named_by_their_main_files():
    with pytest.raises(TypeError, match="main files"):
        ProgramCache().get(("camera_pass.vert",), ("chunks/lighting.glsl", "camera_pass.frag"))


# -- compiled -------------------------------------------------------------------------------


BAD_CHUNK = "// bad\nfloat bad() {\n    return 1.0 +;\n}\n"
BAD_MAIN = """#version 410 core
#define K 1
#include "chunks/a.glsl"
layout(location = 0) out vec4 o;
void main() {
    o = vec4(undeclared_name);
}
"""


@pytest.mark.gl
@pytest.mark.parametrize(
    "files, where",
    [
        (FILES | {"main.frag": MAIN.replace("chunks/a.glsl", "chunks/bad.glsl"),
                  "chunks/bad.glsl": BAD_CHUNK}, "chunks/bad.glsl:3"),
        ({"main.frag": BAD_MAIN, "chunks/a.glsl": A}, "main.frag:6"),
    ],
)
def test_compile_error_names_the_file_and_line(renderer, files, where):
    renderer.context.make_current()
    with pytest.raises(ShaderError) as e:
        Program("fullscreen.vert", "main.frag", (), loader=loader_of(files))
    message = str(e.value)
    assert message.startswith("compiling main.frag (no defines; source numbers 0=main.frag, "
                              "1=<constants>, 2=chunks/"), message
    # The file and line, then what the driver puts there: Mesa a column, "chunks/bad.glsl:3(12):
    # error", NVIDIA a space, "chunks/bad.glsl:3 : error".
    assert re.search(rf"^{re.escape(where)}[( ]", message, re.M), message


CONSTANTS_PROBE = """#version 410 core
#define ENCODING ENC_DEPTH
#include "chunks/depth_encoding.glsl"
layout(location = 0) out vec4 o_value;
#define COUNT(K) + 1
const float VALUES[{n}] = float[{n}]({values});
void main() {{
    o_value = vec4(VALUES[int(gl_FragCoord.x)], 0.0, 0.0, 1.0);
}}
"""


@pytest.mark.gl
@pytest.mark.parametrize("encoding", list(encodings.ENCODING_ID))
def test_glsl_sees_the_python_constants(renderer, encoding):
    from OpenGL import GL

    from probes import _run

    expected = {f"ENC_{e.upper()}": i for e, i in encodings.ENCODING_ID.items()}
    expected |= {f"LIGHT_{t.upper()}": i for t, i in LIGHT_TYPES.items()}
    expected |= {"MAX_LIGHTS": MAX_LIGHTS, "0 FOR_EACH_SLOT(COUNT)": MAX_LIGHTS}
    values = ", ".join(f"float({k})" for k in expected)
    files = {"probe.frag": CONSTANTS_PROBE.format(n=len(expected), values=values)}
    renderer.context.make_current()
    prog = Program("fullscreen.vert", "probe.frag",
                   (("ENCODING", str(encodings.ENCODING_ID[encoding])),), loader=loader_of(files))
    try:
        out = _run(renderer, prog, None, {}, len(expected), 1,
                   (GL.GL_R32F, GL.GL_RED, GL.GL_FLOAT, 1, np.float32))
    finally:
        prog.release()
    got = dict(zip(expected, out[0, :, 0], strict=True))
    assert got == {k: np.float32(v) for k, v in expected.items()}


@pytest.mark.gl
def test_real_programs_compile_with_their_defaults(renderer):
    renderer.context.make_current()
    cache = ProgramCache()
    try:
        cache.get("camera_pass.vert", "camera_pass.frag")
        cache.get("light_pass.vert", "light_pass.frag")
        assert len(cache) == 2
    finally:
        cache.release()


# -- derivatives and discard ----------------------------------------------------------------

# Derivatives, and the texture reads that take them implicitly to choose a mipmap level.
_DERIVATIVE = re.compile(r"\b(?:(?:dFdx|dFdy|fwidth)(?:Fine|Coarse)?|texture|textureProj"
                         r"|textureOffset|textureProjOffset)\s*\(")
_FUNCTION = re.compile(r"^\w+\s+(?P<name>\w+)\s*\([^;{]*\)\s*\{", re.M)


def _bodies(text: str) -> dict[str, str]:
    """Each top-level function of a GLSL text: name -> body (braces matched)."""
    out = {}
    for m in _FUNCTION.finditer(text):
        depth, i = 1, m.end()
        while depth and i < len(text):
            depth += {"{": 1, "}": -1}.get(text[i], 0)
            i += 1
        out[m.group("name")] = text[m.end():i - 1]
    return out


def _code(text: str) -> str:
    return re.sub(r"//[^\n]*", "", text)


def test_every_discard_comes_after_the_last_derivative():
    """A quad's derivatives are undefined once one of its fragments is discarded: NVIDIA's were
    garbage there, which drew false shadow along every alpha cut-out's outline (llvmpipe's stay
    right, so only this order shows it here). In each fragment stage's main(), every derivative
    (and every texture read that takes them for its mipmap level), direct or through a function
    of the shaders that takes one, precedes the first discard."""
    folder = resources.files("shadowmap.shaders")
    texts = {f.name: _code(f.read_text()) for f in folder.iterdir() if f.name.endswith(".frag")}
    chunks = [_code(f.read_text()) for f in folder.joinpath("chunks").iterdir()
              if f.name.endswith(".glsl")]
    takes_derivative = {name for text in [*chunks, *texts.values()]
                        for name, body in _bodies(text).items() if _DERIVATIVE.search(body)}
    assert "map2d_derivatives" in takes_derivative
    uses = re.compile(_DERIVATIVE.pattern + "|" + "|".join(
        rf"\b{name}\s*\(" for name in sorted(takes_derivative)))
    checked = 0
    for name, text in texts.items():
        main = _bodies(text).get("main", "")
        discard = main.find("discard")
        if discard < 0:
            continue
        last = max((m.start() for m in uses.finditer(main)), default=-1)
        assert last < discard, f"{name}: a derivative after the first discard in main()"
        checked += 1
    assert checked >= 2  # the camera pass's cut-out and the light pass's alpha test
