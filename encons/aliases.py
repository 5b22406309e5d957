"""Module names that are also commands or API names, kept from shadowing each other.

``python -m encons.train`` needs a module ``encons.train``, and ``encons.build`` is both the API's
function and the module ``encons/build.py``: importing such a module binds it over the package
attribute of the same name. :func:`callable_module` makes the module callable as the API function,
so ``encons.build(cfg)`` / ``encons.train(cfg)`` work whichever was imported first.
:func:`run_command` is the ``__main__`` block of a library module that is also a command
(``python -m encons.report DIR`` is ``python -m encons report DIR``): it hands the command line to
the one entry, ``encons/__main__.py``, without importing ``encons.cli`` (which imports the library
module: an import cycle).
"""

from __future__ import annotations

import runpy
import sys
import types
from typing import Any, Callable


def callable_module(name: str, function: Callable[..., Any]) -> None:
    """Make the imported module ``name`` callable as ``function`` (Python's documented module
    ``__class__`` assignment)."""
    module = sys.modules[name]
    module.__class__ = type("CallableModule", (types.ModuleType,), {
        "__call__": staticmethod(function),
        "__doc__": f"{module.__doc__}\n\nCalled: ``{function.__module__}.{function.__qualname__}``."})


def run_command(command: str) -> None:
    """Run ``python -m encons <command> <this process's arguments>``, in this process."""
    sys.argv[1:1] = [command]
    runpy.run_module("encons", run_name="__main__", alter_sys=True)
