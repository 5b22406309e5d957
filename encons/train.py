"""``python -m encons.train model=<model> system=<system> [overrides]``: the command ``python -m encons train``, nothing
else.

The Python name ``encons.train`` is the API's function (:func:`encons.entry.api.train`), so importing this file is
refused with that name (a name is a module or a function, never both).
"""

import sys

if __name__ != "__main__":
    raise ImportError(
        "encons.train is the API's function, not a module: call encons.train(cfg); "
        "`python -m encons.train` is the command"
    )

from encons.entry.cli import main  # noqa: E402 - only when run as the command

main(["train", *sys.argv[1:]])
