"""``python -m encons.control RUN [ckpt=…] [starts=…] [seed=…] [duration=…]``: the command ``python -m encons control``,
nothing else.

The library is :mod:`encons.tools.control`, so importing this file is refused with that name (a name is a module or a
function, never both).
"""

from encons.entry import command_file

command_file(
    __name__, "control", "encons.control is only the command `python -m encons.control`; import encons.tools.control"
)
