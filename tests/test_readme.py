"""Every shell and Python example of README.md runs, as written, from a fresh copy of examples/.

The blocks are read from the README itself, so the two cannot drift: each ```sh, ```bash,
```shell, ```python or ```py block is one test. A block the test must not run (one that installs
packages, runs until stopped or builds a container) carries the comment
``<!-- readme-test: skip (why) -->`` on the line before its fence; there are few, each with its
reason.

Each block runs in a new temporary folder holding a copy of ``examples/``, the folder layout the
README's commands assume (they run from the repository's root), with this interpreter's
``bin`` folder first on ``PATH`` (``shadowmap``, ``python3``). Shell blocks run under
``bash -e -o pipefail``, with a ``.curlrc`` that makes ``curl`` fail on an HTTP error, so that a
``curl ... -o demo.png`` answered with a 4xx fails the test instead of saving the error. Blocks
that talk to ``http://127.0.0.1:8000`` get a real server this module starts on a free port: that
address is the one thing rewritten (to the server's). Files the block writes with ``-o FILE``
must exist afterwards and be valid PNG or JSON where their name says so.
"""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
EXAMPLES = ROOT / "examples"
SERVER = "http://127.0.0.1:8000"
SHELLS = {"sh", "bash", "shell"}
PYTHONS = {"python", "py"}
SKIP = re.compile(r"<!--\s*readme-test:\s*skip\s*\((?P<why>[^)]+)\)\s*-->")
#: Most blocks that may be marked as not run: the set-up scripts, serving, container builds.
MAX_SKIPPED = 6

pytestmark = [
    pytest.mark.gl,
    # The container's test stage copies tests/ alone: no README or examples beside them.
    pytest.mark.skipif(not (README.is_file() and EXAMPLES.is_dir()),
                       reason="README.md and examples/ are not beside the tests"),
]


@dataclass
class Block:
    line: int  # 1-based line of the opening fence
    language: str
    code: str
    skip: str | None  # the reason of a skip marker

    @property
    def id(self) -> str:
        return f"line{self.line}-{self.language}"


def blocks(text: str) -> list[Block]:
    """The fenced code blocks of a Markdown text, with the skip marker before each, if any."""
    out: list[Block] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        fence = re.match(r"^(```+|~~~+)\s*([\w+-]*)", lines[i])
        if not fence:
            i += 1
            continue
        start, marker = i, fence.group(1)
        before = next((lines[j] for j in range(i - 1, -1, -1) if lines[j].strip()), "")
        skip = SKIP.search(before)
        i += 1
        body = []
        while i < len(lines) and not lines[i].startswith(marker):
            body.append(lines[i])
            i += 1
        out.append(Block(start + 1, fence.group(2).lower(), "\n".join(body) + "\n",
                         skip.group("why").strip() if skip else None))
        i += 1
    return out


ALL = blocks(README.read_text(encoding="utf-8")) if README.is_file() else []
RUN = [b for b in ALL if b.language in SHELLS | PYTHONS]


def test_skip_markers_are_few_and_each_marks_a_block():
    text = README.read_text(encoding="utf-8")
    markers = [m.start() for m in SKIP.finditer(text)]
    marked = [b for b in ALL if b.skip is not None]
    assert len(markers) == len(marked), "a readme-test marker is not right before a code block"
    assert all(b.language in SHELLS | PYTHONS for b in marked)
    assert len(marked) <= MAX_SKIPPED, [b.id for b in marked]
    assert len(RUN) - len(marked) >= 3  # the examples themselves do run


def test_every_example_block_is_a_known_language():
    # An example in ```console or an untagged fence would be silently left out.
    unknown = [b.id for b in ALL if b.language not in SHELLS | PYTHONS | {"json", "text"}]
    assert not unknown, f"blocks of no runnable language: {unknown}"


@pytest.fixture(scope="module")
def server_url():
    """A real service on a free port, started only when a block needs one."""
    from test_page import uvicorn_server

    with uvicorn_server() as url:
        yield url


@pytest.fixture
def workdir(tmp_path):
    """A fresh folder laid out like the repository root, as far as the examples need it."""
    work = tmp_path / "repo"
    work.mkdir()
    shutil.copytree(EXAMPLES, work / "examples",
                    ignore=shutil.ignore_patterns("__pycache__", "out*", "*.zip"))
    curlrc = tmp_path / "curl"
    curlrc.mkdir()
    # Fail on HTTP errors (exit 22) and keep the progress meter out of the log.
    (curlrc / ".curlrc").write_text("fail-with-body\nsilent\nshow-error\n")
    return work, curlrc


def _outputs(code: str) -> list[str]:
    """Files a block writes with ``-o FILE`` (curl, ``shadowmap render``), or with ``-o -`` and
    the redirect of that line's standard output (``-o - > FILE``)."""
    files = []
    for line in code.splitlines():
        for name in re.findall(r"(?:^|\s)-o\s+(\S+)", line):
            if name == "-":
                redirect = re.search(r"(?:^|\s)>\s*(\S+)", line)
                assert redirect, f"{line!r}: -o - without a redirect to a file"
                name = redirect[1]
            files.append(name)
    return files


def _check_output(path: Path) -> None:
    assert path.is_file() and path.stat().st_size > 0, f"{path.name} was not written"
    data = path.read_bytes()
    if path.suffix == ".png":
        from PIL import Image

        Image.open(io.BytesIO(data)).load()  # a PNG that decodes
    elif path.suffix == ".json":
        body = json.loads(data)
        assert "error" not in body, body


@pytest.mark.parametrize("block", [b for b in RUN], ids=[b.id for b in RUN])
def test_readme_block_runs(block: Block, workdir, request):
    if block.skip is not None:
        pytest.skip(f"README marks it: {block.skip}")
    work, curl_home = workdir
    code = block.code
    if SERVER in code:
        code = code.replace(SERVER, request.getfixturevalue("server_url"))
    env = dict(os.environ)
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    env["CURL_HOME"] = str(curl_home)
    if block.language in SHELLS:
        cmd = ["bash", "-e", "-o", "pipefail", "-c", code]
    else:
        cmd = [sys.executable, "-c", code]
    proc = subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True, timeout=600)
    where = f"README.md line {block.line}:\n{block.code}\nstdout:\n{proc.stdout[-3000:]}\n" \
            f"stderr:\n{proc.stderr[-3000:]}"
    assert proc.returncode == 0, where
    assert "Traceback" not in proc.stderr, where
    for name in _outputs(block.code):
        _check_output(work / name)
