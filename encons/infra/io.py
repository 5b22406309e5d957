"""Atomic file writes: every file encons writes goes to a hidden temporary file in its own folder,
is flushed to disk (``fsync``), then renamed over its final name (``os.replace``). A reader sees the
earlier file or the new one, never a part of one. A full, read-only or unwritable disk ends in one
:class:`~encons.infra.errors.WriteError` naming the folder, with the earlier file kept and the temporary
removed; a killed writer's temporary is removed by the next write into that folder on the same host.
"""

from __future__ import annotations

import errno
import io
import json
import os
import socket
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import IO, Any

from encons.infra.errors import WriteError

TMP_SUFFIX = ".tmp"
#: errors of the disk or the folder rather than of the program: reported as one ``WriteError``
DISK_ERRORS = frozenset(
    {
        errno.ENOSPC,
        errno.EDQUOT,
        errno.EROFS,
        errno.EACCES,
        errno.EPERM,
        errno.EIO,
        errno.EFBIG,
        errno.ENOTDIR,
        errno.EEXIST,
    }
)


def write_error(path: str | Path, err: OSError) -> WriteError:
    """The one-line error of a failed write of ``path``, naming its folder."""
    path = Path(path)
    return WriteError(
        f"folder={str(path.parent)!r}: cannot write {path.name} ({err.strerror or err}); allowed: a "
        f"writable folder with free space (earlier files there are kept, no partial file is left)"
    )


def _disk_error(err: BaseException | None) -> OSError | None:
    """The disk error (:data:`DISK_ERRORS`) that ``err`` is or was raised from (a library may wrap it)."""
    while err is not None:
        if isinstance(err, OSError) and err.errno in DISK_ERRORS:
            return err
        err = err.__cause__ or err.__context__
    return None


def _host() -> str:
    return socket.gethostname().replace(".", "-")


@contextmanager
def atomic_open(path: str | Path, mode: str = "wb", **kwargs: Any) -> Iterator[IO]:
    """Open a temporary sibling of ``path`` for writing (``mode`` ``"wb"`` or ``"w"``, ``kwargs`` as for
    ``open``); on leaving the block without an error, fsync it and rename it to ``path``. Creates the
    folder. A disk error (:data:`DISK_ERRORS`) becomes a ``WriteError``; other errors pass unchanged."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        clean_orphans(path.parent)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{_host()}.{os.getpid()}.", suffix=TMP_SUFFIX)
    except OSError as err:
        if _disk_error(err) is None:
            raise
        raise write_error(path, err) from None
    try:
        with os.fdopen(fd, mode, **kwargs) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # like any other output (mkstemp makes it 0600)
        os.replace(tmp, path)
    except BaseException as err:
        Path(tmp).unlink(missing_ok=True)
        disk = _disk_error(err)
        if disk is not None:
            raise write_error(path, disk) from None
        raise
    with suppress(OSError):  # make the rename itself durable where the platform allows
        folder = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(folder)
        finally:
            os.close(folder)


def clean_orphans(folder: str | Path) -> list[Path]:
    """Remove temporary files left in ``folder`` by killed writers of this host (their process is gone);
    other hosts' and live writers' files are left alone. Returns what was removed."""
    removed = []
    host = _host()
    for tmp in Path(folder).glob(f"*{TMP_SUFFIX}"):
        parts = tmp.name.split(".")
        if len(parts) < 5 or parts[-4] != host or not parts[-3].isdigit():
            continue
        try:
            os.kill(int(parts[-3]), 0)
        except ProcessLookupError:
            tmp.unlink(missing_ok=True)
            removed.append(tmp)
        except PermissionError:  # alive, another user's
            pass
    return removed


def write_bytes(path: str | Path, data: bytes | memoryview) -> Path:
    """Write ``data`` to ``path`` atomically."""
    with atomic_open(path) as f:
        f.write(data)
    return Path(path)


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return write_bytes(path, text.encode())


def write_json(path: str | Path, obj: Any, indent: int = 2) -> Path:
    """Write ``obj`` as JSON to ``path`` atomically."""
    return write_text(path, json.dumps(obj, indent=indent))


def write_yaml(path: str | Path, cfg: Any) -> Path:
    """Write an OmegaConf config (or a plain container) as YAML to ``path`` atomically."""
    from omegaconf import OmegaConf

    return write_text(path, OmegaConf.to_yaml(cfg if OmegaConf.is_config(cfg) else OmegaConf.create(cfg)))


def save_npz(path: str | Path, **arrays: Any) -> Path:
    """``numpy.savez`` of ``arrays`` to ``path`` atomically."""
    import numpy as np

    with atomic_open(path) as f:
        np.savez(f, **arrays)
    return Path(path)


def save_figure(fig: Any, path: str | Path, **kwargs: Any) -> Path:
    """``fig.savefig`` to ``path`` atomically, in the format its suffix names (``.png``). A PNG carries no
    "Software" (matplotlib version) entry, so the same figure gives the same bytes; a file that already holds
    them is left as it is (a report rebuilt over committed figures leaves the clone clean)."""
    path = Path(path)
    fmt = path.suffix.lstrip(".") or None
    buffer = io.BytesIO()
    fig.savefig(buffer, format=fmt, **({"metadata": {"Software": None}} if fmt == "png" else {}), **kwargs)
    if path.is_file() and path.read_bytes() == buffer.getvalue():
        return path
    return write_bytes(path, buffer.getbuffer())


def save_checkpoint(checkpoint: dict, path: str | Path) -> Path:
    """``torch.save`` of a checkpoint dict to ``path`` atomically. Serialised in memory first, so that
    the disk's own error reaches :func:`atomic_open` (torch's writer would wrap it)."""
    import torch

    buffer = io.BytesIO()
    torch.save(checkpoint, buffer)
    return write_bytes(path, buffer.getbuffer())
