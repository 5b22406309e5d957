"""``python -m encons.evaluate RUN_DIR|CKPT [ckpt=best|last|PATH] [overrides]``: an alias of
``python -m encons evaluate``.

Imported (``import encons.evaluate``), this module is bound over the API's ``encons.evaluate``; it is
then callable as that function (``encons.aliases.callable_module``), so ``encons.evaluate(run)`` still works.
"""

import sys

from encons import api, cli
from encons.aliases import callable_module

if __name__ == "__main__":
    cli.main(["evaluate", *sys.argv[1:]])
else:
    callable_module(__name__, api.evaluate)
