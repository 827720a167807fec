"""bench/install_size.py: how it counts, and (on request) the service's install against its bound.

The bound itself is checked in CI by scripts/container-test, on the runtime image's virtualenv
(no download: the image is built anyway). The full check here builds a fresh virtualenv the way
``bash scripts/serve`` does, which downloads every wheel (a minute or two), so it runs only with
``SHADOWMAP_INSTALL_SIZE_TEST=1``. Everything skips where bench/ is not beside the tests (the
container's test stage).
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "bench" / "install_size.py"
if not SCRIPT.is_file() or not (ROOT / "scripts" / "serve").is_file():
    pytest.skip("bench/install_size.py and scripts/ are not beside the tests",
                allow_module_level=True)

_spec = importlib.util.spec_from_file_location("install_size", SCRIPT)
assert _spec is not None and _spec.loader is not None
install_size = importlib.util.module_from_spec(_spec)
sys.modules["install_size"] = install_size  # dataclasses look their module up
_spec.loader.exec_module(install_size)


def _du_bytes(path: Path) -> int:
    out = subprocess.run(["du", "-s", "-B1", str(path)], capture_output=True, text=True,
                         check=True).stdout
    return int(out.split()[0])


def test_measure_counts_like_du_and_attributes_record_files(tmp_path):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    site = next((venv / "lib").glob("python3*/site-packages"))
    # A distribution of two files (one 100 kB, one hard link to it, counted once), its
    # metadata, and a file no RECORD names.
    pkg = site / "fakepkg"
    pkg.mkdir()
    (pkg / "data.bin").write_bytes(os.urandom(100_000))
    os.link(pkg / "data.bin", pkg / "same.bin")
    dist = site / "fakepkg-1.2.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: fakepkg\nVersion: 1.2\n")
    (dist / "RECORD").write_text("fakepkg/data.bin,,\nfakepkg/same.bin,,\n"
                                 "fakepkg-1.2.dist-info/METADATA,,\n"
                                 "fakepkg-1.2.dist-info/RECORD,,\n")
    (site / "stray.bin").write_bytes(os.urandom(50_000))

    m = install_size.measure(venv)
    assert m.total_bytes == _du_bytes(venv)
    (fake,) = [p for p in m.packages if p.name == "fakepkg"]
    assert fake.version == "1.2"
    blocks = os.stat(pkg / "data.bin").st_blocks * 512
    meta = sum(os.stat(dist / f).st_blocks * 512 for f in ("METADATA", "RECORD"))
    assert fake.bytes == blocks + meta  # the hard link once
    assert m.other_bytes == m.total_bytes - sum(p.bytes for p in m.packages)
    assert m.other_bytes >= os.stat(site / "stray.bin").st_blocks * 512

    text = install_size.report(m, "t", max_mib=1e-3, note="n")
    assert "ABOVE the bound" in text and "| fakepkg | 1.2 |" in text


def test_the_script_fails_above_its_bound(tmp_path):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    run = [sys.executable, str(SCRIPT), "--measure", str(venv), "--no-write"]
    assert subprocess.run([*run, "--max-mib", "1000"], capture_output=True).returncode == 0
    low = subprocess.run([*run, "--max-mib", "0.001"], capture_output=True, text=True)
    assert low.returncode == 1 and "above the bound" in low.stderr


@pytest.mark.slow
@pytest.mark.skipif(os.environ.get("SHADOWMAP_INSTALL_SIZE_TEST") != "1",
                    reason="downloads the service's install; set SHADOWMAP_INSTALL_SIZE_TEST=1 "
                           "(CI checks the runtime image's virtualenv in scripts/container-test)")
def test_the_serve_install_is_within_the_bound(tmp_path):
    out = tmp_path / "install_size.md"
    proc = subprocess.run([sys.executable, str(SCRIPT), "--out", str(out)],
                          capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "within the bound" in out.read_text()
