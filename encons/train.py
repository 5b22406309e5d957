"""``python -m encons.train model=<model> system=<system> [overrides]``: the command ``python -m encons train``, nothing
else.

The Python name ``encons.train`` is the API's function (:func:`encons.entry.api.train`), so importing this file is
refused with that name (a name is a module or a function, never both).
"""

from encons.entry import command_file

command_file(
    __name__,
    "train",
    "encons.train is the API's function, not a module: call encons.train(cfg); `python -m encons.train` is the command",
)
