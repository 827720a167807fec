"""An independent API fuzzer against a real server: Schemathesis, every check, over 1,500 cases.

The server runs under uvicorn on a free localhost port with small image limits (at most 64 × 64
pixels, maps up to 256, three lights), which its OpenAPI document states as maximums, so that
every generated render is cheap on llvmpipe. Schemathesis reads the served document, generates
schema-valid and schema-violating requests from it and checks each response: no 5xx, valid
requests accepted, invalid ones refused, status codes, content types, headers and bodies as
documented. The hooks it loads (``tests/schemathesis_hooks.py``) give it valid scenes and say
which documented rules JSON Schema cannot express; their docstring lists them.

``SHADOWMAP_FUZZ_EXAMPLES`` sets the cases per operation (default 300: about 3,000 in all, 1 to
3 minutes), ``SHADOWMAP_FUZZ_SEED`` the seed.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

pytest.importorskip("schemathesis", reason="Schemathesis is not installed (the test extra has it)")

from test_page import uvicorn_server  # noqa: E402

pytestmark = [pytest.mark.gl, pytest.mark.slow]

HERE = Path(__file__).resolve().parent
#: The test server's limits, in the schema as maximums.
LIMITS = {
    "SHADOWMAP_MAX_IMAGE_SIDE": "64",
    "SHADOWMAP_MAX_PIXELS": str(64 * 64),
    "SHADOWMAP_MAX_MAP_SIZE": "256",
    "SHADOWMAP_MAX_LIGHTS": "3",
    "SHADOWMAP_QUEUE_SIZE": "32",
    "SHADOWMAP_RENDER_TIMEOUT": "60",
}
MIN_CASES = 1500


def _schemathesis() -> list[str]:
    exe = shutil.which("schemathesis", path=str(Path(sys.executable).parent))
    return [exe] if exe else [sys.executable, "-m", "schemathesis.cli"]


def test_schemathesis_finds_nothing(tmp_path):
    env = {**os.environ, **LIMITS}
    with uvicorn_server(env=env) as url:
        spec = httpx.get(url + "/openapi.json").json()
        width = spec["components"]["schemas"]["RenderParams"]["properties"]["width"]
        assert width["maximum"] == 64  # the limits are the schema's
        run_env = {**os.environ, "SCHEMATHESIS_HOOKS": "schemathesis_hooks",
                   "PYTHONPATH": os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")])}
        command = [
            *_schemathesis(), "run", f"{url}/openapi.json",
            "--checks", "all",
            "--max-examples", os.environ.get("SHADOWMAP_FUZZ_EXAMPLES", "300"),
            "--seed", os.environ.get("SHADOWMAP_FUZZ_SEED", "20261202"),
            "--workers", "1",
            "--continue-on-failure",
            "--generation-database", "none",
            "--request-timeout", "60",
            "--no-color",
            "--report", "json", "--report-dir", str(tmp_path),
        ]
        t0 = time.monotonic()
        proc = subprocess.run(command, env=run_env, cwd=tmp_path, capture_output=True,
                              text=True, timeout=900)
        seconds = time.monotonic() - t0
    reports = list(tmp_path.glob("json-*.json"))
    assert reports, proc.stdout[-4000:] + proc.stderr[-4000:]
    report = json.loads(reports[0].read_text())
    cases = report["test_cases"]
    print(f"schemathesis: {cases['generated']} cases, {cases['with_failures']} with failures, "
          f"{len(report['errors'])} errors, {seconds:.0f} s")
    assert not report["failures"] and not report["errors"] and proc.returncode == 0, (
        proc.stdout[-12000:])
    assert cases["generated"] >= MIN_CASES
    # The renderer was reached, not only the refusals: most operations answered 2xx.
    accepted = sum(phase["accepted"] for phase in report["valid_rates"]["POST /render"].values())
    assert accepted >= 200, report["valid_rates"]
