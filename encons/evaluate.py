"""Roll out a trained run's checkpoint on a test set: metrics, figures, summary table.

    python -m encons.evaluate RUN_DIR|CKPT [ckpt=best|last|PATH] [key=value ...]

``RUN_DIR`` is a training run's output folder (``checkpoints/``); a ``.ckpt`` file works alone,
since checkpoints carry their config. ``ckpt=best`` (default) is the checkpoint ``train`` tested,
so the metrics agree to the digit. Overrides change the evaluation, e.g. ``data.test_steps=1000``
for a longer test set; metrics sum over the first ``horizon`` steps (4), so add
``horizon=1000`` to score the whole trajectory. Results land in ``RUN_DIR/evaluation/``.
"""

from __future__ import annotations

import sys

from encons import api
from encons.errors import one_line_errors


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__)
        sys.exit(0 if argv else 2)
    api.quiet_upstream()
    overrides = [a for a in argv[1:] if not a.startswith("ckpt=")]
    ckpt = next((a.split("=", 1)[1] for a in argv[1:] if a.startswith("ckpt=")), "best")
    with one_line_errors():
        api.evaluate(argv[0], overrides, ckpt=ckpt)


api._callable_module(__name__, api.evaluate)  # ``encons.evaluate(run)`` stays the API function

if __name__ == "__main__":
    main()
