"""``python -m encons <command> [arguments]``: the one entry (``encons.entry.cli.main``); commands: train,
evaluate, benchmark, report, sweep, control."""

from encons.entry.cli import main

if __name__ == "__main__":
    main()
