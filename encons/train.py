"""``python -m encons.train model=<model> system=<system> [overrides]``: runs :func:`encons.cli.train`.

The Python function is ``encons.train`` (``encons.api.train``); importing this module by name
binds it over that attribute, so scripts call ``encons.cli.train`` or ``encons.api.train`` instead.
"""

if __name__ == "__main__":
    from encons.cli import train

    train()
