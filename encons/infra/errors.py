"""Errors that end a run with one clear line, and :func:`one_line_errors`, which turns them (and
Hydra's own composition and run-folder errors) into that line on stderr with exit status 2."""

from __future__ import annotations

import errno
import os
import re
import sys
from collections.abc import Iterator
from contextlib import contextmanager


class EnconsError(Exception):
    """Base of every error encons reports to the user as one line, without a traceback."""


class ConfigError(EnconsError):
    """A composed config is invalid: a bad key, value or model × system combination."""


class ChartError(ConfigError):
    """A system was asked for a chart it does not have, or for a chart map it does not provide."""


class PhysicsError(ConfigError):
    """A system was asked for physics it does not know: a true field, energy or initial states (a system
    known only through data), a mass matrix, potential, constraints or frames it does not declare."""


class DataError(EnconsError):
    """A data file is missing or malformed."""


class DivergenceError(EnconsError):
    """Training produced a non-finite loss."""


class WriteError(EnconsError):
    """A file could not be written (full, read-only or unwritable disk); the earlier file is kept."""


class Interrupted(EnconsError):
    """A run stopped by SIGTERM (what a scheduler sends before it kills a job) or Ctrl-C: the CLI prints
    ``encons: interrupted: <line>`` with the command that resumes it, and exits with ``status``: 143 (128 + 15)
    for SIGTERM, 130 (128 + 2) for SIGINT."""

    def __init__(self, message: str, status: int = 143):
        super().__init__(message)
        self.status = status


class SweepError(EnconsError):
    """A sweep stopped because more of its trials failed than it allows."""


@contextmanager
def one_line_errors() -> Iterator[None]:
    """Print a user's error as ``encons: error: <line>`` on stderr, last, and exit 2 (an interrupted run:
    ``encons: interrupted: <line>``, exit 143); a bug keeps its traceback.

    Wraps the whole CLI (with ``HYDRA_FULL_ERROR=1``, so that Hydra lets its own errors through
    rather than printing its search path after them)."""
    from hydra.errors import ConfigCompositionException, InstantiationException, OverrideParseException

    try:
        yield
    except Interrupted as err:
        print(f"encons: interrupted: {err}", file=sys.stderr)
        sys.exit(err.status)
    except (EnconsError, ConfigCompositionException, OverrideParseException, InstantiationException) as err:
        print(f"encons: error: {user_line(err)}", file=sys.stderr)
        sys.exit(2)
    except (FileExistsError, NotADirectoryError, PermissionError) as err:  # e.g. Hydra creating hydra.run.dir
        print(
            f"encons: error: {err.filename!r}: {err.strerror}; allowed: a writable folder for hydra.run.dir, "
            f"hydra.sweep.dir and paths.*",
            file=sys.stderr,
        )
        sys.exit(2)
    except OSError as err:  # a full or read-only disk under a writer encons does not own (Hydra's, a logger's)
        if err.errno not in (errno.ENOSPC, errno.EDQUOT, errno.EROFS):
            raise
        where = (
            f"folder={os.path.dirname(err.filename)!r}: cannot write {os.path.basename(err.filename)}"
            if isinstance(err.filename, str)
            else "a write failed"
        )
        print(f"encons: error: {where} ({err.strerror}); allowed: a writable folder with free space", file=sys.stderr)
        sys.exit(2)


def user_line(err: Exception) -> str:
    """The one line of an encons error, or of Hydra's composition, override and instantiation errors."""
    from hydra.errors import InstantiationException, MissingConfigException, OverrideParseException

    if isinstance(err, EnconsError):
        return str(err)
    if isinstance(err, InstantiationException):
        return f"{str(err).splitlines()[0]} ({err.__cause__}); allowed: the values documented in conf/"
    if isinstance(err, MissingConfigException) and err.missing_cfg_file and err.options:
        group, _, name = err.missing_cfg_file.rpartition("/")
        return (
            f"{group}={name} is unknown; allowed: {', '.join(sorted(o for o in err.options if not o.startswith('_')))}"
        )
    lines = str(err).strip().splitlines()
    missing = re.match(r"Could not override '([^']+)'", lines[0])
    if missing:
        key = missing.group(1)
        return (
            f"{key} is not a key of the config{_did_you_mean(key, err.__cause__)}; allowed: the keys `--cfg "
            f"job` prints, or +{key}=VALUE to add one"
        )
    unquoted = re.match(r"Error when parsing index: \d+, string: (([\w.+~/]+)=\[(.*=.*)\]) out of", lines[0])
    if unquoted:  # train=[trainer.max_epochs=150]: Hydra reads an element holding '=' only in quotes
        item, key, elements = unquoted.groups()
        quoted = ",".join(f'"{e.strip()}"' for e in elements.split(","))
        return f"{item}: a list element holding '=' needs quotes; allowed: '{key}=[{quoted}]' (quoted as shown)"
    return lines[0] + (
        "; allowed: key=value overrides (Hydra's override grammar)" if isinstance(err, OverrideParseException) else ""
    )


def _did_you_mean(key: str, cause: BaseException | None) -> str:
    """ ", did you mean trainer.max_epochs" for a misspelt ``key``: the part OmegaConf could not find (its error
    carries the key and the node it was looked up in) replaced by the closest key of that node; nothing when
    none is close."""
    import difflib

    node, missing, where = (getattr(cause, name, None) for name in ("parent_node", "key", "full_key"))
    if node is None or not hasattr(node, "keys") or not isinstance(missing, str) or not isinstance(where, str):
        return ""
    close = difflib.get_close_matches(missing, [str(k) for k in node.keys()], n=1)
    if not close:
        return ""
    return f", did you mean {where.removesuffix(missing) + close[0] + key.lstrip('+~').removeprefix(where)}"
