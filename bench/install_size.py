"""Install size of the service: what ``bash scripts/serve`` puts into a fresh virtualenv.

By default it builds a throwaway virtualenv exactly as ``scripts/serve`` does (``scripts/bootstrap``
with ``SHADOWMAP_VENV_DIR`` pointing at a temporary folder: ``python3 -m venv``, the setuptools it
seeds removed, then ``pip install -e ".[server]"``), checks that ``shadowmap serve --help`` runs
from it, measures it, removes it, and writes bench/results/install_size.md. ``--measure VENV``
measures an existing virtualenv instead (scripts/container-test measures the runtime image's
/opt/venv this way).

The total is the disk usage of the whole virtualenv, counted as ``du -s`` does (allocated blocks,
each hard-linked file once); each distribution's share is the disk usage of the files its
``RECORD`` lists (its byte-code included); the rest (the interpreter's links, the folders
themselves) is one line. Exits with status 1 when the total is above ``--max-mib`` (default 259
MiB: half of the 518 MiB that the service's install once took with the test and benchmark tools).

Only the standard library is used, so it also runs inside the runtime image, without the repository.

Run: ``python3 bench/install_size.py`` (a minute or two: pip downloads every wheel) or
``python3 bench/install_size.py --measure .venv --no-write``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_MAX_MIB = 259.0
MIB = 1 << 20

# Run by the measured virtualenv's own interpreter: every installed distribution with the files
# of its RECORD, as absolute paths.
_LIST_DISTRIBUTIONS = r"""
import json, sys
from importlib import metadata
out = []
for dist in metadata.distributions():
    files = [str(dist.locate_file(f)) for f in (dist.files or [])]
    out.append({"name": dist.metadata["Name"], "version": dist.version, "files": files})
json.dump({"python": sys.version.split()[0], "distributions": out}, sys.stdout)
"""


@dataclass
class Package:
    """One installed distribution and the disk usage of its files."""

    name: str
    version: str
    bytes: int


@dataclass
class Measurement:
    """Disk usage of one virtualenv.

    Attributes
    ----------
    total_bytes : int
        Allocated bytes of everything under the virtualenv, each inode once (``du -s``).
    packages : list of Package
        Installed distributions, largest first.
    other_bytes : int
        What no distribution's RECORD lists (interpreter links, folders, stray caches).
    python : str
        The virtualenv's Python version.
    """

    total_bytes: int
    packages: list[Package] = field(default_factory=list)
    other_bytes: int = 0
    python: str = ""

    def mib(self) -> float:
        """The total in MiB."""
        return self.total_bytes / MIB


def _disk_usage(st: os.stat_result) -> int:
    """Allocated bytes of one file, as du counts them (st_blocks is in 512-byte units)."""
    return st.st_blocks * 512


def measure(venv: Path) -> Measurement:
    """Measure a virtualenv.

    Parameters
    ----------
    venv : Path
        The virtualenv's folder (its ``bin/python`` lists the installed distributions).

    Returns
    -------
    Measurement

    Raises
    ------
    FileNotFoundError
        ``venv`` has no ``bin/python``.
    """
    python = venv / "bin" / "python"
    if not python.exists():
        raise FileNotFoundError(f"{venv} is not a virtualenv (no bin/python)")
    root = os.path.realpath(venv)
    # The folder itself, then everything under it; os.walk does not descend into symbolic
    # links (a venv's lib64 -> lib), which count as the links they are, like du.
    st = os.lstat(root)
    seen: set[tuple[int, int]] = {(st.st_dev, st.st_ino)}
    total = _disk_usage(st)
    usage: dict[str, int] = {}  # path of each file under the venv -> its disk usage
    for dirpath, dirnames, filenames in os.walk(root):
        for name in (*dirnames, *filenames):
            path = os.path.join(dirpath, name)
            st = os.lstat(path)
            if (st.st_dev, st.st_ino) in seen:
                continue
            seen.add((st.st_dev, st.st_ino))
            total += _disk_usage(st)
            usage[path] = _disk_usage(st)

    listing = json.loads(subprocess.run([str(python), "-I", "-c", _LIST_DISTRIBUTIONS],
                                        capture_output=True, text=True, check=True,
                                        timeout=120).stdout)
    packages: list[Package] = []
    counted: set[str] = set()
    for dist in listing["distributions"]:
        size = 0
        for f in dist["files"]:
            # Folders resolved the way the walk above saw them; the file name kept, so that a
            # RECORD entry that is a link counts as the link.
            f = os.path.normpath(f)
            path = os.path.join(os.path.realpath(os.path.dirname(f)), os.path.basename(f))
            if path in usage and path not in counted:  # files outside the venv are not counted
                counted.add(path)
                size += usage[path]
        packages.append(Package(dist["name"], dist["version"], size))
    packages.sort(key=lambda p: (-p.bytes, p.name.lower()))
    return Measurement(total, packages, total - sum(p.bytes for p in packages),
                       listing["python"])


def build_serve_venv(venv: Path) -> float:
    """Make ``venv`` the way ``bash scripts/serve`` makes .venv; returns the seconds it took.

    ``scripts/serve --help`` runs scripts/bootstrap (system packages checked, the virtualenv
    created, ``pip install -e ".[server]"``) and then ``shadowmap serve --help`` from the new
    virtualenv, so the install is also checked to start.
    """
    env = {k: v for k, v in os.environ.items()
           if k not in ("SHADOWMAP_EXTRAS", "SHADOWMAP_DRY_RUN")}
    env["SHADOWMAP_VENV_DIR"] = str(venv)
    t = time.perf_counter()
    proc = subprocess.run(["bash", str(ROOT / "scripts" / "serve"), "--help"], env=env,
                          capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0 or "--port" not in proc.stdout:
        sys.stderr.write(proc.stdout[-4000:] + proc.stderr[-4000:])
        raise SystemExit("install_size: `bash scripts/serve --help` failed "
                         f"(exit {proc.returncode})")
    return time.perf_counter() - t


def report(m: Measurement, title: str, max_mib: float, note: str) -> str:
    """The Markdown report: the total against the bound, then every distribution."""
    verdict = "within" if m.mib() <= max_mib else "ABOVE"
    lines = [
        f"# {title}",
        "",
        f"Total: **{m.mib():.1f} MiB** ({m.total_bytes:,} bytes, counted as `du -s`), "
        f"{verdict} the bound of {max_mib:g} MiB; {len(m.packages)} distributions, Python "
        f"{m.python}.",
        "",
        "| distribution | version | MiB | share |",
        "| :--- | :--- | ---: | ---: |",
    ]
    for p in m.packages:
        lines.append(f"| {p.name} | {p.version} | {p.bytes / MIB:.1f} | "
                     f"{100 * p.bytes / m.total_bytes:.1f} % |")
    lines.append(f"| (not in any RECORD: interpreter links, folders) | | "
                 f"{m.other_bytes / MIB:.1f} | {100 * m.other_bytes / m.total_bytes:.1f} % |")
    lines += ["", note]
    return "\n".join(lines) + "\n"


def _code_state() -> str:
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                              capture_output=True, text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "pyproject.toml"], cwd=ROOT,
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "commit unknown"
    dirty_note = " + uncommitted changes in pyproject.toml" if dirty else ""
    return f"commit {head or 'unknown'}{dirty_note}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--measure", type=Path, metavar="VENV",
                    help="measure this existing virtualenv instead of building the serve one")
    ap.add_argument("--max-mib", type=float, default=DEFAULT_MAX_MIB,
                    help=f"fail (exit 1) above this total (default {DEFAULT_MAX_MIB:g})")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "install_size.md",
                    help="Markdown report to write (default bench/results/install_size.md)")
    ap.add_argument("--no-write", action="store_true", help="print the report only")
    ap.add_argument("--keep", type=Path, metavar="DIR",
                    help="build the serve virtualenv in DIR (must not exist) and keep it")
    args = ap.parse_args(argv)

    if args.measure is not None:
        m = measure(args.measure)
        title = f"Install size of {args.measure}"
        note = f"Measured by `bench/install_size.py --measure {args.measure}`."
    else:
        tmp = None
        if args.keep is not None:
            if args.keep.exists():
                ap.error(f"--keep {args.keep}: already exists")
            venv = args.keep.resolve()
        else:
            tmp = Path(tempfile.mkdtemp(prefix="shadowmap-install-size."))
            venv = tmp / "venv"
        try:
            seconds = build_serve_venv(venv)
            m = measure(venv)
        finally:
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)
        title = "Install size of the service (`bash scripts/serve`)"
        note = (f"A fresh virtualenv made as `bash scripts/serve` makes .venv (`python3 -m venv`, "
                f"the setuptools it seeds removed, then `pip install -e \".[server]\"`; built "
                f"in {seconds:.0f} s, `shadowmap serve --help` checked to run), measured by "
                f"`bench/install_size.py`; {platform.system()} {platform.machine()}, "
                f"{_code_state()}.")
    text = report(m, title, args.max_mib, note)
    sys.stdout.write(text)
    if not args.no_write:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
        print(f"wrote {args.out}", file=sys.stderr)
    if m.mib() > args.max_mib:
        print(f"install_size: {m.mib():.1f} MiB is above the bound of {args.max_mib:g} MiB",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
