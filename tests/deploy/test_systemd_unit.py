"""deploy/systemd/compd.service: systemd's own analyser accepts and scores it,
it holds the sandbox the design asks for, and compd still works inside its system call
filter (applied here with libseccomp, since this machine runs no systemd)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from compd.errors import EX_CONFIG

REPO = Path(__file__).resolve().parents[2]
UNIT = REPO / "deploy" / "systemd" / "compd.service"
HERE = Path(__file__).resolve().parent
#: systemd-analyze security: 0-1 SAFE, 1-2 OK, above that MEDIUM/EXPOSED/UNSAFE
MAX_EXPOSURE = 2.0

ANALYZE = shutil.which("systemd-analyze")
needs_analyze = pytest.mark.skipif(
    ANALYZE is None,
    reason="systemd-analyze not found (Debian package `systemd`; .ci/run installs it)")


def parse_unit(text: str) -> dict[str, dict[str, list[str]]]:
    """Section -> key -> every value in order (systemd keys repeat)."""
    sections: dict[str, dict[str, list[str]]] = {}
    current: dict[str, list[str]] | None = None
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], {})
            continue
        if current is None or "=" not in line:
            raise ValueError(f"not a unit line: {raw!r}")
        key, _, value = line.partition("=")
        current.setdefault(key.strip(), []).append(value.strip())
    return sections


@pytest.fixture(scope="module")
def service() -> dict[str, list[str]]:
    return parse_unit(UNIT.read_text())["Service"]


def _one(service: dict[str, list[str]], key: str) -> str:
    values = service.get(key)
    if values is None or len(values) != 1:
        pytest.fail(f"{key}= should appear exactly once, found {values}")
    return values[0]


def _testable_copy(tmp_path: Path, extra: str = "") -> Path:
    """The unit with ExecStart pointing at this venv's compd (verify checks that
    the executable exists), plus `extra` lines appended to [Service]."""
    compd = Path(sys.executable).parent / "compd"
    if not compd.exists():
        pytest.fail(f"{compd} missing: install the project into the venv (pip install -e .)")
    text = UNIT.read_text()
    text, n = re.subn(r"^ExecStart=/usr/local/bin/compd ", f"ExecStart={compd} ", text,
                      flags=re.MULTILINE)
    if n != 1:
        pytest.fail("ExecStart=/usr/local/bin/compd ... not found exactly once")
    if extra:
        text = text.replace("\n[Install]", f"{extra}\n\n[Install]")
    out = tmp_path / "compd.service"
    out.write_text(text)
    return out


def _verify(unit: Path) -> list[str]:
    """systemd-analyze verify: exit status 0 and no complaint about this unit."""
    if ANALYZE is None:
        pytest.skip("systemd-analyze not found")
    proc = subprocess.run([ANALYZE, "verify", str(unit)], capture_output=True, text=True,
                          timeout=60, check=False)
    complaints = [line for line in (proc.stdout + proc.stderr).splitlines()
                  if unit.name in line or str(unit) in line]
    if proc.returncode != 0:
        complaints.append(f"exit status {proc.returncode}: {proc.stderr.strip()}")
    return complaints


# -- what the unit says ----------------------------------------------------------


def test_service_type_watchdog_and_restart_policy(service: dict[str, list[str]]) -> None:
    assert _one(service, "Type") == "notify"
    assert _one(service, "NotifyAccess") == "main"
    assert _one(service, "WatchdogSec") == "10s"
    assert _one(service, "Restart") == "on-failure"
    assert _one(service, "RestartSec")
    # a bad config exits EX_CONFIG and must not restart-loop
    assert str(EX_CONFIG) in _one(service, "RestartPreventExitStatus").split()
    assert _one(service, "ExecStart") == "/usr/local/bin/compd run /etc/compd/compd.toml"
    # systemctl reload: SIGHUP, which compd serves as a reload (tests/compd/runtime/test_reload.py)
    assert _one(service, "ExecReload") == "/bin/kill -HUP $MAINPID"


def test_identity_state_config_and_credentials(service: dict[str, list[str]]) -> None:
    assert _one(service, "DynamicUser") == "yes"
    assert _one(service, "StateDirectory") == "compd"
    assert _one(service, "StateDirectoryMode") == "0700"
    assert _one(service, "ConfigurationDirectory") == "compd"
    assert _one(service, "UMask") == "0077"
    assert ("controller-password:/etc/compd/credentials/controller-password"
            in service["LoadCredential"])


def test_hardening_settings(service: dict[str, list[str]]) -> None:
    expected = {
        "ProtectSystem": "strict", "ProtectHome": "yes", "PrivateTmp": "yes",
        "PrivateDevices": "yes", "NoNewPrivileges": "yes", "CapabilityBoundingSet": "",
        "AmbientCapabilities": "", "RestrictAddressFamilies": "AF_INET AF_INET6 AF_UNIX",
        "SystemCallArchitectures": "native", "ProtectKernelTunables": "yes",
        "ProtectKernelModules": "yes", "ProtectKernelLogs": "yes",
        "ProtectControlGroups": "yes", "ProtectClock": "yes", "ProtectHostname": "yes",
        "ProtectProc": "invisible", "ProcSubset": "pid", "RestrictNamespaces": "yes",
        "RestrictRealtime": "yes", "RestrictSUIDSGID": "yes", "LockPersonality": "yes",
        "MemoryDenyWriteExecute": "yes", "PrivateUsers": "yes", "RemoveIPC": "yes",
        "DevicePolicy": "closed", "IPAddressDeny": "any",
        # a denied call fails with EPERM instead of killing the daemon (see below)
        "SystemCallErrorNumber": "EPERM",
    }
    got = {key: _one(service, key) for key in expected}
    assert got == expected
    assert service["SystemCallFilter"] == ["@system-service", "~@privileged @resources"]
    assert service["IPAddressAllow"] == ["localhost"]
    assert "#IPAddressAllow=192.168.0.10" in UNIT.read_text()
    assert _one(service, "MemoryMax") and _one(service, "TasksMax")


# -- systemd's analyser -------------------------------------------------------------


@needs_analyze
def test_systemd_analyze_verify_accepts_the_unit(tmp_path: Path) -> None:
    assert _verify(_testable_copy(tmp_path)) == []


@needs_analyze
def test_verify_check_catches_a_misspelt_key(tmp_path: Path) -> None:
    # the check above is not vacuous: verify only warns (exit 0) on unknown keys
    complaints = _verify(_testable_copy(tmp_path, extra="ProtectSystm=strict"))
    assert any("ProtectSystm" in line for line in complaints), complaints


@needs_analyze
def test_security_exposure_is_ok_or_better(tmp_path: Path) -> None:
    unit = _testable_copy(tmp_path)
    proc = subprocess.run([str(ANALYZE), "security", "--offline=yes", str(unit)],
                          capture_output=True, text=True, timeout=60, check=False)
    match = re.search(r"Overall exposure level for \S+: (\d+\.\d+) (\w+)", proc.stdout)
    if match is None:
        if "--offline" in proc.stderr or "unrecognized option" in proc.stderr:
            pytest.skip(f"systemd-analyze too old for --offline: {proc.stderr.strip()}")
        pytest.fail(f"no exposure level in the output:\n{proc.stdout}\n{proc.stderr}")
    score, level = float(match.group(1)), match.group(2)
    print(f"\nsystemd-analyze security --offline=yes compd.service: {score} {level}")
    assert score <= MAX_EXPOSURE, proc.stdout
    assert level in {"SAFE", "OK"}


# -- compd inside the unit's system call filter ---------------------------------------


def _groups(listing: str) -> dict[str, list[str]]:
    groups: dict[str, list[str]] = {}
    current: list[str] | None = None
    for line in listing.splitlines():
        if line.startswith("@"):
            current = groups.setdefault(line.strip(), [])
        elif not line.strip():
            current = None
        elif current is not None and not line.strip().startswith("#"):
            current.append(line.strip())
    return groups


def _expand(groups: dict[str, list[str]], name: str) -> set[str]:
    out: set[str] = set()
    for member in groups[name]:
        out |= _expand(groups, member) if member.startswith("@") else {member}
    return out


def allowed_syscalls(service: dict[str, list[str]]) -> set[str]:
    """The effective set of the unit's SystemCallFilter= lines (allow, then deny)."""
    if ANALYZE is None:
        pytest.skip("systemd-analyze not found")
    listing = subprocess.run([ANALYZE, "syscall-filter"], capture_output=True, text=True,
                             timeout=60, check=True).stdout
    groups = _groups(listing)
    allowed: set[str] = set()
    for value in service["SystemCallFilter"]:
        deny = value.startswith("~")
        names: set[str] = set()
        for item in value.lstrip("~").split():
            names |= _expand(groups, item) if item.startswith("@") else {item}
        allowed = allowed - names if deny else allowed | names
    return allowed


@pytest.fixture(scope="module")
def seccomp_exec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler to build the seccomp launcher")
    out = tmp_path_factory.mktemp("seccomp") / "seccomp_exec"
    proc = subprocess.run([cc, "-O2", "-Wall", "-o", str(out), str(HERE / "seccomp_exec.c"),
                           "-lseccomp"], capture_output=True, text=True, timeout=120,
                          check=False)
    if proc.returncode != 0:
        pytest.skip(f"cannot build the seccomp launcher (Debian package libseccomp-dev): "
                    f"{proc.stderr.strip()[:300]}")
    return out


def _filtered(seccomp_exec: Path, allowed_file: Path, *cmd: str,
              env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(seccomp_exec), str(allowed_file), "--mdwx", "--", *cmd],
                          capture_output=True, text=True, timeout=120, check=False,
                          cwd=REPO, env=env)


@needs_analyze
def test_compd_workload_runs_inside_the_filter_and_wx_rules(
        service: dict[str, list[str]], seccomp_exec: Path, tmp_path: Path) -> None:
    # numpy's OpenBLAS calls mbind() (@resources) and ignores its failure, and
    # SQLite fchown()s its journal when run as root: both are denied, both
    # harmless *because* the unit says SystemCallErrorNumber=EPERM (the default
    # action would kill the daemon with SIGSYS).
    allowed = allowed_syscalls(service)
    assert "mbind" not in allowed and "fsync" in allowed and "flock" in allowed
    allowed_file = tmp_path / "allowed"
    allowed_file.write_text("\n".join(sorted(allowed)) + "\n")
    state = tmp_path / "state"
    state.mkdir()
    env = dict(os.environ)
    try:
        from drivers.sim.fwlib_build import build_standin
        env["COMPD_WORKLOAD_FWLIB"] = str(build_standin())
    except RuntimeError:
        pass  # no C compiler: the workload still loads libc through ctypes
    proc = _filtered(seccomp_exec, allowed_file, sys.executable, "-m",
                     "tests.deploy.syscall_workload", str(state), env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip().endswith("workload ok")
    assert (state / "checkpoint.json").exists()

    # ...and the filter does bite: a privileged call and a W+X mapping fail.
    denied = _filtered(seccomp_exec, allowed_file, sys.executable, "-c",
                       "import os; os.setuid(os.getuid())")
    assert denied.returncode == 1 and "Operation not permitted" in denied.stderr
    wx = _filtered(seccomp_exec, allowed_file, sys.executable, "-c",
                   "import mmap; mmap.mmap(-1, 4096, prot=7)")
    assert wx.returncode == 1 and "Operation not permitted" in wx.stderr
