"""``python -m encons.report DIR``: the command ``python -m encons report``, nothing else.

The library is :mod:`encons.tools.report`, so importing this file is refused with that name (a name is a module or a
function, never both).
"""

from encons.entry import command_file

command_file(
    __name__, "report", "encons.report is only the command `python -m encons.report`; import encons.tools.report"
)
