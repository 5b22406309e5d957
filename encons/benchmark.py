"""``python -m encons.benchmark [profile=NAME] [overrides]``: the command ``python -m encons benchmark``, nothing else.

The library is :mod:`encons.tools.benchmark`, so importing this file is refused with that name (a name is a module or a
function, never both).
"""

import sys

if __name__ != "__main__":
    raise ImportError(
        "encons.benchmark is only the command `python -m encons.benchmark`; import encons.tools.benchmark"
    )

from encons.entry.cli import main  # noqa: E402 - only when run as the command

main(["benchmark", *sys.argv[1:]])
