"""``python -m encons.evaluate RUN_DIR|CKPT [ckpt=best|last|PATH] [overrides]``: the command ``python -m encons
evaluate``, nothing else.

The Python name ``encons.evaluate`` is the API's function (:func:`encons.entry.api.evaluate`), so importing this file is
refused with that name (a name is a module or a function, never both).
"""

from encons.entry import command_file

command_file(
    __name__,
    "evaluate",
    "encons.evaluate is the API's function, not a module: call encons.evaluate(run); "
    "`python -m encons.evaluate` is the command",
)
