"""`compd health [--url URL] [--state-dir DIR] [--max-age-s S]`: is the daemon healthy?

For container health checks and monitoring scripts. Exit 0 when healthy, 1
otherwise, with one line saying why. Healthy means either

* the metrics endpoint (``--url http://127.0.0.1:PORT/metrics``) answers and
  shows at least one complete cycle (``compd_cycle_seconds_count`` > 0), a
  fault state other than 3 (alarm/stopped), and, when the daemon exports
  ``compd_last_cycle_timestamp_seconds``, a last cycle within ``--max-age-s``; or
* the state directory holds evidence of a recent cycle: the checkpoint's
  ``saved_wall_s`` or the modification time of the sample recorder's files,
  whichever is newest, within ``--max-age-s``.

With both given, either one suffices (the report names both). With neither,
the state directory is ``$STATE_DIRECTORY`` (set by systemd) or
``/var/lib/compd``. Only the standard library is imported: a health check runs
every few seconds and must stay cheap.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

from compd.core.faults import GAUGE_ALARM

HELP = "exit 0 when the running daemon is healthy (metrics endpoint or fresh state), else 1"

DEFAULT_STATE_DIR = Path("/var/lib/compd")
#: Files in the state dir that say nothing about cycles completing.
IGNORED = frozenset({"compd.lock"})
CHECKPOINT_NAME = "checkpoint.json"
#: Read at most this much of a checkpoint (it holds delay lines, not records).
MAX_CHECKPOINT_BYTES = 16 * 1024 * 1024
FAULT_STOPPED = float(GAUGE_ALARM)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--url", metavar="URL",
                        help="the daemon's metrics endpoint, e.g. http://127.0.0.1:9105/metrics")
    parser.add_argument("--state-dir", metavar="DIR", type=Path,
                        help="the daemon's state directory ([state] dir); default "
                             "$STATE_DIRECTORY or /var/lib/compd when --url is not given")
    parser.add_argument("--max-age-s", metavar="S", type=float, default=180.0,
                        help="the newest evidence of a cycle may be this old (default 180; "
                             "above checkpoint_every × period_s / time_scale)")
    parser.add_argument("--timeout-s", metavar="S", type=float, default=5.0,
                        help="how long to wait for the metrics endpoint (default 5)")


# -- metrics endpoint ------------------------------------------------------------------


def parse_metrics(text: str) -> dict[str, float]:
    """Prometheus text exposition -> {sample name: value}, summed over labels."""
    out: dict[str, float] = {}
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        if "{" in line:
            name, _, rest = line.partition("{")
            _, _, rest = rest.rpartition("}")
        else:
            name, _, rest = line.partition(" ")
        fields = rest.split()
        if not fields:
            continue
        try:
            value = float(fields[0])
        except ValueError:
            continue
        out[name] = out.get(name, 0.0) + value
    return out


def check_metrics(url: str, max_age_s: float, timeout_s: float,
                  now_wall_s: float) -> tuple[bool, str]:
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as resp:
            body = resp.read(8 * 1024 * 1024).decode("utf-8", "replace")
    except urllib.error.HTTPError as exc:
        return False, f"metrics {url}: HTTP {exc.code}"
    except (urllib.error.URLError, OSError, ValueError) as exc:
        reason = getattr(exc, "reason", exc)
        return False, f"metrics {url}: {reason}"
    metrics = parse_metrics(body)
    cycles = metrics.get("compd_cycle_seconds_count")
    if cycles is None:
        return False, f"metrics {url}: no compd_cycle_seconds_count (not a compd endpoint?)"
    if cycles < 1:
        return False, f"metrics {url}: no complete cycle yet"
    fault = metrics.get("compd_fault_state")
    if fault is not None and fault >= FAULT_STOPPED:
        return False, f"metrics {url}: fault state {fault:g} (alarm/stopped)"
    last = metrics.get("compd_last_cycle_timestamp_seconds")
    if last is not None:
        age_s = max(0.0, now_wall_s - last)
        if not age_s <= max_age_s:
            return False, (f"metrics {url}: last complete cycle {age_s:.0f} s ago "
                           f"(max {max_age_s:g} s)")
        return True, f"metrics: {cycles:.0f} cycles, last {age_s:.0f} s ago"
    return True, f"metrics: {cycles:.0f} cycles complete"


# -- state directory ---------------------------------------------------------------------


def _checkpoint_wall_s(path: Path) -> float | None:
    """`saved_wall_s` of a checkpoint, None when it cannot be read or trusted."""
    try:
        with path.open("rb") as f:
            data = json.loads(f.read(MAX_CHECKPOINT_BYTES))
    except (OSError, ValueError):
        return None
    saved = data.get("saved_wall_s") if isinstance(data, dict) else None
    if isinstance(saved, int | float) and math.isfinite(saved):
        return float(saved)
    return None


def check_state_dir(state_dir: Path, max_age_s: float, now_wall_s: float) -> tuple[bool, str]:
    if not state_dir.is_dir():
        return False, f"state dir {state_dir}: not a directory"
    newest: tuple[float, str] | None = None
    try:
        entries = list(os.scandir(state_dir))
    except OSError as exc:
        return False, f"state dir {state_dir}: {exc.strerror or exc}"
    for entry in entries:
        if entry.name in IGNORED or entry.name.startswith(".") or not entry.is_file():
            continue
        if entry.name == CHECKPOINT_NAME:
            wall_s = _checkpoint_wall_s(Path(entry.path))
            what = "checkpoint saved"
            if wall_s is None:
                continue  # a torn checkpoint proves nothing
        else:
            try:
                wall_s = entry.stat().st_mtime
            except OSError:
                continue
            what = f"{entry.name} written"
        if newest is None or wall_s > newest[0]:
            newest = (wall_s, what)
    if newest is None:
        return False, f"state dir {state_dir}: no checkpoint or record yet"
    age_s = max(0.0, now_wall_s - newest[0])
    if not age_s <= max_age_s:
        return False, (f"state dir {state_dir}: newest {newest[1]} {age_s:.0f} s ago "
                       f"(max {max_age_s:g} s)")
    return True, f"state dir: {newest[1]} {age_s:.0f} s ago"


def run(args: argparse.Namespace) -> int:
    max_age_s: float = args.max_age_s
    if not (math.isfinite(max_age_s) and max_age_s > 0):
        print("unhealthy: --max-age-s must be a positive number")
        return 1
    state_dir: Path | None = args.state_dir
    if state_dir is None and args.url is None:
        state_dir = Path(os.environ.get("STATE_DIRECTORY", "").split(":")[0]
                         or DEFAULT_STATE_DIR)
    now_wall_s = time.time()
    results: list[tuple[bool, str]] = []
    if args.url is not None:
        results.append(check_metrics(args.url, max_age_s, args.timeout_s, now_wall_s))
    if state_dir is not None:
        results.append(check_state_dir(state_dir, max_age_s, now_wall_s))
    healthy = any(ok for ok, _ in results)
    print(("healthy: " if healthy else "unhealthy: ") + "; ".join(msg for _, msg in results))
    sys.stdout.flush()
    return 0 if healthy else 1
