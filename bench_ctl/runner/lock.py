"""One run per exciter: an exclusive lock file keyed by the exciter's endpoint.

A run that may write takes `BenchLock` before it connects: `fcntl.flock` on a file in ONE
host-wide folder, whatever the environment and whoever runs it (`LOCK_FOLDER`:
`/run/lock/bench-ctl`, or `/tmp/bench-ctl-locks` on a host without `/run/lock`; never taken from
`XDG_RUNTIME_DIR`, `TMPDIR` or the user, which differ between two shells of one host), one file
per exciter endpoint (host resolved to its address, port, unit id). The folder is shared like
/tmp (mode 1777: anyone makes a lock file, only its owner removes it) and each lock file is
readable and writable by all (0666), so two users' runs on one exciter meet on one file. The holder writes its pid,
host, user, procedure, output folder and start time into the file, so a second run is refused
with a message naming it. The lock is released on every way out of the run (and by the
operating system when the holder dies, even by SIGKILL: a crashed run never leaves a stale
lock). It covers the runs of this machine; the device's own "remote owned by another master"
state covers other machines (docs/decisions/0012).
"""
from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import logging
import os
import socket
import stat
from pathlib import Path
from typing import Any

from bench_ctl.runner.safety import BenchBusy
from bench_ctl.timestamps import utc_now_text

log = logging.getLogger(__name__)


#: candidate host-wide folders of the lock files, the first whose parent exists is the one (a
#: property of the host, the same for every user and environment; docs/decisions/0012)
LOCK_FOLDERS = (Path("/run/lock/bench-ctl"), Path("/tmp/bench-ctl-locks"))


def lock_dir() -> Path:
    """The host-wide folder of lock files (see the module docstring): made with mode 1777 (sticky,
    shared as /tmp is) when missing; refused when it is not a folder (a link, a file) or when
    another user owns it without the sticky bit (they could remove a lock file in use)."""
    base = next((f for f in LOCK_FOLDERS if f.parent.is_dir()), LOCK_FOLDERS[-1])
    try:
        base.mkdir(mode=0o1777, exist_ok=False)   # sticky from the start (the umask may narrow the rest)
        os.chmod(base, 0o1777)
    except FileExistsError:
        pass
    except OSError as exc:
        raise OSError(exc.errno, f"cannot make the lock folder {base}: {exc.strerror} (an administrator "
                      f"can make it once: mkdir -m 1777 {base})") from None
    st = os.lstat(base)
    if not stat.S_ISDIR(st.st_mode):
        raise OSError(errno.EPERM, f"lock folder {base} is not a folder; refusing to keep bench locks there")
    if st.st_uid not in (0, os.getuid()) and not st.st_mode & stat.S_ISVTX:
        raise OSError(errno.EPERM, f"lock folder {base} belongs to another user and is not sticky (mode "
                      f"{stat.S_IMODE(st.st_mode):o}): they could remove a lock in use; make it 1777 or root's")
    return base


def endpoint_key(url: str, unit_id: int) -> str:
    """`tcp://ADDRESS:PORT/unit` with the host resolved to its address when it resolves (the
    same exciter named `localhost` and `127.0.0.1` is one bench)."""
    scheme, _, rest = url.partition("://")
    host, _, port = rest.rpartition(":")
    host = host.strip("[]").lower()
    try:
        infos = socket.getaddrinfo(host, int(port), type=socket.SOCK_STREAM)
        host = sorted(info[4][0] for info in infos)[0]
    except (OSError, ValueError):
        pass  # an unresolvable name is its own key; connecting will say what is wrong
    return f"{scheme}://{host}:{port}/{unit_id}"


class BenchLock:
    """The exclusive lock of one exciter endpoint (see the module docstring). No I/O before
    `acquire()`; usable as a context manager."""

    def __init__(self, url: str, unit_id: int, *, procedure: str, out_dir: str,
                 folder: Path | None = None) -> None:
        self.key = endpoint_key(url, unit_id)
        self.url = url
        self.procedure = procedure
        self.out_dir = out_dir
        self._folder = folder
        self.path: Path | None = None
        self._fd: int | None = None

    def acquire(self) -> BenchLock:
        """Take the lock, or BenchBusy naming the holder. OSError when the lock folder or file
        cannot be used (the run is then refused: it would not know it is alone)."""
        folder = self._folder or lock_dir()
        name = hashlib.sha256(self.key.encode()).hexdigest()[:20]
        self.path = folder / f"exciter-{name}.lock"
        for _ in range(10):
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
            try:
                if os.fstat(fd).st_uid == os.getuid():
                    os.fchmod(fd, 0o666)   # every user's run opens it (the umask narrowed it)
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _read_holder(fd)
                os.close(fd)
                raise BenchBusy(f"refused before any write: another run holds the exciter {self.url} "
                                f"({describe_holder(holder)}); one run per exciter (lock file "
                                f"{self.path})") from None
            except BaseException:
                os.close(fd)
                raise
            if _same_file(fd, self.path):
                break
            os.close(fd)  # the holder removed the file while it released it: open the new one
        else:
            raise OSError(errno.EAGAIN, f"lock file {self.path} keeps being replaced")
        self._fd = fd
        holder = {"pid": os.getpid(), "host": socket.gethostname(), "user": _user(),
                  "procedure": self.procedure, "out_dir": self.out_dir, "endpoint": self.key,
                  "started_utc": utc_now_text()}
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, (json.dumps(holder) + "\n").encode(), 0)
        except OSError as exc:  # the lock holds without its note (e.g. a full /tmp)
            log.warning("bench lock %s taken, but the holder's note could not be written: %s",
                        self.path, exc.strerror)
        log.info("bench lock taken: %s (%s)", self.key, self.path)
        return self

    @property
    def held(self) -> bool:
        return self._fd is not None

    def release(self) -> None:
        """Remove the lock file, then unlock (idempotent; never raises). A run waiting on the
        old file sees it replaced and opens the new one (`acquire` checks), so lock files do
        not pile up, one per port a dry run used."""
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:
            if self.path is not None and _same_file(fd, self.path):
                os.unlink(self.path)
        except OSError:
            pass
        try:
            fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            os.close(fd)
        log.info("bench lock released: %s", self.key)

    def __enter__(self) -> BenchLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def _same_file(fd: int, path: Path) -> bool:
    """The open lock file is still the one under `path`."""
    try:
        a, b = os.fstat(fd), os.stat(path, follow_symlinks=False)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _user() -> str:
    try:
        import getpass

        return getpass.getuser()
    except Exception:  # noqa: BLE001 - a name is a courtesy, not a requirement
        return str(os.getuid())


def _read_holder(fd: int) -> dict[str, Any]:
    try:
        text = os.pread(fd, 4096, 0).decode("utf-8", "replace")
        holder = json.loads(text)
        return holder if isinstance(holder, dict) else {}
    except (OSError, ValueError):
        return {}


def describe_holder(holder: dict[str, Any]) -> str:
    """`pid 1234 on host h (user u), procedure no_load_pulse, started 2025-...Z, output runs/x`."""
    if not holder:
        return "its holder did not say who it is"
    parts = [f"pid {holder.get('pid', '?')} on host {holder.get('host', '?')} "
             f"(user {holder.get('user', '?')})"]
    if holder.get("procedure"):
        parts.append(f"procedure {holder['procedure']}")
    if holder.get("started_utc"):
        parts.append(f"started {holder['started_utc']}")
    if holder.get("out_dir"):
        parts.append(f"output {holder['out_dir']}")
    return ", ".join(parts)
