"""``python -m encons.evaluate RUN_DIR|CKPT [ckpt=best|last|PATH] [overrides]``: the command ``python -m encons
evaluate``, nothing else.

The Python name ``encons.evaluate`` is the API's function (:func:`encons.entry.api.evaluate`), so importing this file is
refused with that name (a name is a module or a function, never both).
"""

import sys

if __name__ != "__main__":
    raise ImportError(
        "encons.evaluate is the API's function, not a module: call encons.evaluate(run); "
        "`python -m encons.evaluate` is the command"
    )

from encons.entry.cli import main  # noqa: E402 - only when run as the command

main(["evaluate", *sys.argv[1:]])
