"""``python -m encons.sweep STORAGE STUDY [OUT]``: the command ``python -m encons sweep``, nothing else.

The library is :mod:`encons.tools.sweep`, so importing this file is refused with that name (a name is a module or a
function, never both).
"""

import sys

if __name__ != "__main__":
    raise ImportError("encons.sweep is only the command `python -m encons.sweep`; import encons.tools.sweep")

from encons.entry.cli import main  # noqa: E402 - only when run as the command

main(["sweep", *sys.argv[1:]])
