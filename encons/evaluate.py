"""``python -m encons.evaluate RUN_DIR|CKPT [ckpt=best|last|PATH] [overrides]``: runs :func:`encons.cli.evaluate`.

The Python function is ``encons.evaluate`` (``encons.api.evaluate``); importing this module by
name binds it over that attribute, so scripts call ``encons.cli.evaluate`` or ``encons.api.evaluate``.
"""

if __name__ == "__main__":
    from encons.cli import evaluate

    evaluate()
