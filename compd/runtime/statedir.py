"""The state directory and the files compd creates in it, opened so that a
planted link or a loose permission cannot turn the daemon against the host.

The daemon often runs as root (or as a DynamicUser whose state directory a
privileged user can reach), so its state directory is a target: a symbolic
link planted at ``compd.lock`` made the lock truncate the file it pointed at,
and one at the checkpoint's temporary name made the checkpoint overwrite it.

- `prepare_state_dir` creates the directory 0700 (whatever the umask) and
  refuses one that is not a directory, is owned by another user, or is
  writable by group or others. The directory itself may be reached through a
  link (systemd's ``DynamicUser=`` makes ``/var/lib/compd`` a link into
  ``/var/lib/private``); what counts is the directory it resolves to.
- `open_private` opens a file inside it with ``O_NOFOLLOW`` (a link is
  refused, never followed), creates it 0600, and refuses anything but a
  regular file of ours with one name (a planted hard link is refused too).
  A link as the state directory itself must belong to root or to us.
- `refuse_link` checks a path compd is about to hand to a library that opens
  it by name (SQLite): it must not be a link or a non-regular file.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from compd.errors import CompdError

__all__ = ["StateDirError", "open_private", "prepare_state_dir", "refuse_link"]


class StateDirError(CompdError):
    """The state directory or a file in it cannot be used safely. `path`, `reason`."""

    def __init__(self, path: Path, reason: str) -> None:
        self.path = path
        self.reason = reason
        super().__init__(f"{path}: {reason}")


def prepare_state_dir(path: Path) -> None:
    """Create `path` (mode 0700) if missing; refuse it when it is not safe to use."""
    path = Path(path)
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
    except FileExistsError:
        raise StateDirError(path, "state directory is not a directory") from None
    except OSError as exc:
        raise StateDirError(path, f"cannot create the state directory: "
                                  f"{exc.strerror or exc}") from exc
    try:
        lst = os.lstat(path)
        st = os.stat(path)
    except OSError as exc:
        raise StateDirError(path, f"cannot read the state directory: "
                                  f"{exc.strerror or exc}") from exc
    euid = os.geteuid()
    if stat.S_ISLNK(lst.st_mode) and lst.st_uid not in (0, euid):
        # systemd's link is root's; one another user made could point anywhere
        raise StateDirError(path, f"state directory is a link owned by uid {lst.st_uid}, "
                                  "neither root nor this process")
    if not stat.S_ISDIR(st.st_mode):
        raise StateDirError(path, "state directory is not a directory")
    if st.st_uid != euid:
        raise StateDirError(path, f"state directory is owned by uid {st.st_uid}, "
                                  f"not by this process (uid {euid})")
    if st.st_mode & 0o022:
        raise StateDirError(path, f"state directory is writable by group or others "
                                  f"(mode {stat.S_IMODE(st.st_mode):04o}); chmod 700 it")


def open_private(path: Path, flags: int, *, create: bool = True) -> int:
    """A descriptor of the regular file `path` (ours, never through a link).

    `flags` are the access flags (os.O_RDONLY, os.O_RDWR, …); ``O_NOFOLLOW``
    and ``O_CLOEXEC`` are added, and ``O_CREAT`` (mode 0600) with `create`.
    Raises StateDirError for a link, a non-regular file or another owner's
    file, FileNotFoundError when it is missing and not created, and OSError
    for what the file system refuses.
    """
    all_flags = flags | os.O_NOFOLLOW | os.O_CLOEXEC | (os.O_CREAT if create else 0)
    try:
        fd = os.open(path, all_flags, 0o600)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise StateDirError(path, "is a symbolic link; refused (not followed)") from None
        raise
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise StateDirError(path, "is not a regular file; refused")
        if st.st_uid != os.geteuid():
            raise StateDirError(path, f"is owned by uid {st.st_uid}, not by this process")
        if st.st_nlink != 1:  # a hard link planted to another file: truncating it hurts that
            raise StateDirError(path, f"has {st.st_nlink} hard links; refused")
    except BaseException:
        os.close(fd)
        raise
    return fd


def refuse_link(path: Path) -> None:
    """Raise StateDirError when `path` exists as a link or a non-regular file."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if stat.S_ISLNK(st.st_mode):
        raise StateDirError(path, "is a symbolic link; refused (not followed)")
    if not stat.S_ISREG(st.st_mode):
        raise StateDirError(path, "is not a regular file; refused")
