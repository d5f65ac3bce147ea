"""The state directory and the files compd creates in it, opened so that a
planted link, a loose permission or a swapped parent cannot turn the daemon
against the host.

The daemon often runs as root (or as a DynamicUser whose state directory a
privileged user can reach), so its state directory is a target: a symbolic
link planted at ``compd.lock`` would make the lock truncate the file it points
at, one at the checkpoint's temporary name would make the checkpoint overwrite
it, and a state directory under a world-writable place, whose parents compd
itself created 0777, could be renamed away and replaced by a link, so that the
root daemon would replace another directory's ``checkpoint.json``.

- `StateDir.open` walks the path one component at a time from ``/`` (each
  opened ``O_DIRECTORY | O_NOFOLLOW`` relative to the one before), creates
  the missing parents 0755 and the directory itself 0700 whatever the umask,
  and refuses (`UnsafeParent`, exit 78) a parent that another user could
  rename entries in: one owned by neither root nor this process, or writable
  by group or others without the sticky bit (OpenSSH's StrictModes; ``/tmp``
  is sticky and root's, so it is fine). The directory itself must be ours
  and not writable by group or others. A link on the way (systemd's
  ``DynamicUser=`` makes ``/var/lib/compd`` one into ``/var/lib/private``) is
  followed only when it belongs to root or to us. The directory is then held
  open: every file compd makes in it is opened, renamed, unlinked and
  stat-ed relative to that descriptor (``dir_fd``), so a later swap of the
  path moves nothing compd writes.
- `StateDir.open_file` / `open_private` open a file ``O_NOFOLLOW`` (a link is
  refused, never followed), create it 0600, and refuse anything but a regular
  file of ours with one name (a planted hard link is refused too).
- `StateDir.check_names` and `StateDir.verify` serve a library that opens
  files by name (SQLite): the names must not be links, hard links or other
  than regular files, and the path must still name the directory compd opened
  (same st_dev/st_ino).
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
from collections.abc import Iterable
from pathlib import Path

from compd.errors import CompdError
from compd.sysexits import EX_CANTCREAT, EX_CONFIG

__all__ = ["PARENT_MODE", "STATE_MODE", "StateDir", "StateDirError", "UnsafeParent",
           "open_private", "prepare_state_dir", "refuse_link"]

#: missing parents are created with this mode, the state directory with STATE_MODE
PARENT_MODE = 0o755
STATE_MODE = 0o700
#: symbolic links followed on the way to a directory (the kernel's own limit)
MAX_LINKS = 40

_DIR_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC


class StateDirError(CompdError):
    """The state directory or a file in it cannot be used safely. `path`, `reason`;
    `code` the exit status `compd run` ends with (73: cannot create safely)."""

    code = EX_CANTCREAT

    def __init__(self, path: Path, reason: str) -> None:
        self.path = path
        self.reason = reason
        super().__init__(f"{path}: {reason}")


class UnsafeParent(StateDirError):
    """A directory on the way to the state directory lets another user swap it:
    a configuration to fix (78), not a file compd could create."""

    code = EX_CONFIG


def _loose_parent(st: os.stat_result, euid: int) -> str | None:
    """Why another user could rename entries in the directory `st`, None when not."""
    if st.st_uid not in (0, euid):
        return (f"is owned by uid {st.st_uid}, neither root nor this process (uid {euid}): "
                "its owner could swap the state directory")
    if st.st_mode & 0o022 and not st.st_mode & stat.S_ISVTX:
        return (f"is writable by group or others (mode {stat.S_IMODE(st.st_mode):04o}) "
                "without the sticky bit: another user could swap the state directory; "
                "chmod go-w it (or +t)")
    return None


def _private_problem(st: os.stat_result, euid: int, what: str) -> str | None:
    if not stat.S_ISDIR(st.st_mode):
        return f"{what} is not a directory"
    if st.st_uid != euid:
        return f"{what} is owned by uid {st.st_uid}, not by this process (uid {euid})"
    if st.st_mode & 0o022:
        return (f"{what} is writable by group or others "
                f"(mode {stat.S_IMODE(st.st_mode):04o}); chmod 700 it")
    return None


def _mkdir_exact(name: str, dir_fd: int, mode: int) -> bool:
    """mkdir `name` under `dir_fd` with exactly `mode` (the umask cannot widen or
    narrow it); False when something stands there already."""
    try:
        os.mkdir(name, mode & 0o700, dir_fd=dir_fd)  # never wider than ours until chmod-ed
    except FileExistsError:
        return False
    fd = os.open(name, _DIR_FLAGS, dir_fd=dir_fd)
    try:
        os.fchmod(fd, mode)
    finally:
        os.close(fd)
    return True


def _walk(path: Path, *, create: bool, what: str,
          private: bool) -> tuple[int, os.stat_result]:
    """A descriptor of directory `path`, reached safely (see the module docstring)."""
    euid = os.geteuid()
    absolute = Path(os.path.abspath(path))
    todo = list(absolute.parts[1:])
    todo.reverse()  # a stack: the next component last
    stack: list[tuple[int, Path]] = []
    links = 0
    try:
        fd = os.open("/", _DIR_FLAGS)
        stack.append((fd, Path("/")))
        if (why := _loose_parent(os.fstat(fd), euid)) is not None:
            raise UnsafeParent(Path("/"), why)
        while todo:
            name = todo.pop()
            if name in ("", "."):
                continue
            here_fd, here = stack[-1]
            if name == "..":
                if len(stack) > 1:
                    os.close(stack.pop()[0])
                continue
            where = here / name
            last = not todo
            try:
                lst = os.stat(name, dir_fd=here_fd, follow_symlinks=False)
            except FileNotFoundError:
                if not create:
                    raise StateDirError(where, "no such directory") from None
                _mkdir_exact(name, here_fd, STATE_MODE if last else PARENT_MODE)
                lst = os.stat(name, dir_fd=here_fd, follow_symlinks=False)
            if stat.S_ISLNK(lst.st_mode):
                if lst.st_uid not in (0, euid):  # a link another user made could point anywhere
                    which = what if last else "a directory on the way"
                    raise UnsafeParent(where, f"{which} is a link owned by uid {lst.st_uid}, "
                                              "neither root nor this process")
                links += 1
                if links > MAX_LINKS:
                    raise StateDirError(where, "too many symbolic links")
                target = Path(os.readlink(name, dir_fd=here_fd))
                if target.is_absolute():
                    for old, _ in stack[1:]:
                        os.close(old)
                    del stack[1:]
                todo.extend(reversed(target.parts[1:] if target.is_absolute()
                                     else target.parts))
                continue
            if not stat.S_ISDIR(lst.st_mode):
                raise StateDirError(where, f"{what} is not a directory" if last
                                    else f"a component of the {what}'s path is "
                                         "not a directory")
            try:
                fd = os.open(name, _DIR_FLAGS, dir_fd=here_fd)
            except OSError as exc:
                if exc.errno in (errno.ELOOP, errno.ENOTDIR):  # swapped since the lstat
                    raise StateDirError(where, "changed while being opened; refused") from None
                raise
            stack.append((fd, where))
            st = os.fstat(fd)
            if last and private:
                if (why := _private_problem(st, euid, what)) is not None:
                    raise StateDirError(where, why)
            elif (why := _loose_parent(st, euid)) is not None:
                raise UnsafeParent(where, f"the {what} {why}" if last
                                   else f"a parent of the {what} {why}")
        fd, _ = stack.pop()
        return fd, os.fstat(fd)
    finally:
        for old, _ in stack:
            os.close(old)


class StateDir:
    """An open directory compd keeps its files in (see the module docstring).
    `path` as given, `fd` its descriptor; `close()` when done."""

    def __init__(self, path: Path, fd: int, st: os.stat_result) -> None:
        self.path = path
        self.fd: int | None = fd
        self._id = (st.st_dev, st.st_ino)

    @classmethod
    def open(cls, path: Path, *, create: bool = True, what: str = "state directory",
             private: bool = True) -> StateDir:
        """Open (create if missing, with `create`) directory `path`, reached
        safely; `private`: ours and closed to group and others (the state
        directory), else held to the parents' rule (a sticky /tmp will do for a
        directory compd only checks names in). `what` names it in errors."""
        path = Path(path)
        try:
            fd, st = _walk(path, create=create, what=what, private=private)
        except StateDirError:
            raise
        except OSError as exc:
            raise StateDirError(path, f"cannot open the {what}: "
                                      f"{exc.strerror or exc}") from exc
        return cls(path, fd, st)

    def _dir_fd(self) -> int:
        if self.fd is None:
            raise StateDirError(self.path, "state directory closed")
        return self.fd

    def open_file(self, name: str, flags: int, *, create: bool = True) -> int:
        """`open_private` of `name` in this directory."""
        return open_private(self.path / name, flags, create=create, dir_fd=self._dir_fd())

    def replace(self, src: str, dst: str) -> None:
        fd = self._dir_fd()
        os.replace(src, dst, src_dir_fd=fd, dst_dir_fd=fd)

    def unlink(self, name: str, *, missing_ok: bool = True) -> None:
        try:
            os.unlink(name, dir_fd=self._dir_fd())
        except FileNotFoundError:
            if not missing_ok:
                raise

    def fsync(self) -> None:
        os.fsync(self._dir_fd())

    def check_names(self, names: Iterable[str]) -> None:
        """Raise StateDirError when one of `names` in this directory is a link, a
        hard link (st_nlink > 1), another owner's or not a regular file."""
        fd, euid = self._dir_fd(), os.geteuid()
        for name in names:
            try:
                st = os.stat(name, dir_fd=fd, follow_symlinks=False)
            except FileNotFoundError:
                continue
            _check_regular(self.path / name, st, euid)

    def verify(self) -> None:
        """Raise StateDirError unless `path` still names the directory opened
        (a library opening files by name would otherwise write elsewhere)."""
        try:
            st = os.stat(self.path)
        except OSError as exc:
            raise StateDirError(self.path, f"no longer reachable: {exc.strerror or exc}"
                                ) from None
        if (st.st_dev, st.st_ino) != self._id:
            raise StateDirError(self.path, "no longer names the directory compd opened "
                                           "(moved or swapped); refused")

    def close(self) -> None:
        fd, self.fd = self.fd, None
        if fd is not None:
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> StateDir:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def prepare_state_dir(path: Path) -> None:
    """Create `path` (mode 0700, parents 0755) if missing; refuse it when it is not
    safe to use (see `StateDir.open`)."""
    StateDir.open(path).close()


def _check_regular(path: Path, st: os.stat_result, euid: int) -> None:
    if stat.S_ISLNK(st.st_mode):
        raise StateDirError(path, "is a symbolic link; refused (not followed)")
    if not stat.S_ISREG(st.st_mode):
        raise StateDirError(path, "is not a regular file; refused")
    if st.st_uid != euid:
        raise StateDirError(path, f"is owned by uid {st.st_uid}, not by this process")
    if st.st_nlink != 1:  # a hard link planted to another file: writing it hurts that
        raise StateDirError(path, f"has {st.st_nlink} hard links; refused")


def open_private(path: Path, flags: int, *, create: bool = True,
                 dir_fd: int | None = None, owner: int | None = None) -> int:
    """A descriptor of the regular file `path` (ours, never through a link);
    with `dir_fd`, `path`'s name is opened in that directory. "Ours" is owned
    by this process's effective uid, or by `owner` when given (a reader that
    is not the writer, such as `compd health` run as root).

    `flags` are the access flags (os.O_RDONLY, os.O_RDWR, …); ``O_NOFOLLOW``
    and ``O_CLOEXEC`` are added, and ``O_CREAT`` (mode 0600) with `create`.
    Raises StateDirError for a link, a non-regular file, another owner's file
    or one with several names, FileNotFoundError when it is missing and not
    created, and OSError for what the file system refuses.
    """
    path = Path(path)
    all_flags = flags | os.O_NOFOLLOW | os.O_CLOEXEC | (os.O_CREAT if create else 0)
    if not all_flags & (os.O_WRONLY | os.O_RDWR):
        all_flags |= os.O_NONBLOCK  # a FIFO planted there must not hang the open
    try:
        if dir_fd is None:
            fd = os.open(path, all_flags, 0o600)
        else:
            fd = os.open(path.name, all_flags, 0o600, dir_fd=dir_fd)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise StateDirError(path, "is a symbolic link; refused (not followed)") from None
        raise
    try:
        _check_regular(path, os.fstat(fd), os.geteuid() if owner is None else owner)
        if all_flags & os.O_NONBLOCK and not flags & os.O_NONBLOCK:
            os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def refuse_link(path: Path) -> None:
    """Raise StateDirError when `path` exists as a link, a hard link or a
    non-regular file."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if stat.S_ISLNK(st.st_mode):
        raise StateDirError(path, "is a symbolic link; refused (not followed)")
    if not stat.S_ISREG(st.st_mode):
        raise StateDirError(path, "is not a regular file; refused")
    if st.st_nlink != 1:
        raise StateDirError(path, f"has {st.st_nlink} hard links; refused")
