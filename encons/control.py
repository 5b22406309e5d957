"""``python -m encons.control RUN [ckpt=…] [starts=…] [seed=…] [duration=…]``: the command ``python -m encons control``,
nothing else.

The library is :mod:`encons.tools.control`, so importing this file is refused with that name (a name is a module or a
function, never both).
"""

import sys

if __name__ != "__main__":
    raise ImportError("encons.control is only the command `python -m encons.control`; import encons.tools.control")

from encons.entry.cli import main  # noqa: E402 - only when run as the command

main(["control", *sys.argv[1:]])
