"""The entry: the Python API (``api``), the one room where every command's argv is handled (``cli``), and the
``--help`` groups."""

import sys


def command_file(name: str, command: str, refusal: str) -> None:
    """The body of ``encons/<command>.py``: run as ``python -m encons.<command>`` (``name`` is ``"__main__"``), the
    command ``python -m encons <command>`` with this process's arguments; imported, refused with ``refusal``, which
    names the function or library module to import instead (a name is a module or a function, never both)."""
    if name != "__main__":
        raise ImportError(refusal)
    from encons.entry.cli import main

    main([command, *sys.argv[1:]])
