"""``python -m encons.train model=<model> system=<system> [overrides]``: an alias of ``python -m encons train``.

Imported (``import encons.train``), this module is bound over the API's ``encons.train``; it is then
callable as that function (``encons.aliases.callable_module``), so ``encons.train(cfg)`` still trains.
"""

import sys

from encons import api, cli
from encons.aliases import callable_module

if __name__ == "__main__":
    cli.main(["train", *sys.argv[1:]])
else:
    callable_module(__name__, api.train)
