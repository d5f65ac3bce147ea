"""deploy/container: the lock file and the Containerfile's promises (always), and
(COMPD_CONTAINER_TEST=1) a real build with Debian's buildah plus runs inside
the image: `compd check`, the daemon against a simulated controller judged by
`compd health`, a short `compd demo`, and no writes outside the state
volume and /tmp.

No registry is reachable here: when python:3.11-slim cannot be pulled, the base
is a Debian bookworm root file system made with debootstrap (python3 and
python3-venv from Debian), cached in ~/.cache/compd-container. The Python
packages come from a wheelhouse downloaded on the host by its pip (same
versions as requirements.lock), mounted into the build with an /etc/pip.conf
that says no-index: the documented offline build (README.md).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest

from drivers.sim.ports import free_tcp_port

REPO = Path(__file__).resolve().parents[2]
CONTAINER_DIR = REPO / "deploy" / "container"
CONTAINERFILE = CONTAINER_DIR / "Containerfile"
LOCK = CONTAINER_DIR / "requirements.lock"
CACHE = Path(os.environ.get("COMPD_CONTAINER_CACHE",
                            Path.home() / ".cache" / "compd-container"))
LOCAL_BASE = "localhost/compd-base:bookworm"
IMAGE = "localhost/compd:test"
CONTEXT_PARTS = ("pyproject.toml", "README.md", "compd", "drivers", "models",
                 "deploy/container")


# -- always: the lock file and the Containerfile --------------------------------------


def _lock_entries() -> dict[str, str]:
    from packaging.utils import canonicalize_name

    entries: dict[str, str] = {}
    for line in LOCK.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, sep, version = line.partition("==")
            assert sep, f"not pinned: {line!r}"
            entries[canonicalize_name(name)] = version
    return entries


def test_lock_holds_exactly_the_runtime_closure() -> None:
    """The lock names every runtime dependency and what they pull in, and no dev tool.

    What the lock promises is a closed, consistent set for `pip install --no-deps`;
    not that it equals whatever an unpinned install resolved today (an upstream
    patch release the day after would turn a fresh clone red).
    """
    sys.path.insert(0, str(CONTAINER_DIR))
    try:
        import lock_requirements
    finally:
        sys.path.remove(str(CONTAINER_DIR))
    entries = _lock_entries()
    closure = lock_requirements.runtime_closure()
    assert set(entries) == closure
    for dev_tool in ("pytest", "hypothesis", "ruff", "mypy", "matplotlib", "import-linter"):
        assert dev_tool not in entries


def test_locked_versions_satisfy_each_other() -> None:
    """Each locked package's own requirements are met by the other locked versions.

    A package's requirements are read from its installed metadata, so only the
    packages installed here at their locked version can be checked; a newer patch
    release installed beside an older lock is not a failure of the lock.
    """
    import importlib.metadata as md

    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    entries = _lock_entries()
    checked = 0
    for name, version in entries.items():
        try:
            installed = md.version(name)
        except md.PackageNotFoundError:
            continue
        if installed != version:
            continue
        checked += 1
        for line in md.requires(name) or []:
            req = Requirement(line)
            if req.marker is not None and not req.marker.evaluate({"extra": ""}):
                continue
            dep = canonicalize_name(req.name)
            assert dep in entries, f"{name}=={version} requires {req}, not in the lock"
            assert req.specifier.contains(entries[dep], prereleases=True), \
                f"{name}=={version} requires {req}; the lock has {dep}=={entries[dep]}"
    assert checked > 0, "no locked package is installed at its pin"


def test_lock_satisfies_the_pyproject_ranges() -> None:
    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    entries = _lock_entries()
    deps = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]
    for dep in deps:
        req = Requirement(dep)
        assert req.specifier.contains(entries[canonicalize_name(req.name)]), dep


def test_containerfile_promises() -> None:
    text = CONTAINERFILE.read_text()
    assert "ARG BASE_IMAGE=python:3.11-slim" in text
    assert "pip install --no-deps -r /src/deploy/container/requirements.lock" in text
    assert "pip install --no-deps /src" in text
    assert "USER 10001:10001" in text
    assert 'VOLUME ["/var/lib/compd"]' in text
    assert re.search(r'HEALTHCHECK .*\n?.*CMD \["compd", "health"', text)
    assert 'ENTRYPOINT ["compd"]' in text
    assert 'CMD ["run", "/etc/compd/compd.toml"]' in text


# -- COMPD_CONTAINER_TEST=1: build and run --------------------------------------------

def _run(cmd: list[str], timeout: float = 900, check: bool = True,
         **kwargs: object) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False,
                          **kwargs)  # type: ignore[call-overload]
    if check and proc.returncode != 0:
        pytest.fail(f"{' '.join(cmd[:6])}... exited {proc.returncode}:\n"
                    f"{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    result: subprocess.CompletedProcess[str] = proc
    return result


def _apt_mirror() -> str:
    """The Debian mirror apt uses here (deb822 or one-line sources)."""
    sources = [Path("/etc/apt/sources.list"), *Path("/etc/apt/sources.list.d").glob("*")]
    for path in sources:
        text = path.read_text() if path.is_file() else ""
        for m in re.finditer(r"^URIs:\s*(\S+/debian)\s*$|^deb\s+(?:\[[^]]*\]\s+)?(\S+/debian)\s",
                             text, re.MULTILINE):
            return m.group(1) or m.group(2)
    return "http://deb.debian.org/debian"


def _image_exists(name: str) -> bool:
    return _run(["buildah", "images", "--quiet", name], check=False, timeout=60).returncode == 0


def _base_image(timings: dict[str, float]) -> str:
    """python:3.11-slim when it can be pulled, else a local debootstrap base."""
    forced = os.environ.get("COMPD_CONTAINER_BASE_IMAGE")
    if forced:
        return forced
    started = time.monotonic()
    pulled = _run(["buildah", "pull", "--quiet", "docker.io/library/python:3.11-slim"],
                  check=False, timeout=120)
    timings["pull_s"] = time.monotonic() - started
    if pulled.returncode == 0:
        return "docker.io/library/python:3.11-slim"
    if _image_exists(LOCAL_BASE):
        return LOCAL_BASE
    rootfs = CACHE / "rootfs-bookworm"
    if not (rootfs / "usr" / "bin" / "python3").exists():
        if shutil.which("debootstrap") is None:
            pytest.skip("python:3.11-slim cannot be pulled and debootstrap is missing "
                        "(apt-get install debootstrap)")
        started = time.monotonic()
        partial = CACHE / "rootfs-bookworm.partial"
        shutil.rmtree(partial, ignore_errors=True)
        CACHE.mkdir(parents=True, exist_ok=True)
        _run(["debootstrap", "--variant=minbase", "--include=python3,python3-venv",
              "bookworm", str(partial), _apt_mirror()], timeout=1500)
        for junk in ("var/cache/apt/archives", "var/lib/apt/lists"):
            for f in (partial / junk).glob("*"):
                if f.is_file():
                    f.unlink()
        partial.rename(rootfs)
        timings["debootstrap_s"] = time.monotonic() - started
    ctr = _run(["buildah", "from", "scratch"]).stdout.strip()
    try:
        mnt = _run(["buildah", "mount", ctr]).stdout.strip()
        _run(["cp", "-a", f"{rootfs}/.", mnt])
        _run(["buildah", "umount", ctr])
        _run(["buildah", "config", "--env",
              "PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
              "--env", "LANG=C.UTF-8", "--cmd", "/bin/sh", ctr])
        _run(["buildah", "commit", "--quiet", ctr, LOCAL_BASE])
    finally:
        _run(["buildah", "rm", ctr], check=False)
    return LOCAL_BASE


def _wheelhouse() -> Path:
    """The locked wheels plus the build backend, downloaded by the host's pip."""
    wheels = CACHE / "wheels"
    wheels.mkdir(parents=True, exist_ok=True)
    pip = [sys.executable, "-m", "pip", "download", "--quiet", "--dest", str(wheels)]
    _run([*pip, "--no-deps", "--only-binary=:all:", "-r", str(LOCK)])
    backend = tomllib.loads((REPO / "pyproject.toml").read_text())["build-system"]["requires"]
    _run([*pip, *backend])
    return wheels


def _context(tmp: Path) -> Path:
    ctx = tmp / "context"
    for part in CONTEXT_PARTS:
        src, dst = REPO / part, ctx / part
        if src.is_dir():
            shutil.copytree(src, dst, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst)
    return ctx


def _daemon_config(sim_port: int, metrics_port: int) -> str:
    """The shipped Modbus example, pointed at the in-container sim and state volume."""
    text = (REPO / "compd" / "examples" / "modbus.toml").read_text()
    subs = [(r'endpoint = "modbus://127\.0\.0\.1:\d+"',
             f'endpoint = "modbus://127.0.0.1:{sim_port}"'),
            (r'(?m)^dir = ".*"$', 'dir = "/var/lib/compd"'),
            (r"(?m)^checkpoint_every = \d+", "checkpoint_every = 5"),
            (r"(?m)^\[telemetry\]$", f"[telemetry]\nmetrics_port = {metrics_port}")]
    for pattern, repl in subs:
        text, n = re.subn(pattern, repl, text)
        if n != 1:
            pytest.fail(f"compd/examples/modbus.toml changed: {pattern!r} matched {n} times")
    return text


DAEMON_SCRIPT = """
set -u
compd sim --protocol modbus --port {sim_port} --speedup 10 > /tmp/sim.log 2>&1 &
sim=$!
compd run /etc/compd/compd.toml > /tmp/run.log 2>&1 &
run=$!
ok=1
for i in $(seq 1 120); do
  if compd health --url http://127.0.0.1:{metrics_port}/metrics --max-age-s 30 \\
       > /tmp/health.txt; then ok=0; break; fi
  sleep 0.25
done
cat /tmp/health.txt
compd health --state-dir /var/lib/compd --max-age-s 30 || ok=1
kill -TERM $run; wait $run; echo "run-exit=$?"
kill -TERM $sim; wait $sim
compd health --url http://127.0.0.1:{metrics_port}/metrics --timeout-s 2 \\
  && echo "health-after-stop=0" || echo "health-after-stop=1"
[ $ok = 0 ] || {{ tail -n 30 /tmp/run.log /tmp/sim.log; exit 1; }}
"""


@pytest.fixture(scope="module")
def buildah() -> str:
    path = shutil.which("buildah")
    if path is None:
        pytest.skip("buildah not installed (apt-get install buildah)")
    if os.geteuid() != 0:
        pytest.skip("the container test builds as root (buildah --isolation chroot)")
    return path


@pytest.fixture
def container(buildah: str, tmp_path: Path) -> Iterator[tuple[str, dict[str, float]]]:
    timings: dict[str, float] = {}
    started = time.monotonic()
    base = _base_image(timings)
    t = time.monotonic()
    wheels = _wheelhouse()
    timings["wheelhouse_s"] = time.monotonic() - t
    pip_conf = tmp_path / "pip.conf"
    pip_conf.write_text("[global]\nno-index = true\nfind-links = /wheels\n")
    ctx = _context(tmp_path)
    t = time.monotonic()
    _run([buildah, "bud", "--isolation", "chroot", "--format", "docker", "--layers=false",
          "--volume", f"{wheels}:/wheels:ro", "--volume", f"{pip_conf}:/etc/pip.conf:ro",
          "--build-arg", f"BASE_IMAGE={base}", "-f", "deploy/container/Containerfile",
          "-t", IMAGE, "."], cwd=ctx, timeout=1200)
    timings["build_s"] = time.monotonic() - t
    ctr = _run([buildah, "from", "--quiet", IMAGE]).stdout.strip()
    timings["setup_s"] = time.monotonic() - started
    try:
        yield ctr, timings
    finally:
        _run([buildah, "rm", ctr], check=False)
        _run([buildah, "rmi", IMAGE], check=False)


@pytest.mark.slow
@pytest.mark.container
@pytest.mark.timeout(1800)
@pytest.mark.skipif(os.environ.get("COMPD_CONTAINER_TEST") != "1",
                    reason="set COMPD_CONTAINER_TEST=1 to build and run the image")
def test_image_builds_and_runs_compd(container: tuple[str, dict[str, float]],
                                     tmp_path: Path) -> None:
    ctr, timings = container
    t0 = time.monotonic()
    config = json.loads(_run(["buildah", "inspect", "--type", "image", IMAGE]).stdout)
    docker_cfg = config["Docker"]["config"]
    assert docker_cfg["User"] == "10001:10001"
    assert docker_cfg["Entrypoint"] == ["compd"]
    assert docker_cfg["Cmd"] == ["run", "/etc/compd/compd.toml"]
    assert "/var/lib/compd" in docker_cfg["Volumes"]
    assert docker_cfg["Healthcheck"]["Test"][:3] == ["CMD", "compd", "health"]

    marker = time.time()
    time.sleep(1.1)  # mtime granularity: anything written from here on is newer
    run = ["buildah", "run", "--isolation", "chroot", "--mount",
           "type=tmpfs,destination=/tmp", ctr, "--"]
    checked = _run([*run, "compd", "check", "sp2"], timeout=120)
    assert "stable: yes" in checked.stdout

    whoami = _run([*run, "sh", "-c", "id -u; touch /opt/compd/x 2>/dev/null || echo ro"])
    assert whoami.stdout.split() == ["10001", "ro"]

    # the daemon against the simulated Modbus controller, config mounted read-only
    etc = tmp_path / "etc-compd"
    etc.mkdir()
    sim_port, metrics_port = free_tcp_port("127.0.0.1"), free_tcp_port("127.0.0.1")
    (etc / "compd.toml").write_text(_daemon_config(sim_port, metrics_port))
    t = time.monotonic()
    daemon = _run(["buildah", "run", "--isolation", "chroot", "--mount",
                   "type=tmpfs,destination=/tmp", "--volume", f"{etc}:/etc/compd:ro", ctr,
                   "--", "sh", "-c",
                   DAEMON_SCRIPT.format(sim_port=sim_port, metrics_port=metrics_port)],
                  timeout=300)
    timings["daemon_s"] = time.monotonic() - t
    out = daemon.stdout
    assert "healthy: metrics: " in out and "healthy: state dir: " in out, out
    assert "run-exit=0" in out and "health-after-stop=1" in out, out

    # a short demo inside the image: simulated machine + compd run, both as uid 10001
    t = time.monotonic()
    demo = _run([*run, "compd", "demo", "--protocol", "modbus", "--hours", "8",
                 "--seconds", "20", "--json"], timeout=300)
    timings["demo_s"] = time.monotonic() - t
    result = json.loads(demo.stdout.strip().splitlines()[-1])
    assert result["range_reduction"] >= 5.0, result

    # read-only root: nothing written outside the state volume and /tmp
    mnt = _run(["buildah", "mount", ctr]).stdout.strip()
    try:
        allowed = ("var/lib/compd", "tmp", "proc", "sys", "dev", "run", "etc/hosts",
                   "etc/hostname", "etc/resolv.conf")
        written = []
        for dirpath, dirnames, filenames in os.walk(mnt):
            rel_dir = os.path.relpath(dirpath, mnt)
            if rel_dir != "." and rel_dir.startswith(allowed):
                dirnames[:] = []
                continue
            for name in filenames:
                rel = os.path.normpath(os.path.join(rel_dir, name))
                if rel.startswith(allowed):
                    continue
                try:
                    if os.lstat(os.path.join(dirpath, name)).st_mtime > marker:
                        written.append(rel)
                except OSError:
                    continue
        assert written == [], f"written outside the volume and /tmp: {written[:20]}"
    finally:
        _run(["buildah", "umount", ctr], check=False)

    timings["runs_s"] = time.monotonic() - t0
    timings["total_s"] = time.monotonic() - t0 + timings["setup_s"]
    print("\ncontainer test timings: "
          + ", ".join(f"{k} {v:.1f}" for k, v in timings.items()))
