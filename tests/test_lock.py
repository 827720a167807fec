"""The container's lock files against pyproject.toml.

The Dockerfile installs requirements/runtime.lock (runtime stage) and requirements/test.lock (test
stage) with ``--require-hashes --no-deps``, so a dependency added to pyproject.toml without
running ``bash scripts/lock`` would be missing from the image; these checks catch that, without
network. They skip where requirements/ is not beside the tests (the container's test stage).
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

packaging_requirements = pytest.importorskip("packaging.requirements")
from packaging.utils import canonicalize_name  # noqa: E402  (after the importorskip)

ROOT = Path(__file__).resolve().parent.parent
LOCKS = ROOT / "requirements"
if not (LOCKS / "runtime.lock").is_file() or not (ROOT / "pyproject.toml").is_file():
    pytest.skip("requirements/*.lock are not beside the tests", allow_module_level=True)

# The interpreter and platform the locks are made for (scripts/lock): the image's Python.
IMAGE_ENV = {"python_version": "3.11", "python_full_version": "3.11.2", "sys_platform": "linux",
             "platform_system": "Linux", "platform_machine": "x86_64", "os_name": "posix",
             "implementation_name": "cpython", "platform_python_implementation": "CPython"}
# Test tools that must stay out of the runtime stage.
TEST_ONLY = {"pytest", "httpx", "embreex", "ruff", "mypy", "scipy"}

_PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==([^\s\\;]+)")


def read_lock(path: Path) -> dict[str, tuple[str, int]]:
    """Pins of a lock file: canonical name -> (version, number of hashes)."""
    pins: dict[str, tuple[str, int]] = {}
    current = None
    for line in path.read_text().splitlines():
        m = _PIN.match(line)
        if m:
            current = canonicalize_name(m.group(1))
            assert current not in pins, f"{path.name}: {current} pinned twice"
            pins[current] = (m.group(2), 0)
        elif current and line.strip().startswith("--hash=sha256:"):
            version, n = pins[current]
            pins[current] = (version, n + 1)
        elif not line.startswith(" "):
            current = None
    return pins


def requirements(*extras: str) -> list:
    """pyproject.toml's dependencies plus the named extras (self-references expanded)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    own = canonicalize_name(project["name"])
    out, todo, seen = list(project["dependencies"]), list(extras), set()
    while todo:
        extra = todo.pop()
        if extra in seen:
            continue
        seen.add(extra)
        out.extend(project["optional-dependencies"][extra])
    reqs = []
    for text in out:
        req = packaging_requirements.Requirement(text)
        if canonicalize_name(req.name) == own:
            todo = [e for e in req.extras if e not in seen]
            while todo:  # an extra naming the project's own extras
                extra = todo.pop()
                seen.add(extra)
                for t in project["optional-dependencies"][extra]:
                    r = packaging_requirements.Requirement(t)
                    if canonicalize_name(r.name) == own:
                        todo.extend(e for e in r.extras if e not in seen)
                    else:
                        reqs.append(r)
            continue
        reqs.append(req)
    return [r for r in reqs if r.marker is None or r.marker.evaluate(IMAGE_ENV)]


@pytest.mark.parametrize(("lock", "extras"), [("runtime.lock", ("server",)),
                                              ("test.lock", ("server", "test"))])
def test_lock_pins_every_requirement_of_pyproject(lock, extras):
    pins = read_lock(LOCKS / lock)
    problems = []
    for req in requirements(*extras):
        name = canonicalize_name(req.name)
        if name not in pins:
            problems.append(f"{req} is not in {lock}")
        elif not req.specifier.contains(pins[name][0], prereleases=True):
            problems.append(f"{req}: {lock} pins {pins[name][0]}")
    assert not problems, "; ".join(problems) + " (run: bash scripts/lock)"


def test_every_pin_has_hashes():
    for lock in ("runtime.lock", "test.lock"):
        unhashed = [n for n, (_, hashes) in read_lock(LOCKS / lock).items() if hashes == 0]
        assert not unhashed, f"{lock}: no --hash for {unhashed} (run: bash scripts/lock)"


def test_runtime_lock_has_no_test_tools_and_test_lock_keeps_its_pins():
    runtime = read_lock(LOCKS / "runtime.lock")
    test = read_lock(LOCKS / "test.lock")
    assert not TEST_ONLY & set(runtime), f"test tools in runtime.lock: {TEST_ONLY & set(runtime)}"
    assert TEST_ONLY <= set(test)
    # The test stage tests the runtime stage's versions.
    differ = {n: (v, test.get(n, ("missing",))[0]) for n, (v, _) in runtime.items()
              if test.get(n, ("missing",))[0] != v}
    assert not differ, f"runtime.lock and test.lock disagree: {differ} (run: bash scripts/lock)"


def test_read_lock_parses_pins_markers_and_hashes(tmp_path):
    """The parser itself, on the format uv writes."""
    lock = tmp_path / "x.lock"
    lock.write_text(
        "# header\n"
        "Foo_Bar==1.2.3 \\\n"
        "    --hash=sha256:aa \\\n"
        "    --hash=sha256:bb\n"
        "    # via x\n"
        "uvloop==0.23.0 ; sys_platform != 'win32' \\\n"
        "    --hash=sha256:cc\n"
        "plain==2.0\n"
    )
    assert read_lock(lock) == {"foo-bar": ("1.2.3", 2), "uvloop": ("0.23.0", 1),
                               "plain": ("2.0", 0)}
