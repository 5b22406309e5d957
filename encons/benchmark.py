"""``python -m encons.benchmark [profile=NAME] [overrides]``: the command ``python -m encons benchmark``, nothing else.

The library is :mod:`encons.tools.benchmark`, so importing this file is refused with that name (a name is a module or a
function, never both).
"""

from encons.entry import command_file

command_file(
    __name__,
    "benchmark",
    "encons.benchmark is only the command `python -m encons.benchmark`; import encons.tools.benchmark",
)
