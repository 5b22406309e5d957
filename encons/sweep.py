"""``python -m encons.sweep STORAGE STUDY [OUT]``: the command ``python -m encons sweep``, nothing else.

The library is :mod:`encons.tools.sweep`, so importing this file is refused with that name (a name is a module or a
function, never both).
"""

from encons.entry import command_file

command_file(__name__, "sweep", "encons.sweep is only the command `python -m encons.sweep`; import encons.tools.sweep")
