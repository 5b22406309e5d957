"""``python -m encons.report DIR``: the command ``python -m encons report``, nothing else.

The library is :mod:`encons.tools.report`, so importing this file is refused with that name (a name is a module or a
function, never both).
"""

import sys

if __name__ != "__main__":
    raise ImportError("encons.report is only the command `python -m encons.report`; import encons.tools.report")

from encons.entry.cli import main  # noqa: E402 - only when run as the command

main(["report", *sys.argv[1:]])
