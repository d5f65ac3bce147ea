"""A re-zero asked for through the state directory (`compd rezero`).

Why the state directory: it is the one channel to the running daemon that
already carries an authorisation and needs no new listener. The directory
is the daemon's own (0700, `compd.runtime.statedir`): only the daemon's user
and root can put a file in it, so the operating system decides who may
re-zero, as it decides who may read the checkpoint. The HTTP face has no
authentication and serves read-only pages (a write there would be open to
whoever reaches the port); a signal carries neither who sent it nor an
answer, and SIGUSR1 from a stray ``kill`` would move the offset.

`compd rezero` writes ``rezero.request`` (JSON: who, when, an id) by a
temporary name and a rename; the daemon looks for it before every cycle
(`RezeroRequests.take`: one ``openat`` that usually finds nothing), accepts
only a regular file of one name owned by its own user or root, at most
`MAX_BYTES`, written within `MAX_AGE_S` (a request left behind by a killed
`compd rezero` never re-zeroes days later), removes it, and applies the
re-zero at the start of the cycle; the checkpoint written at once names the
request (``zero.by``), which is how `compd rezero` learns that it was
applied.
"""

from __future__ import annotations

import contextlib
import json
import os
import stat

from compd.runtime.statedir import StateDir

__all__ = ["MAX_BYTES", "REQUEST_NAME", "RezeroRequests", "describe_request"]

REQUEST_NAME = "rezero.request"
#: a request is a few fields of JSON
MAX_BYTES = 4096
#: a request older than this (wall seconds; `compd rezero` left it behind when it was
#: killed) is refused: a re-zero is for the tool touched off now, not last week
MAX_AGE_S = 120.0


def describe_request(doc: object, uid: int) -> str | None:
    """The audit text of a request (`by` of the zero), None when it is not one."""
    if not isinstance(doc, dict):
        return None
    user, rid = doc.get("user"), doc.get("id")
    if not (isinstance(user, str) and isinstance(rid, str) and 0 < len(user) <= 64
            and 0 < len(rid) <= 64 and rid.isalnum() and user.isprintable()):
        return None
    return f"compd rezero: {user} (uid {uid}, request {rid})"


def _stale(doc: object, now_wall_s: float) -> bool:
    wall = doc.get("wall_s") if isinstance(doc, dict) else None
    return not isinstance(wall, int | float) or abs(now_wall_s - wall) > MAX_AGE_S


class RezeroRequests:
    """The daemon's side (see the module docstring)."""

    def __init__(self, directory: StateDir | None) -> None:
        self.directory = directory
        #: why the last file found was refused (for the log), None: none refused
        self.refused: str | None = None

    def take(self, now_wall_s: float) -> str | None:
        """The audit text of a request waiting in the state directory (removed),
        None when there is none; a file that is no request is removed and
        `refused` says why."""
        d = self.directory
        if d is None or d.fd is None:
            return None
        try:
            fd = os.open(REQUEST_NAME, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC
                         | os.O_NONBLOCK, dir_fd=d.fd)
        except FileNotFoundError:
            return None
        except OSError as exc:
            return self._refuse(f"cannot open it: {exc.strerror or exc}")
        try:
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode) or st.st_nlink != 1:
                return self._refuse("not a regular file of one name")
            if st.st_uid not in (os.geteuid(), 0):
                return self._refuse(f"owned by uid {st.st_uid}, neither compd's user nor root")
            data = os.read(fd, MAX_BYTES + 1)
            if len(data) > MAX_BYTES:
                return self._refuse(f"larger than {MAX_BYTES} bytes")
            try:
                doc = json.loads(data)
            except ValueError:
                return self._refuse("not JSON")
            who = describe_request(doc, st.st_uid)
            if who is None:
                return self._refuse("not a re-zero request (user, id)")
            if _stale(doc, now_wall_s):
                return self._refuse(f"{who}: older than {MAX_AGE_S:g} s, or no time")
            self._remove()
            return who
        finally:
            os.close(fd)

    def _refuse(self, reason: str) -> str | None:
        """Remove the file that is no request; None (no re-zero), `refused` says why."""
        self.refused = reason
        self._remove()
        return None

    def _remove(self) -> None:
        if self.directory is not None:
            with contextlib.suppress(OSError):
                self.directory.unlink(REQUEST_NAME)
